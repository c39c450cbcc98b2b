//! Materials and their BSDFs, evaluated in the local shading frame (normal = +z).
//!
//! Each lobe is labelled diffuse or glossy so the film can split radiance into the
//! `diffuse` and `specular` buffers of ARCHITECTURE.md §Layout.

use super::geometry::cosine_hemisphere;
use super::texture::Texture;
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI};

/// A surface material, resolved for rendering.
#[derive(Debug, Clone)]
pub enum Material {
    /// Lambertian reflector.
    Diffuse {
        /// Reflectance.
        albedo: Texture,
    },
    /// Rough (GGX) or perfectly smooth (roughness 0) metal.
    Conductor {
        /// Reflectance at normal incidence.
        color: Vec3,
        /// Perceptual roughness; alpha = roughness².
        roughness: f32,
    },
    /// Diffuse base under a GGX dielectric coat (F0 = 0.04).
    Plastic {
        /// Base reflectance.
        albedo: Texture,
        /// Coat roughness (> 0).
        roughness: f32,
    },
    /// Glass: smooth (roughness 0) or rough (GGX, Walter et al. 2007).
    Dielectric {
        /// Index of refraction.
        ior: f32,
        /// Roughness.
        roughness: f32,
    },
    /// A black emitter (area light).
    Emissive {
        /// Emitted radiance.
        radiance: Vec3,
    },
}

/// Which buffer a lobe's light goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lobe {
    /// The diffuse lobe.
    Diffuse,
    /// Anything else.
    Glossy,
}

/// A sampled direction.
#[derive(Debug, Clone, Copy)]
pub struct BsdfSample {
    /// Incident direction (local).
    pub wi: Vec3,
    /// f · |cos| / pdf.
    pub weight: Vec3,
    /// Solid-angle pdf; 0 for delta lobes (no MIS).
    pub pdf: f32,
    /// The lobe sampled.
    pub lobe: Lobe,
}

/// BSDF values split by lobe.
#[derive(Debug, Clone, Copy, Default)]
pub struct BsdfValue {
    /// Diffuse part of f.
    pub diffuse: Vec3,
    /// Glossy part of f.
    pub glossy: Vec3,
}

/// A material at one surface point (textures resolved).
#[derive(Debug, Clone, Copy)]
pub enum Bsdf {
    /// Lambert.
    Diffuse(Vec3),
    /// GGX metal (alpha) or mirror (alpha 0).
    Conductor(Vec3, f32),
    /// Lambert + GGX coat.
    Plastic(Vec3, f32),
    /// Glass.
    Dielectric(f32, f32),
    /// Emitters do not scatter.
    Black,
}

const PLASTIC_F0: f32 = 0.04;
const PLASTIC_GLOSSY_PROB: f32 = 0.5;

impl Material {
    /// The BSDF at world position `p`.
    pub fn at(&self, p: Vec3) -> Bsdf {
        match self {
            Material::Diffuse { albedo } => Bsdf::Diffuse(albedo.eval(p)),
            Material::Conductor { color, roughness } => Bsdf::Conductor(*color, roughness * roughness),
            Material::Plastic { albedo, roughness } => Bsdf::Plastic(albedo.eval(p), (roughness * roughness).max(1e-3)),
            Material::Dielectric { ior, roughness } => Bsdf::Dielectric(*ior, roughness * roughness),
            Material::Emissive { .. } => Bsdf::Black,
        }
    }

    /// Emitted radiance.
    pub fn emission(&self) -> Vec3 {
        match self {
            Material::Emissive { radiance } => *radiance,
            _ => Vec3::ZERO,
        }
    }
}

fn ggx_d(h: Vec3, a: f32) -> f32 {
    let a2 = a * a;
    let c2 = h.z * h.z;
    let d = c2 * (a2 - 1.0) + 1.0;
    a2 / (PI * d * d)
}

