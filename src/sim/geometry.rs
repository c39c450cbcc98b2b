//! Rays, shapes and their intersection; procedural meshes; an orthonormal shading frame.

use glam::{Mat4, Vec3};

/// Offset that keeps secondary rays from re-hitting their origin surface.
pub const RAY_EPSILON: f32 = 1e-4;

/// A ray `origin + t * dir`, `t` in `(RAY_EPSILON, t_max)`.
#[derive(Debug, Clone, Copy)]
pub struct Ray {
    /// Origin.
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
    /// Farthest distance of interest.
    pub t_max: f32,
}

impl Ray {
    /// A ray to infinity.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir, t_max: f32::INFINITY }
    }
}

/// An axis-aligned box.
#[derive(Debug, Clone, Copy)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box.
    pub const EMPTY: Aabb = Aabb { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) };

    /// Union with another box.
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb { min: self.min.min(o.min), max: self.max.max(o.max) }
    }

    /// Centre.
    pub fn centroid(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }

    /// Surface area (for the SAH).
    pub fn area(&self) -> f32 {
        let d = (self.max - self.min).max(Vec3::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }

    /// Slab test against a ray with precomputed inverse direction.
    pub fn hit(&self, origin: Vec3, inv_dir: Vec3, t_max: f32) -> bool {
        let t0 = (self.min - origin) * inv_dir;
        let t1 = (self.max - origin) * inv_dir;
        let tmin = t0.min(t1).max_element().max(0.0);
        let tmax = t0.max(t1).min_element().min(t_max);
        tmin <= tmax
    }
}

/// A renderable shape, already in world space.
#[derive(Debug, Clone, Copy)]
pub enum Shape {
    /// A sphere.
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius.
        radius: f32,
    },
    /// A triangle with per-vertex shading normals.
    Triangle {
        /// Vertices.
        p: [Vec3; 3],
        /// Shading normals.
        n: [Vec3; 3],
    },
}

/// Where a ray met a shape.
#[derive(Debug, Clone, Copy)]
pub struct SurfaceHit {
    /// Distance along the ray.
    pub t: f32,
    /// Position.
    pub p: Vec3,
    /// Geometric normal (facing the ray's origin side is not guaranteed).
    pub ng: Vec3,
    /// Interpolated shading normal.
    pub ns: Vec3,
}

impl Shape {
    /// Bounding box.
    pub fn bounds(&self) -> Aabb {
        match *self {
            Shape::Sphere { center, radius } => {
                Aabb { min: center - Vec3::splat(radius), max: center + Vec3::splat(radius) }
            }
            Shape::Triangle { p, .. } => Aabb { min: p[0].min(p[1]).min(p[2]), max: p[0].max(p[1]).max(p[2]) },
        }
    }

    /// Surface area.
    pub fn area(&self) -> f32 {
        match *self {
            Shape::Sphere { radius, .. } => 4.0 * std::f32::consts::PI * radius * radius,
            Shape::Triangle { p, .. } => 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length(),
        }
    }

    /// Nearest intersection within the ray's range.
    pub fn intersect(&self, ray: &Ray) -> Option<SurfaceHit> {
        match *self {
            Shape::Sphere { center, radius } => {
                let oc = ray.origin - center;
                let b = oc.dot(ray.dir);
                let c = oc.length_squared() - radius * radius;
                let disc = b * b - c;
                if disc < 0.0 {
                    return None;
                }
                let s = disc.sqrt();
                let t = [-b - s, -b + s].into_iter().find(|&t| t > RAY_EPSILON && t < ray.t_max)?;
                let p = ray.origin + t * ray.dir;
                let n = (p - center) / radius;
                Some(SurfaceHit { t, p, ng: n, ns: n })
            }
            Shape::Triangle { p, n } => {
                let e1 = p[1] - p[0];
                let e2 = p[2] - p[0];
                let pv = ray.dir.cross(e2);
                let det = e1.dot(pv);
                if det.abs() < 1e-12 {
                    return None;
                }
                let inv = 1.0 / det;
                let tv = ray.origin - p[0];
                let u = tv.dot(pv) * inv;
                if !(0.0..=1.0).contains(&u) {
                    return None;
                }
                let qv = tv.cross(e1);
                let v = ray.dir.dot(qv) * inv;
                if v < 0.0 || u + v > 1.0 {
                    return None;
                }
                let t = e2.dot(qv) * inv;
                if t <= RAY_EPSILON || t >= ray.t_max {
                    return None;
                }
                let ng = e1.cross(e2).normalize();
                let ns = ((1.0 - u - v) * n[0] + u * n[1] + v * n[2]).normalize_or(ng);
                Some(SurfaceHit { t, p: ray.origin + t * ray.dir, ng, ns })
            }
        }
    }

