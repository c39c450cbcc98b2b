//! Scene files: a TOML description with an `effects` list, validated so that a scene only
//! uses the effects it declares, and built into the runtime [`Scene`].

use super::bvh::Bvh;
use super::camera::Camera;
use super::geometry::{Ray, Shape, SurfaceHit, mesh};
use super::light::{Environment, Light, Sky, Sun};
use super::material::Material;
use super::texture::{Pattern, Texture};
use glam::{EulerRot, Mat4, Quat, Vec3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Effects a scene may declare; the renderer simulates only those.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Effect {
    /// Thin-lens camera (aperture > 0).
    DepthOfField,
    /// Glossy lobes: metals, plastics, rough glass.
    Glossy,
    /// Refraction through glass.
    Transmission,
    /// Light from an environment (constant or sky).
    Environment,
    /// A sun disc in the environment.
    Sun,
    /// Procedural textures other than a constant colour.
    Textures,
    /// Emissive shapes.
    AreaLights,
    /// Point and spot lights.
    PointLights,
    /// Paths beyond the first bounce; without it, direct lighting only.
    Indirect,
}

impl Effect {
    /// Every effect.
    pub const ALL: [Effect; 9] = [
        Effect::DepthOfField,
        Effect::Glossy,
        Effect::Transmission,
        Effect::Environment,
        Effect::Sun,
        Effect::Textures,
        Effect::AreaLights,
        Effect::PointLights,
        Effect::Indirect,
    ];

    /// The name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            Effect::DepthOfField => "depth_of_field",
            Effect::Glossy => "glossy",
            Effect::Transmission => "transmission",
            Effect::Environment => "environment",
            Effect::Sun => "sun",
            Effect::Textures => "textures",
            Effect::AreaLights => "area_lights",
            Effect::PointLights => "point_lights",
            Effect::Indirect => "indirect",
        }
    }
}

/// Errors in scene files and scene building.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("{path}: cannot read: {source} — check the path")]
    Read {
        /// The file.
        path: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// TOML syntax or schema error.
    #[error("{path}: {msg} — see `kpcn scenes --example` for a complete scene file")]
    Parse {
        /// The file.
        path: String,
        /// The parser's message.
        msg: String,
    },
    /// The scene uses an effect it does not declare.
    #[error("scene `{scene}`: {what} needs the `{}` effect — add \"{}\" to `effects`", effect.name(), effect.name())]
    UndeclaredEffect {
        /// Scene name.
        scene: String,
        /// What uses it.
        what: String,
        /// The effect.
        effect: Effect,
    },
    /// Anything else that makes the scene unusable.
    #[error("scene `{scene}`: {msg}")]
    Invalid {
        /// Scene name.
        scene: String,
        /// What is wrong and what to do.
        msg: String,
    },
}

/// A colour or a procedural texture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum TextureDesc {
    /// Constant RGB.
    Color([f32; 3]),
    /// A pattern.
    Texture(Texture),
}

/// Material kinds in scene files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialType {
    /// Lambert: `albedo`.
    Diffuse,
    /// Metal: `color`, `roughness` (0 = mirror).
    Conductor,
    /// Diffuse + coat: `albedo`, `roughness`.
    Plastic,
    /// Glass: `ior`, `roughness` (0 = smooth).
    Dielectric,
    /// Area light: `radiance`.
    Emissive,
}

/// A named material.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDesc {
    /// Name objects refer to.
    pub name: String,
    /// Kind.
    #[serde(rename = "type")]
    pub kind: MaterialType,
    /// Diffuse reflectance (diffuse, plastic).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub albedo: Option<TextureDesc>,
    /// Metal colour.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<[f32; 3]>,
    /// Roughness in [0, 1].
    #[serde(default)]
    pub roughness: f32,
    /// Index of refraction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ior: Option<f32>,
    /// Emitted radiance.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radiance: Option<[f32; 3]>,
}

/// Built-in shapes (unit size, centred at the origin; place them with the transform).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeKind {
    /// Radius 1.
    Sphere,
    /// 1×1 in the XZ plane, normal +Y.
    Quad,
    /// 1×1×1.
    Box,
    /// Major radius 1, minor 0.35, around Y (a triangle mesh).
    Torus,
    /// Radius 0.5, height 1, around Y (a triangle mesh).
    Cylinder,
}