fn ggx_g1(v: Vec3, a: f32) -> f32 {
    let c2 = v.z * v.z;
    if c2 <= 0.0 {
        return 0.0;
    }
    let t2 = (1.0 - c2) / c2;
    2.0 / (1.0 + (1.0 + a * a * t2).sqrt())
}

fn ggx_sample_h(a: f32, u: [f32; 2]) -> Vec3 {
    let t2 = a * a * u[0] / (1.0 - u[0]).max(1e-7);
    let cos = 1.0 / (1.0 + t2).sqrt();
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let phi = 2.0 * PI * u[1];
    Vec3::new(sin * phi.cos(), sin * phi.sin(), cos)
}

fn schlick(f0: Vec3, c: f32) -> Vec3 {
    f0 + (Vec3::ONE - f0) * (1.0 - c.clamp(0.0, 1.0)).powi(5)
}

/// Unpolarised Fresnel reflectance of a dielectric; `eta` = n_t / n_i.
fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let sin_t2 = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin_t2 >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin_t2).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
}

fn reflect(wo: Vec3, h: Vec3) -> Vec3 {
    2.0 * wo.dot(h) * h - wo
}

/// Refraction of `wo` through the microfacet `h` (on wo's side); `eta` = n_t / n_i.
fn refract(wo: Vec3, h: Vec3, eta: f32) -> Option<Vec3> {
    let c = wo.dot(h);
    let sin_t2 = (1.0 - c * c).max(0.0) / (eta * eta);
    if sin_t2 >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin_t2).sqrt();
    Some((-wo / eta + (c / eta - cos_t) * h).normalize())
}

/// Counts lobe work so tests can prove undeclared effects cost nothing.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct LobeCounters {
    /// Glossy lobe evaluations and samples.
    pub glossy: u64,
    /// Transmission events sampled.
    pub transmission: u64,
}

impl Bsdf {
    /// Diffuse reflectance for the albedo feature (0 for metal, glass, emitters).
    pub fn albedo(&self) -> Vec3 {
        match *self {
            Bsdf::Diffuse(a) | Bsdf::Plastic(a, _) => a,
            _ => Vec3::ZERO,
        }
    }

    /// Whether light sampling can help (the BSDF has a non-delta lobe).
    pub fn has_smooth_lobe(&self) -> bool {
        match *self {
            Bsdf::Diffuse(_) | Bsdf::Plastic(..) => true,
            Bsdf::Conductor(_, a) => a > 0.0,
            // Rough glass is sampled only: its transmission makes light sampling rarely useful.
            Bsdf::Dielectric(..) | Bsdf::Black => false,
        }
    }

