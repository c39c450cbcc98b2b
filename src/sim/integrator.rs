//! The path tracer: next-event estimation with multiple importance sampling (power
//! heuristic), Russian roulette, and the per-sample KPCN features of ARCHITECTURE.md §Layout.

use super::geometry::{Frame, RAY_EPSILON, Ray};
use super::light::{Light, LightContext};
use super::material::{Bsdf, Lobe, LobeCounters};
use super::rng::Rng;
use super::scene::Scene;
use glam::Vec3;

/// Values recorded per sample, in this order.
pub const SAMPLE_LEN: usize = 17;
/// Offsets into a sample: color, diffuse, specular, albedo, normal (3 each), depth, visibility.
pub const COLOR: usize = 0;
/// Diffuse offset.
pub const DIFFUSE: usize = 3;
/// Specular offset.
pub const SPECULAR: usize = 6;
/// Albedo offset.
pub const ALBEDO: usize = 9;
/// Normal offset.
pub const NORMAL: usize = 12;
/// Depth offset.
pub const DEPTH: usize = 15;
/// Visibility offset.
pub const VISIBILITY: usize = 16;

/// Work counters, for tests that prove undeclared effects cost nothing.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Counters {
    /// Closest-hit rays.
    pub rays: u64,
    /// Shadow rays.
    pub shadow_rays: u64,
    /// Lens samples drawn.
    pub lens_samples: u64,
    /// Lobe work.
    pub lobes: LobeCounters,
}

impl Counters {
    /// Adds another set.
    pub fn add(&mut self, o: &Counters) {
        self.rays += o.rays;
        self.shadow_rays += o.shadow_rays;
        self.lens_samples += o.lens_samples;
        self.lobes.glossy += o.lobes.glossy;
        self.lobes.transmission += o.lobes.transmission;
    }
}

fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 == 0.0 { 0.0 } else { a2 / (a2 + b2) }
}