    /// A point uniformly distributed over the surface and its normal.
    pub fn sample_point(&self, u: [f32; 2]) -> (Vec3, Vec3) {
        match *self {
            Shape::Sphere { center, radius } => {
                let n = uniform_sphere(u);
                (center + radius * n, n)
            }
            Shape::Triangle { p, .. } => {
                let su = u[0].sqrt();
                let (b0, b1) = (1.0 - su, u[1] * su);
                let pt = b0 * p[0] + b1 * p[1] + (1.0 - b0 - b1) * p[2];
                (pt, (p[1] - p[0]).cross(p[2] - p[0]).normalize())
            }
        }
    }
}

/// Uniform direction on the unit sphere.
pub fn uniform_sphere(u: [f32; 2]) -> Vec3 {
    let z = 1.0 - 2.0 * u[0];
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f32::consts::PI * u[1];
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Cosine-weighted direction on the +z hemisphere.
pub fn cosine_hemisphere(u: [f32; 2]) -> Vec3 {
    let d = concentric_disk(u);
    Vec3::new(d.0, d.1, (1.0 - d.0 * d.0 - d.1 * d.1).max(0.0).sqrt())
}

/// Shirley–Chiu concentric map from the square to the unit disk.
pub fn concentric_disk(u: [f32; 2]) -> (f32, f32) {
    let (a, b) = (2.0 * u[0] - 1.0, 2.0 * u[1] - 1.0);
    if a == 0.0 && b == 0.0 {
        return (0.0, 0.0);
    }
    let q = std::f32::consts::FRAC_PI_4;
    let (r, theta) = if a.abs() > b.abs() { (a, q * (b / a)) } else { (b, 2.0 * q - q * (a / b)) };
    (r * theta.cos(), r * theta.sin())
}

/// An orthonormal basis around a unit normal (Duff et al. 2017).
#[derive(Debug, Clone, Copy)]
pub struct Frame {
    /// Tangent.
    pub s: Vec3,
    /// Bitangent.
    pub t: Vec3,
    /// Normal.
    pub n: Vec3,
}

impl Frame {
    /// The frame around `n`.
    pub fn new(n: Vec3) -> Self {
        let sign = 1f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        Frame {
            s: Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
            t: Vec3::new(b, sign + n.y * n.y * a, -n.y),
            n,
        }
    }

    /// World → local.
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    /// Local → world.
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        v.x * self.s + v.y * self.t + v.z * self.n
    }
}

/// Procedural meshes in object space, as triangles with shading normals.
pub mod mesh {
    use super::*;

    fn tri(a: Vec3, b: Vec3, c: Vec3) -> Shape {
        let n = (b - a).cross(c - a).normalize();
        Shape::Triangle { p: [a, b, c], n: [n; 3] }
    }

    /// Unit square in the XZ plane, centred at the origin, normal +Y.
    pub fn quad() -> Vec<Shape> {
        let (a, b, c, d) = (
            Vec3::new(-0.5, 0.0, -0.5),
            Vec3::new(-0.5, 0.0, 0.5),
            Vec3::new(0.5, 0.0, 0.5),
            Vec3::new(0.5, 0.0, -0.5),
        );
        vec![tri(a, b, c), tri(a, c, d)]
    }