    /// f(wo, wi), split by lobe. Reflection only (glass is never evaluated).
    pub fn eval(&self, wo: Vec3, wi: Vec3, c: &mut LobeCounters) -> BsdfValue {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return BsdfValue::default();
        }
        match *self {
            Bsdf::Diffuse(a) => BsdfValue { diffuse: a * FRAC_1_PI, glossy: Vec3::ZERO },
            Bsdf::Conductor(f0, a) if a > 0.0 => {
                c.glossy += 1;
                BsdfValue { diffuse: Vec3::ZERO, glossy: microfacet_reflection(wo, wi, a, |ch| schlick(f0, ch)) }
            }
            Bsdf::Plastic(albedo, a) => {
                c.glossy += 1;
                let coat = microfacet_reflection(wo, wi, a, |ch| schlick(Vec3::splat(PLASTIC_F0), ch));
                let base = (1.0 - PLASTIC_F0) * albedo * FRAC_1_PI;
                BsdfValue { diffuse: base, glossy: coat }
            }
            _ => BsdfValue::default(),
        }
    }

    /// Solid-angle pdf of sampling `wi` from `wo`.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let glossy = |a: f32| {
            let h = (wo + wi).normalize();
            ggx_d(h, a) * h.z / (4.0 * wo.dot(h).abs())
        };
        match *self {
            Bsdf::Diffuse(_) => wi.z * FRAC_1_PI,
            Bsdf::Conductor(_, a) if a > 0.0 => glossy(a),
            Bsdf::Plastic(_, a) => PLASTIC_GLOSSY_PROB * glossy(a) + (1.0 - PLASTIC_GLOSSY_PROB) * wi.z * FRAC_1_PI,
            _ => 0.0,
        }
    }

    /// Samples an incident direction. `wo` may lie below the surface only for glass.
    pub fn sample(&self, wo: Vec3, u: [f32; 3], c: &mut LobeCounters) -> Option<BsdfSample> {
        match *self {
            Bsdf::Diffuse(a) => {
                if wo.z <= 0.0 {
                    return None;
                }
                let wi = cosine_hemisphere([u[0], u[1]]);
                Some(BsdfSample { wi, weight: a, pdf: wi.z * FRAC_1_PI, lobe: Lobe::Diffuse })
            }
            Bsdf::Conductor(f0, a) => {
                if wo.z <= 0.0 {
                    return None;
                }
                c.glossy += 1;
                if a == 0.0 {
                    let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                    return Some(BsdfSample { wi, weight: schlick(f0, wo.z), pdf: 0.0, lobe: Lobe::Glossy });
                }
                let h = ggx_sample_h(a, [u[0], u[1]]);
                let wi = reflect(wo, h);
                if wi.z <= 0.0 {
                    return None;
                }
                let f = self.eval(wo, wi, c).glossy;
                let pdf = self.pdf(wo, wi);
                (pdf > 0.0).then(|| BsdfSample { wi, weight: f * wi.z / pdf, pdf, lobe: Lobe::Glossy })
            }
            Bsdf::Plastic(_, a) => {
                if wo.z <= 0.0 {
                    return None;
                }
                let (wi, lobe) = if u[2] < PLASTIC_GLOSSY_PROB {
                    (reflect(wo, ggx_sample_h(a, [u[0], u[1]])), Lobe::Glossy)
                } else {
                    (cosine_hemisphere([u[0], u[1]]), Lobe::Diffuse)
                };
                if wi.z <= 0.0 {
                    return None;
                }
                let f = self.eval(wo, wi, c);
                let pdf = self.pdf(wo, wi);
                (pdf > 0.0).then(|| BsdfSample { wi, weight: (f.diffuse + f.glossy) * wi.z / pdf, pdf, lobe })
            }
            Bsdf::Dielectric(ior, a) => sample_dielectric(wo, ior, a, u, c),
            Bsdf::Black => None,
        }
    }
}

/// Torrance–Sparrow reflection with GGX and a Fresnel term of `cos(wo, h)`.
fn microfacet_reflection(wo: Vec3, wi: Vec3, a: f32, fresnel: impl Fn(f32) -> Vec3) -> Vec3 {
    let h = (wo + wi).normalize();
    let d = ggx_d(h, a);
    let g = ggx_g1(wo, a) * ggx_g1(wi, a);
    fresnel(wo.dot(h)) * (d * g / (4.0 * wo.z * wi.z))
}