/// An object: a shape, a material, a transform (scale, then rotate X→Y→Z in degrees, then translate).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDesc {
    /// Shape.
    pub shape: ShapeKind,
    /// Material name.
    pub material: String,
    /// Translation.
    #[serde(default)]
    pub translate: [f32; 3],
    /// Rotation in degrees about X, Y, Z.
    #[serde(default)]
    pub rotate: [f32; 3],
    /// Scale per axis.
    #[serde(default = "unit3")]
    pub scale: [f32; 3],
}

fn unit3() -> [f32; 3] {
    [1.0; 3]
}

/// Point and spot lights.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LightType {
    /// Omnidirectional.
    Point,
    /// A cone.
    Spot,
}

/// A point or spot light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightDesc {
    /// Kind.
    #[serde(rename = "type")]
    pub kind: LightType,
    /// Position.
    pub position: [f32; 3],
    /// Radiant intensity (RGB).
    pub intensity: [f32; 3],
    /// Spot axis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direction: Option<[f32; 3]>,
    /// Spot half-angle in degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cone_angle: Option<f32>,
}

/// The environment's kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EnvType {
    /// `color` everywhere.
    Constant,
    /// Procedural sky gradient.
    Sky,
}

/// A sun disc.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SunDesc {
    /// Degrees above the horizon.
    pub elevation: f32,
    /// Degrees around +Y (before the environment's rotation).
    pub azimuth: f32,
    /// Irradiance on a surface facing the sun (RGB).
    pub irradiance: [f32; 3],
    /// Angular diameter in degrees.
    #[serde(default = "sun_diameter")]
    pub angular_diameter: f32,
}

fn sun_diameter() -> f32 {
    2.0
}

/// The environment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvDesc {
    /// Kind.
    #[serde(rename = "type")]
    pub kind: EnvType,
    /// Radiance of a constant environment; scale of a sky.
    #[serde(default = "unit3")]
    pub color: [f32; 3],
    /// Rotation about +Y in degrees.
    #[serde(default)]
    pub rotation: f32,
    /// Optional sun.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sun: Option<SunDesc>,
}

/// The camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDesc {
    /// Eye position.
    pub position: [f32; 3],
    /// Point looked at.
    pub look_at: [f32; 3],
    /// Up vector.
    #[serde(default = "up")]
    pub up: [f32; 3],
    /// Vertical field of view in degrees.
    pub fov: f32,
    /// Lens radius; > 0 needs `depth_of_field`.
    #[serde(default)]
    pub aperture: f32,
    /// Focus distance (default: distance to `look_at`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focus_distance: Option<f32>,
}

fn up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

fn default_depth() -> u32 {
    8
}

/// A scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneDesc {
    /// Name used in output file names.
    pub name: String,
    /// Declared effects.
    #[serde(default)]
    pub effects: Vec<Effect>,
    /// Maximum path length in vertices (with `indirect`).
    #[serde(default = "default_depth")]
    pub max_depth: u32,
    /// The camera.
    pub camera: CameraDesc,
    /// Materials.
    #[serde(default)]
    pub materials: Vec<MaterialDesc>,
    /// Objects.
    #[serde(default)]
    pub objects: Vec<ObjectDesc>,
    /// Point and spot lights.
    #[serde(default)]
    pub lights: Vec<LightDesc>,
    /// Environment.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub environment: Option<EnvDesc>,
}

/// A scene ready to render.
pub struct Scene {
    /// Name.
    pub name: String,
    /// All shapes, world space.
    pub shapes: Vec<Shape>,
    /// Material of each shape.
    pub shape_material: Vec<u32>,
    /// Area-light index of each emissive shape.
    pub shape_light: Vec<Option<u32>>,
    /// Materials.
    pub materials: Vec<Material>,
    /// Lights for next-event estimation.
    pub lights: Vec<Light>,
    /// Whether the environment is among `lights`.
    pub env_light: bool,
    /// Environment.
    pub env: Option<Environment>,
    /// Sun.
    pub sun: Option<Sun>,
    /// Camera.
    pub camera: Camera,
    /// Path length limit.
    pub max_depth: u32,
    /// Whether paths continue after the first hit.
    pub indirect: bool,
    /// Declared effects.
    pub effects: Vec<Effect>,
    bvh: Bvh,
}