    /// Unit cube centred at the origin, outward normals.
    pub fn cube() -> Vec<Shape> {
        let mut out = Vec::new();
        let faces = [Mat4::IDENTITY, Mat4::from_rotation_x(std::f32::consts::PI)];
        let sides = [
            Mat4::IDENTITY,
            Mat4::from_rotation_z(std::f32::consts::FRAC_PI_2),
            Mat4::from_rotation_x(std::f32::consts::FRAC_PI_2),
        ];
        for s in sides {
            for f in faces {
                let m = s * f * Mat4::from_translation(Vec3::new(0.0, 0.5, 0.0));
                out.extend(quad().into_iter().map(|t| transform(&t, &m)));
            }
        }
        out
    }

    /// A torus around the Y axis: major radius 1, minor radius `minor`, smooth normals.
    pub fn torus(minor: f32, segments: usize) -> Vec<Shape> {
        let (nu, nv) = (segments * 2, segments);
        let at = |i: usize, j: usize| {
            let u = 2.0 * std::f32::consts::PI * (i % nu) as f32 / nu as f32;
            let v = 2.0 * std::f32::consts::PI * (j % nv) as f32 / nv as f32;
            let c = Vec3::new(u.cos(), 0.0, u.sin());
            let n = c * v.cos() + Vec3::Y * v.sin();
            (c + minor * n, n)
        };
        let mut out = Vec::new();
        for i in 0..nu {
            for j in 0..nv {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                out.push(Shape::Triangle { p: [a.0, c.0, b.0], n: [a.1, c.1, b.1] });
                out.push(Shape::Triangle { p: [a.0, d.0, c.0], n: [a.1, d.1, c.1] });
            }
        }
        out
    }

    /// A capped cylinder of radius 0.5 and height 1 around the Y axis, centred at the origin.
    pub fn cylinder(segments: usize) -> Vec<Shape> {
        let mut out = Vec::new();
        let ring = |i: usize| {
            let a = 2.0 * std::f32::consts::PI * (i % segments) as f32 / segments as f32;
            Vec3::new(0.5 * a.cos(), 0.0, 0.5 * a.sin())
        };
        let (top, bottom) = (Vec3::new(0.0, 0.5, 0.0), Vec3::new(0.0, -0.5, 0.0));
        for i in 0..segments {
            let (r0, r1) = (ring(i), ring(i + 1));
            let (n0, n1) = (r0.normalize(), r1.normalize());
            let (a, b, c, d) = (r0 + bottom, r1 + bottom, r1 + top, r0 + top);
            out.push(Shape::Triangle { p: [a, c, b], n: [n0, n1, n1] });
            out.push(Shape::Triangle { p: [a, d, c], n: [n0, n0, n1] });
            out.push(tri(top, r1 + top, r0 + top));
            out.push(tri(bottom, r0 + bottom, r1 + bottom));
        }
        out
    }

    /// A shape moved by an affine transform (normals by the inverse transpose).
    pub fn transform(s: &Shape, m: &Mat4) -> Shape {
        let nm = m.inverse().transpose();
        match *s {
            Shape::Triangle { p, n } => Shape::Triangle {
                p: p.map(|v| m.transform_point3(v)),
                n: n.map(|v| nm.transform_vector3(v).normalize()),
            },
            Shape::Sphere { center, radius } => {
                // Spheres take the transform's mean scale.
                let scale = (m.transform_vector3(Vec3::X).length()
                    + m.transform_vector3(Vec3::Y).length()
                    + m.transform_vector3(Vec3::Z).length())
                    / 3.0;
                Shape::Sphere { center: m.transform_point3(center), radius: radius * scale }
            }
        }
    }
}