/// Glass: Fresnel picks reflection or refraction; rough glass samples a GGX microfacet first
/// and weights by G·|wo·h| / (|wo·n| |h·n|) (Walter et al. 2007, eq. 41).
fn sample_dielectric(wo: Vec3, ior: f32, a: f32, u: [f32; 3], c: &mut LobeCounters) -> Option<BsdfSample> {
    let entering = wo.z > 0.0;
    let eta = if entering { ior } else { 1.0 / ior };
    // Work on wo's side of the surface.
    let flip = |v: Vec3| if entering { v } else { -v };
    let wo_l = flip(wo);
    let h = if a > 0.0 {
        c.glossy += 1;
        ggx_sample_h(a, [u[0], u[1]])
    } else {
        Vec3::Z
    };
    let cos_o = wo_l.dot(h);
    if cos_o <= 0.0 {
        return None;
    }
    let f = fresnel_dielectric(cos_o, eta);
    let (wi, transmitted) = if u[2] < f {
        (reflect(wo_l, h), false)
    } else {
        match refract(wo_l, h, eta) {
            Some(t) => (t, true),
            None => (reflect(wo_l, h), false),
        }
    };
    if transmitted {
        c.transmission += 1;
    }
    // Reflection must stay on wo's side, transmission must cross.
    if (wi.z > 0.0) == transmitted || wi.z == 0.0 {
        return None;
    }
    let weight = if a > 0.0 {
        let g = ggx_g1(wo_l, a) * ggx_g1(wi, a);
        g * cos_o / (wo_l.z * h.z)
    } else {
        1.0
    };
    Some(BsdfSample { wi: flip(wi), weight: Vec3::splat(weight.max(0.0)), pdf: 0.0, lobe: Lobe::Glossy })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::rng::Rng;

    /// ∫ f cos over the hemisphere by importance sampling.
    fn albedo_estimate(b: &Bsdf, wo: Vec3, n: usize) -> Vec3 {
        let mut rng = Rng::for_sample(3, 4, 5);
        let mut c = LobeCounters::default();
        let mut sum = Vec3::ZERO;
        for _ in 0..n {
            if let Some(s) = b.sample(wo, [rng.uniform(), rng.uniform(), rng.uniform()], &mut c) {
                sum += s.weight;
            }
        }
        sum / n as f32
    }

    #[test]
    fn lambert_reflects_its_albedo() {
        let wo = Vec3::new(0.3, 0.1, 0.9).normalize();
        let a = albedo_estimate(&Bsdf::Diffuse(Vec3::splat(0.7)), wo, 1000);
        assert!((a - Vec3::splat(0.7)).abs().max_element() < 1e-5, "{a}");
    }

    #[test]
    fn sampled_weights_match_eval_over_pdf() {
        let wo = Vec3::new(0.4, -0.2, 0.8).normalize();
        let mut rng = Rng::for_sample(9, 9, 9);
        let mut c = LobeCounters::default();
        for b in [Bsdf::Conductor(Vec3::new(0.9, 0.6, 0.3), 0.3), Bsdf::Plastic(Vec3::splat(0.5), 0.2)] {
            for _ in 0..200 {
                let Some(s) = b.sample(wo, [rng.uniform(), rng.uniform(), rng.uniform()], &mut c) else { continue };
                let f = b.eval(wo, s.wi, &mut c);
                let expect = (f.diffuse + f.glossy) * s.wi.z / b.pdf(wo, s.wi);
                assert!((expect - s.weight).abs().max_element() < 1e-3 * (1.0 + expect.max_element()));
            }
        }
    }

    #[test]
    fn rough_metal_conserves_energy_and_is_near_white_furnace_at_low_roughness() {
        let wo = Vec3::new(0.0, 0.0, 1.0);
        let a = albedo_estimate(&Bsdf::Conductor(Vec3::ONE, 0.05), wo, 20000);
        assert!(a.x > 0.95 && a.x <= 1.01, "{a}");
    }

    #[test]
    fn smooth_glass_transmits_most_light_at_normal_incidence() {
        let mut c = LobeCounters::default();
        let (mut t, n) = (0, 10000);
        let mut rng = Rng::for_sample(1, 1, 1);
        for _ in 0..n {
            let s = Bsdf::Dielectric(1.5, 0.0).sample(Vec3::Z, [rng.uniform(), rng.uniform(), rng.uniform()], &mut c);
            if s.unwrap().wi.z < 0.0 {
                t += 1;
            }
        }
        // Fresnel at normal incidence for n = 1.5: R = 0.04.
        assert!((t as f32 / n as f32 - 0.96).abs() < 0.01, "{t}");
    }
}
