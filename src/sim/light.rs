//! Light sources: area emitters (emissive shapes), point and spot lights, the environment
//! (constant or procedural sky) and a sun disc.

use super::geometry::{Shape, uniform_sphere};
use glam::Vec3;
use std::f32::consts::PI;

/// The environment's radiance model.
#[derive(Debug, Clone)]
pub enum Sky {
    /// One radiance in every direction.
    Constant(Vec3),
    /// A procedural sky: zenith-to-horizon gradient over a ground colour.
    Gradient {
        /// Radiance straight up.
        zenith: Vec3,
        /// Radiance at the horizon.
        horizon: Vec3,
        /// Radiance below the horizon.
        ground: Vec3,
    },
}

/// A sun: a small disc of constant radiance.
#[derive(Debug, Clone, Copy)]
pub struct Sun {
    /// Unit direction towards the sun.
    pub dir: Vec3,
    /// Radiance of the disc.
    pub radiance: Vec3,
    /// Cosine of the disc's angular radius.
    pub cos_max: f32,
}

impl Sun {
    /// Solid angle of the disc.
    pub fn solid_angle(&self) -> f32 {
        2.0 * PI * (1.0 - self.cos_max)
    }

    /// Uniform direction within the disc.
    pub fn sample(&self, u: [f32; 2]) -> Vec3 {
        let cos = 1.0 - u[0] * (1.0 - self.cos_max);
        let sin = (1.0 - cos * cos).max(0.0).sqrt();
        let phi = 2.0 * PI * u[1];
        let f = super::geometry::Frame::new(self.dir);
        f.to_world(Vec3::new(sin * phi.cos(), sin * phi.sin(), cos))
    }
}

/// The environment: radiance arriving from infinitely far away.
#[derive(Debug, Clone)]
pub struct Environment {
    /// The sky model.
    pub sky: Sky,
    /// Rotation about +Y (radians).
    pub rotation: f32,
}

impl Environment {
    /// Radiance from direction `d` (the sun disc excluded).
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        match &self.sky {
            Sky::Constant(c) => *c,
            Sky::Gradient { zenith, horizon, ground } => {
                let (s, c) = self.rotation.sin_cos();
                // Rotating the sky rotates its (subtle) azimuthal tint.
                let x = c * d.x - s * d.z;
                if d.y < 0.0 {
                    *ground
                } else {
                    let t = d.y.sqrt();
                    let tint = 1.0 + 0.15 * x;
                    horizon.lerp(*zenith, t) * tint
                }
            }
        }
    }
}

/// A light that next-event estimation can sample.
#[derive(Debug, Clone, Copy)]
pub enum Light {
    /// An emissive shape (index into the scene's shapes).
    Area {
        /// Shape index.
        shape: usize,
        /// Emitted radiance.
        radiance: Vec3,
    },
    /// A point light, optionally a spot.
    Point {
        /// Position.
        position: Vec3,
        /// Radiant intensity.
        intensity: Vec3,
        /// Spot: (axis, cos inner, cos outer).
        spot: Option<(Vec3, f32, f32)>,
    },
    /// The environment (uniformly sampled sphere).
    Environment,
    /// The sun disc.
    Sun,
}

/// A light sample as seen from a shading point.
#[derive(Debug, Clone, Copy)]
pub struct LightSample {
    /// Unit direction to the light.
    pub wi: Vec3,
    /// Distance to the light (infinite for distant lights).
    pub dist: f32,
    /// Radiance (or intensity / dist² for point lights) arriving.
    pub radiance: Vec3,
    /// Solid-angle pdf of this light's sampling; 0 for delta lights.
    pub pdf: f32,
}

/// What a light needs from the scene.
pub struct LightContext<'a> {
    /// Scene shapes.
    pub shapes: &'a [Shape],
    /// The environment.
    pub env: Option<&'a Environment>,
    /// The sun.
    pub sun: Option<&'a Sun>,
}

impl Light {
    /// Samples the light from point `p`.
    pub fn sample(&self, ctx: &LightContext, p: Vec3, u: [f32; 2]) -> Option<LightSample> {
        match *self {
            Light::Area { shape, radiance } => {
                let s = &ctx.shapes[shape];
                let (q, n) = s.sample_point(u);
                let d = q - p;
                let dist2 = d.length_squared();
                let dist = dist2.sqrt();
                let wi = d / dist;
                let cos_l = n.dot(-wi).abs();
                if cos_l <= 1e-6 || dist <= 1e-5 {
                    return None;
                }
                Some(LightSample { wi, dist, radiance, pdf: dist2 / (cos_l * s.area()) })
            }
            Light::Point { position, intensity, spot } => {
                let d = position - p;
                let dist2 = d.length_squared();
                let dist = dist2.sqrt();
                let wi = d / dist;
                let falloff = match spot {
                    None => 1.0,
                    Some((axis, cos_in, cos_out)) => {
                        let c = (-wi).dot(axis);
                        ((c - cos_out) / (cos_in - cos_out).max(1e-6)).clamp(0.0, 1.0).powi(2)
                    }
                };
                (falloff > 0.0).then(|| LightSample { wi, dist, radiance: intensity * falloff / dist2, pdf: 0.0 })
            }
            Light::Environment => {
                let env = ctx.env?;
                let wi = uniform_sphere(u);
                Some(LightSample { wi, dist: f32::INFINITY, radiance: env.radiance(wi), pdf: 1.0 / (4.0 * PI) })
            }
            Light::Sun => {
                let sun = ctx.sun?;
                let wi = sun.sample(u);
                Some(LightSample { wi, dist: f32::INFINITY, radiance: sun.radiance, pdf: 1.0 / sun.solid_angle() })
            }
        }
    }

    /// Solid-angle pdf of an area light for a BSDF-sampled direction that hit it.
    pub fn area_pdf(shape: &Shape, dist: f32, cos_l: f32) -> f32 {
        if cos_l <= 1e-6 { 0.0 } else { dist * dist / (cos_l * shape.area()) }
    }
}