/// Renders one sample through film position (`sx`, `sy`).
pub fn trace(scene: &Scene, sx: f32, sy: f32, rng: &mut Rng, nee: bool, c: &mut Counters) -> [f32; SAMPLE_LEN] {
    let mut out = [0f32; SAMPLE_LEN];
    let lens = if scene.camera.is_thin_lens() {
        c.lens_samples += 1;
        Some(rng.uniform2())
    } else {
        None
    };
    let mut ray = scene.camera.ray(sx, sy, lens);
    let ctx = LightContext { shapes: &scene.shapes, env: scene.env.as_ref(), sun: scene.sun.as_ref() };
    let n_lights = scene.lights.len() as f32;

    let mut diffuse = Vec3::ZERO;
    let mut specular = Vec3::ZERO;
    // Throughput after the first bounce; the first bounce's weight is kept per lobe
    // (f_lobe · cos / pdf), which makes both buffers unbiased for mixed materials.
    // At the camera everything counts as specular (emitters and background seen directly).
    let mut throughput = Vec3::ONE;
    let mut first = FirstBounce { diffuse: Vec3::ZERO, glossy: Vec3::ONE };
    // Solid-angle pdf of the last BSDF sample (0 after a delta lobe or at the camera).
    let mut last_pdf = 0f32;

    for depth in 0..scene.max_depth {
        c.rays += 1;
        let Some((shape, hit)) = scene.intersect(&ray) else {
            // Escaped: environment and sun, MIS-weighted against light sampling.
            let mut l = Vec3::ZERO;
            if let Some(env) = &scene.env {
                let w = if nee && last_pdf > 0.0 && scene.env_light {
                    power_heuristic(last_pdf, 1.0 / (4.0 * std::f32::consts::PI) / n_lights)
                } else {
                    1.0
                };
                l += w * env.radiance(ray.dir);
            }
            if let Some(sun) = &scene.sun
                && ray.dir.dot(sun.dir) >= sun.cos_max
            {
                let w = if nee && last_pdf > 0.0 {
                    power_heuristic(last_pdf, 1.0 / sun.solid_angle() / n_lights)
                } else {
                    1.0
                };
                l += w * sun.radiance;
            }
            first.add(&mut diffuse, &mut specular, throughput * l);
            break;
        };
        let material = &scene.materials[scene.shape_material[shape] as usize];
        let front = hit.ng.dot(ray.dir) < 0.0;
        let ns = if front { hit.ns } else { -hit.ns };
        let bsdf = material.at(hit.p);
        if depth == 0 {
            out[ALBEDO..ALBEDO + 3].copy_from_slice(&bsdf.albedo().to_array());
            out[NORMAL..NORMAL + 3].copy_from_slice(&hit.ns.to_array());
            out[DEPTH] = hit.t;
        }
        let emitted = material.emission();
        if emitted != Vec3::ZERO {
            // Emitters are one-sided (front) and black.
            if front {
                let w = match scene.shape_light[shape] {
                    Some(_) if nee && last_pdf > 0.0 => {
                        let pdf_l = Light::area_pdf(&scene.shapes[shape], hit.t, hit.ng.dot(-ray.dir).abs()) / n_lights;
                        power_heuristic(last_pdf, pdf_l)
                    }
                    _ => 1.0,
                };
                first.add(&mut diffuse, &mut specular, throughput * emitted * w);
            }
            break;
        }
        let frame = Frame::new(if matches!(bsdf, Bsdf::Dielectric(..)) { hit.ns } else { ns });
        let wo = frame.to_local(-ray.dir);
        let p = hit.p;

        // Next-event estimation.
        if nee && bsdf.has_smooth_lobe() && !scene.lights.is_empty() {
            let pick = ((rng.uniform() * n_lights) as usize).min(scene.lights.len() - 1);
            let light = &scene.lights[pick];
            let u = rng.uniform2();
            if let Some(ls) = light.sample(&ctx, p, u) {
                let wi = frame.to_local(ls.wi);
                let f = bsdf.eval(wo, wi, &mut c.lobes);
                if wi.z > 0.0 && (f.diffuse + f.glossy) != Vec3::ZERO && ls.radiance != Vec3::ZERO {
                    c.shadow_rays += 1;
                    let offset = if ls.wi.dot(ns) >= 0.0 { ns } else { -ns };
                    let shadow = Ray { origin: p + offset * RAY_EPSILON, dir: ls.wi, t_max: ls.dist * (1.0 - 1e-3) };
                    let visible = !scene.occluded(&shadow);
                    if depth == 0 {
                        out[VISIBILITY] = visible as u8 as f32;
                    }
                    if visible {
                        let pdf_l = ls.pdf / n_lights;
                        let (w, scale) = if ls.pdf == 0.0 {
                            (1.0, n_lights)
                        } else {
                            (power_heuristic(pdf_l, bsdf.pdf(wo, wi)), 1.0 / pdf_l)
                        };
                        let k = throughput * ls.radiance * (wi.z * w * scale);
                        if depth == 0 {
                            diffuse += f.diffuse * k;
                            specular += f.glossy * k;
                        } else {
                            first.add(&mut diffuse, &mut specular, (f.diffuse + f.glossy) * k);
                        }
                    }
                }
            }
        }
        if !scene.indirect || depth + 1 == scene.max_depth {
            break;
        }

        // The direction's two numbers form one pair (stratified in 2D by the Sobol' sampler).
        let [u0, u1] = rng.uniform2();
        let Some(s) = bsdf.sample(wo, [u0, u1, rng.uniform()], &mut c.lobes) else { break };
        if depth == 0 {
            first = if s.pdf > 0.0 && matches!(bsdf, Bsdf::Plastic(..)) {
                let f = bsdf.eval(wo, s.wi, &mut c.lobes);
                let k = s.wi.z / s.pdf;
                FirstBounce { diffuse: f.diffuse * k, glossy: f.glossy * k }
            } else if s.lobe == Lobe::Diffuse {
                FirstBounce { diffuse: s.weight, glossy: Vec3::ZERO }
            } else {
                FirstBounce { diffuse: Vec3::ZERO, glossy: s.weight }
            };
        } else {
            throughput *= s.weight;
        }
        last_pdf = s.pdf;
        let wi = frame.to_world(s.wi);
        let offset = if wi.dot(hit.ng) >= 0.0 { hit.ng } else { -hit.ng };
        ray = Ray::new(p + offset * RAY_EPSILON, wi);

        // Russian roulette after a few bounces.
        if depth >= 3 {
            let q = (throughput * (first.diffuse + first.glossy)).max_element().clamp(0.05, 0.95);
            if rng.uniform() >= q {
                break;
            }
            throughput /= q;
        }
        if throughput == Vec3::ZERO || first.diffuse + first.glossy == Vec3::ZERO {
            break;
        }
    }
    let color = diffuse + specular;
    out[COLOR..COLOR + 3].copy_from_slice(&color.to_array());
    out[DIFFUSE..DIFFUSE + 3].copy_from_slice(&diffuse.to_array());
    out[SPECULAR..SPECULAR + 3].copy_from_slice(&specular.to_array());
    out
}

/// The first bounce's weight split by lobe.
struct FirstBounce {
    diffuse: Vec3,
    glossy: Vec3,
}

impl FirstBounce {
    /// Adds light `l` arriving after the first bounce (already multiplied by the later
    /// throughput) to both buffers.
    fn add(&self, diffuse: &mut Vec3, specular: &mut Vec3, l: Vec3) {
        *diffuse += self.diffuse * l;
        *specular += self.glossy * l;
    }
}