impl Scene {
    /// Nearest hit.
    pub fn intersect(&self, ray: &Ray) -> Option<(usize, SurfaceHit)> {
        self.bvh.intersect(&self.shapes, ray)
    }

    /// Whether the ray is blocked.
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.bvh.occluded(&self.shapes, ray)
    }
}

fn v3(a: [f32; 3]) -> Vec3 {
    Vec3::from(a)
}

impl SceneDesc {
    /// Reads a TOML scene file.
    pub fn load(path: &Path) -> Result<SceneDesc, SceneError> {
        let p = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Read { path: p.clone(), source })?;
        Self::parse(&text, &p)
    }

    /// Parses TOML text (`origin` names it in errors).
    pub fn parse(text: &str, origin: &str) -> Result<SceneDesc, SceneError> {
        toml::from_str(text)
            .map_err(|e| SceneError::Parse { path: origin.into(), msg: e.to_string().trim().replace('\n', " ") })
    }

    /// The scene as TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    fn has(&self, e: Effect) -> bool {
        self.effects.contains(&e)
    }

    fn need(&self, e: Effect, what: impl FnOnce() -> String) -> Result<(), SceneError> {
        if self.has(e) {
            Ok(())
        } else {
            Err(SceneError::UndeclaredEffect { scene: self.name.clone(), what: what(), effect: e })
        }
    }

    fn invalid(&self, msg: String) -> SceneError {
        SceneError::Invalid { scene: self.name.clone(), msg }
    }

    fn texture(&self, m: &MaterialDesc) -> Result<Texture, SceneError> {
        let t = match &m.albedo {
            None => return Err(self.invalid(format!("material `{}` needs `albedo`", m.name))),
            Some(TextureDesc::Color(c)) => Texture::constant(*c),
            Some(TextureDesc::Texture(t)) => t.clone(),
        };
        if t.pattern != Pattern::Constant {
            self.need(Effect::Textures, || format!("material `{}` ({:?} texture)", m.name, t.pattern))?;
        }
        Ok(t)
    }

    fn material(&self, m: &MaterialDesc) -> Result<Material, SceneError> {
        let glossy = |what: &str| self.need(Effect::Glossy, || format!("material `{}` ({what})", m.name));
        let roughness = m.roughness.clamp(0.0, 1.0);
        Ok(match m.kind {
            MaterialType::Diffuse => Material::Diffuse { albedo: self.texture(m)? },
            MaterialType::Conductor => {
                glossy("conductor")?;
                let color = m.color.ok_or_else(|| self.invalid(format!("material `{}` needs `color`", m.name)))?;
                Material::Conductor { color: v3(color), roughness }
            }
            MaterialType::Plastic => {
                glossy("plastic")?;
                Material::Plastic { albedo: self.texture(m)?, roughness: roughness.max(0.03) }
            }
            MaterialType::Dielectric => {
                self.need(Effect::Transmission, || format!("material `{}` (dielectric)", m.name))?;
                if roughness > 0.0 {
                    glossy("rough dielectric")?;
                }
                Material::Dielectric { ior: m.ior.unwrap_or(1.5), roughness }
            }
            MaterialType::Emissive => {
                let r = m.radiance.ok_or_else(|| self.invalid(format!("material `{}` needs `radiance`", m.name)))?;
                Material::Emissive { radiance: v3(r) }
            }
        })
    }

    /// Validates the scene against its effects and builds it for a film of `aspect`.
    pub fn build(&self, aspect: f32) -> Result<Scene, SceneError> {
        let materials: Vec<Material> = self.materials.iter().map(|m| self.material(m)).collect::<Result<_, _>>()?;
        let mut shapes = Vec::new();
        let mut shape_material = Vec::new();
        for (i, o) in self.objects.iter().enumerate() {
            let mi = self
                .materials
                .iter()
                .position(|m| m.name == o.material)
                .ok_or_else(|| self.invalid(format!("object {i} uses unknown material `{}`", o.material)))?;
            if matches!(materials[mi], Material::Emissive { .. }) {
                self.need(Effect::AreaLights, || format!("object {i} (emissive material `{}`)", o.material))?;
            }
            let r = o.rotate.map(f32::to_radians);
            let m = Mat4::from_scale_rotation_translation(
                v3(o.scale),
                Quat::from_euler(EulerRot::ZYX, r[2], r[1], r[0]),
                v3(o.translate),
            );
            let local = match o.shape {
                ShapeKind::Sphere => vec![Shape::Sphere { center: Vec3::ZERO, radius: 1.0 }],
                ShapeKind::Quad => mesh::quad(),
                ShapeKind::Box => mesh::cube(),
                ShapeKind::Torus => mesh::torus(0.35, 24),
                ShapeKind::Cylinder => mesh::cylinder(32),
            };
            for s in local {
                shapes.push(mesh::transform(&s, &m));
                shape_material.push(mi as u32);
            }
        }

        let mut lights = Vec::new();
        let mut shape_light = vec![None; shapes.len()];
        for (i, &mi) in shape_material.iter().enumerate() {
            if let Material::Emissive { radiance } = materials[mi as usize] {
                shape_light[i] = Some(lights.len() as u32);
                lights.push(Light::Area { shape: i, radiance });
            }
        }
        for l in &self.lights {
            self.need(Effect::PointLights, || format!("a {:?} light", l.kind).to_lowercase())?;
            let spot = match l.kind {
                LightType::Point => None,
                LightType::Spot => {
                    let dir = l.direction.ok_or_else(|| self.invalid("a spot light needs `direction`".into()))?;
                    let outer = l.cone_angle.unwrap_or(30.0).to_radians();
                    Some((v3(dir).normalize(), (outer * 0.8).cos(), outer.cos()))
                }
            };
            lights.push(Light::Point { position: v3(l.position), intensity: v3(l.intensity), spot });
        }
        let (mut env, mut sun, mut env_light) = (None, None, false);
        if let Some(e) = &self.environment {
            self.need(Effect::Environment, || "the environment".into())?;
            let c = v3(e.color);
            let sky = match e.kind {
                EnvType::Constant => Sky::Constant(c),
                EnvType::Sky => Sky::Gradient {
                    zenith: c * Vec3::new(0.25, 0.45, 0.95),
                    horizon: c * Vec3::new(0.85, 0.9, 1.0),
                    ground: c * Vec3::new(0.18, 0.16, 0.14),
                },
            };
            env = Some(Environment { sky, rotation: e.rotation.to_radians() });
            lights.push(Light::Environment);
            env_light = true;
            if let Some(s) = &e.sun {
                self.need(Effect::Sun, || "the environment's sun".into())?;
                let (el, az) = (s.elevation.to_radians(), (s.azimuth + e.rotation).to_radians());
                let dir = Vec3::new(el.cos() * az.cos(), el.sin(), el.cos() * az.sin());
                let cos_max = (s.angular_diameter.to_radians() * 0.5).cos();
                let mut sn = Sun { dir, radiance: Vec3::ZERO, cos_max };
                sn.radiance = v3(s.irradiance) / sn.solid_angle();
                sun = Some(sn);
                lights.push(Light::Sun);
            }
        }
        if lights.is_empty() {
            return Err(
                self.invalid("the scene has no light: add an emissive object, a light or an environment".into())
            );
        }

        let c = &self.camera;
        if c.aperture > 0.0 {
            self.need(Effect::DepthOfField, || format!("the camera's aperture {}", c.aperture))?;
        }
        let focus = c.focus_distance.unwrap_or_else(|| (v3(c.look_at) - v3(c.position)).length());
        let camera = Camera::new(v3(c.position), v3(c.look_at), v3(c.up), c.fov, aspect, c.aperture, focus);
        let indirect = self.has(Effect::Indirect);
        Ok(Scene {
            name: self.name.clone(),
            bvh: Bvh::build(&shapes),
            shapes,
            shape_material,
            shape_light,
            materials,
            lights,
            env_light,
            env,
            sun,
            camera,
            max_depth: if indirect { self.max_depth.max(1) } else { 1 },
            indirect,
            effects: self.effects.clone(),
        })
    }
}
