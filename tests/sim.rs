//! The simulator against physics and its own contract (small images, fixed seeds).

use kpcn::io::FrameBuffers;
use kpcn::sim::integrator::Counters;
use kpcn::sim::rng::Sampler;
use kpcn::sim::scene::{Effect, SceneDesc, SceneError};
use kpcn::sim::{RenderOptions, render};

fn scene(toml: &str) -> SceneDesc {
    SceneDesc::parse(toml, "test").unwrap()
}

fn opts(w: usize, h: usize, spp: &[u32], seed: u64) -> RenderOptions {
    RenderOptions::new(w, h, spp.to_vec(), seed)
}

fn run(desc: &SceneDesc, o: &RenderOptions) -> (Vec<FrameBuffers>, Counters) {
    let s = desc.build(o.width as f32 / o.height as f32).unwrap();
    let out = render(&s, o, &[], &|_| {}).unwrap();
    (out.frames.into_iter().map(|f| f.1).collect(), out.counters)
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
}

/// A diffuse sphere and a floor under an area light and a dim constant environment.
const BASE: &str = r#"
name = "base"
effects = ["area_lights", "environment", "indirect"]
[camera]
position = [0, 1, 4]
look_at = [0, 0.5, 0]
fov = 40
[[materials]]
name = "white"
type = "diffuse"
albedo = [0.7, 0.7, 0.7]
[[materials]]
name = "light"
type = "emissive"
radiance = [4, 4, 4]
[[objects]]
shape = "sphere"
material = "white"
translate = [0, 0.5, 0]
scale = [0.5, 0.5, 0.5]
[[objects]]
shape = "quad"
material = "white"
scale = [6, 1, 6]
[[objects]]
shape = "quad"
material = "light"
translate = [0, 3, 0]
rotate = [180, 0, 0]
scale = [2, 1, 2]
[environment]
type = "constant"
color = [0.2, 0.2, 0.2]
"#;

#[test]
fn white_furnace_converges_to_the_environment_radiance() {
    let d = scene(
        r#"
name = "furnace"
effects = ["environment", "indirect"]
max_depth = 64
[camera]
position = [0, 0, 3]
look_at = [0, 0, 0]
fov = 30
[[materials]]
name = "white"
type = "diffuse"
albedo = [1, 1, 1]
[[objects]]
shape = "sphere"
material = "white"
[environment]
type = "constant"
color = [0.5, 0.5, 0.5]
"#,
    );
    let (frames, _) = run(&d, &opts(12, 12, &[64], 1));
    let f = &frames[0];
    let p = f.width() * f.height();
    let m = mean(f.channel("R").unwrap());
    // Standard error of the frame mean from the written per-pixel variances.
    let se = (mean(f.channel("colorVariance.Z").unwrap()) / p as f64).sqrt();
    assert!((m - 0.5).abs() < 4.0 * se + 1e-6, "mean {m}, 4σ = {}", 4.0 * se);
    assert!(se < 0.01, "the estimate is precise enough to mean something: σ = {se}");
}

#[test]
fn color_is_exactly_diffuse_plus_specular() {
    let d = kpcn::sim::families::generate("product", 2).unwrap();
    let (frames, _) = run(&d, &opts(24, 14, &[4], 3));
    let f = &frames[0];
    for c in ["R", "G", "B"] {
        let (col, dif, spe) = (
            f.channel(c).unwrap(),
            f.channel(&format!("diffuse.{c}")).unwrap(),
            f.channel(&format!("specular.{c}")).unwrap(),
        );
        for i in 0..col.len() {
            assert_eq!(col[i], dif[i] + spe[i], "pixel {i} channel {c}");
        }
    }
    // A glossy scene puts light in both buffers.
    assert!(mean(f.channel("specular.G").unwrap()) > 0.0 && mean(f.channel("diffuse.G").unwrap()) > 0.0);
}

#[test]
fn albedo_normal_and_depth_match_analytic_values() {
    let d = scene(
        r#"
name = "plane"
effects = ["environment"]
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
fov = 20
[[materials]]
name = "paint"
type = "diffuse"
albedo = [0.3, 0.5, 0.7]
[[objects]]
shape = "quad"
material = "paint"
rotate = [90, 0, 0]
scale = [1.5, 1, 1.5]
[[objects]]
shape = "sphere"
material = "paint"
translate = [0, 0, 1]
scale = [0.2, 0.2, 0.2]
[environment]
type = "constant"
"#,
    );
    let (w, h) = (41, 41);
    let (frames, _) = run(&d, &opts(w, h, &[8], 5));
    let f = &frames[0];
    let at = |name: &str, x: usize, y: usize| f.channel(name).unwrap()[y * w + x];
    // Centre pixel: the sphere's front at distance 5 − 1 − 0.2 = 3.8, normal +z.
    assert!((at("depth.Z", 20, 20) - 3.8).abs() < 2e-3, "{}", at("depth.Z", 20, 20));
    // The pixel spans ±0.016 units on a sphere of radius 0.2: normals tilt by up to 0.08 rad.
    assert!(at("normal.B", 20, 20) > 0.99);
    // A pixel on the plane beside the sphere: depth 5 / cos θ, normal exactly +z.
    let (x, y) = (20, 6);
    let tan = (10f32.to_radians()).tan();
    let (sx, sy) = ((x as f32 + 0.5) / w as f32 * 2.0 - 1.0, 1.0 - (y as f32 + 0.5) / h as f32 * 2.0);
    let dir = glam::Vec3::new(sx * tan, sy * tan, -1.0).normalize();
    let expect = 5.0 / dir.z.abs();
    assert!((at("depth.Z", x, y) - expect).abs() < 2e-3, "{} vs {expect}", at("depth.Z", x, y));
    let n = glam::Vec3::new(at("normal.R", x, y), at("normal.G", x, y), at("normal.B", x, y));
    assert!((n - glam::Vec3::Z).abs().max_element() < 1e-6, "{n}");
    assert_eq!([at("albedo.R", x, y), at("albedo.G", x, y), at("albedo.B", x, y)], [0.3, 0.5, 0.7]);
    assert_eq!(at("albedoVariance.Z", x, y), 0.0);
    // A corner pixel misses everything: zeros, as ARCHITECTURE.md §Layout says.
    for c in ["depth.Z", "normal.B", "albedo.R"] {
        assert_eq!(at(c, 0, 0), 0.0, "{c}");
    }
    assert!((at("R", 0, 0) - 1.0).abs() < 1e-6, "the environment seen directly");
}

#[test]
fn written_variance_is_unbiased_across_independent_seeds_whatever_the_sampler() {
    // Issue 24: with one Sobol' scramble per pixel the written variance was 2.4–9.5× the
    // real one; the spread of independent scrambles' means is not.
    let d = scene(BASE);
    let (w, h, k) = (8, 6, 40usize);
    for sampler in [Sampler::Random, Sampler::Sobol] {
        for spp in [4, 16, 64] {
            let o = |seed| RenderOptions { sampler, ..opts(w, h, &[spp], seed) };
            let frames: Vec<FrameBuffers> = (0..k as u64).map(|s| run(&d, &o(100 + s)).0.remove(0)).collect();
            let (mut empirical, mut written) = (0f64, 0f64);
            for i in 0..w * h {
                for c in ["R", "G", "B"] {
                    let xs: Vec<f64> = frames.iter().map(|f| f.channel(c).unwrap()[i] as f64).collect();
                    let m = xs.iter().sum::<f64>() / k as f64;
                    empirical += xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (k - 1) as f64 / 3.0;
                }
                written +=
                    frames.iter().map(|f| f.channel("colorVariance.Z").unwrap()[i] as f64).sum::<f64>() / k as f64;
            }
            let ratio = empirical / written;
            // Relative standard deviation of a variance estimate from K samples, over P pixels.
            let tol = 5.0 * (2.0 / ((k - 1) as f64 * (w * h) as f64)).sqrt();
            println!("{} {spp} spp: empirical / written = {ratio:.3}", sampler.name());
            assert!(
                (ratio - 1.0).abs() < tol,
                "{} {spp} spp: empirical / written = {ratio:.3}, tolerance {tol:.3}",
                sampler.name()
            );
        }
    }
}

/// Per-pixel variance across independent seeds, and the pooled mean, of `o` on BASE.
fn spread_across_seeds(o: impl Fn(u64) -> RenderOptions, k: u64) -> (f64, f64, f64) {
    let d = scene(BASE);
    let frames: Vec<FrameBuffers> = (0..k).map(|s| run(&d, &o(200 + s)).0.remove(0)).collect();
    let p = frames[0].width() * frames[0].height();
    let (mut var, mut sum, mut written) = (0f64, 0f64, 0f64);
    for i in 0..p {
        let xs: Vec<f64> = frames.iter().map(|f| f.channel("G").unwrap()[i] as f64).collect();
        let m = xs.iter().sum::<f64>() / k as f64;
        var += xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (k - 1) as f64;
        sum += m;
        written += frames.iter().map(|f| f.channel("colorVariance.Z").unwrap()[i] as f64).sum::<f64>() / k as f64;
    }
    (var / p as f64, sum / p as f64, written / p as f64)
}

#[test]
fn sobol_sampler_is_unbiased_and_less_noisy_than_random_at_equal_spp() {
    let sobol = |seed| RenderOptions { sampler: Sampler::Sobol, ..opts(8, 6, &[16], seed) };
    let (v_random, m_random, _) = spread_across_seeds(|seed| opts(8, 6, &[16], seed), 32);
    let (v_sobol, m_sobol, written) = spread_across_seeds(sobol, 32);
    assert!(v_sobol < 0.8 * v_random, "variance sobol {v_sobol:.3e} vs random {v_random:.3e}");
    // Same expectation: the pooled means agree within 5 standard errors.
    let se = ((v_random + v_sobol) / (32.0 * 48.0)).sqrt();
    assert!((m_sobol - m_random).abs() < 5.0 * se, "means {m_sobol} vs {m_random}, se {se}");
    // The written variance comes from the scrambles' spread: it says the same.
    assert!((written / v_sobol - 1.0).abs() < 0.35, "written {written:.3e} against the true {v_sobol:.3e}");
}

#[test]
fn production_sampling_is_recorded_and_box_random_is_the_original_sampling() {
    let d = scene(BASE);
    let dir = tempfile::tempdir().unwrap();
    let o = RenderOptions::production(8, 6, vec![4], 1);
    let w = kpcn::sim::render_to_dir(&d, &o, None, dir.path(), &Default::default(), &|_| {}).unwrap();
    let f = FrameBuffers::read(&w.noisy[0].1).unwrap();
    assert_eq!(f.attribute("kpcn:pixel_filter"), Some("blackman-harris:1.5"));
    assert_eq!(f.attribute("kpcn:sampler"), Some("sobol"));
    // The wide filter and the other sample placement give a different frame.
    let boxed = run(&d, &opts(8, 6, &[4], 1)).0.remove(0);
    assert_ne!(f.channel("G").unwrap(), boxed.channel("G").unwrap());
}

#[test]
fn nee_with_mis_matches_brute_force_path_tracing() {
    let mut d = scene(BASE);
    d.effects.push(Effect::Glossy);
    d.materials[0].kind = kpcn::sim::scene::MaterialType::Plastic;
    d.materials[0].roughness = 0.3;
    let (w, h) = (10, 8);
    let with = run(&d, &opts(w, h, &[256], 7)).0.remove(0);
    let mut brute = opts(w, h, &[1024], 8);
    brute.nee = false;
    let without = run(&d, &brute).0.remove(0);
    let p = (w * h) as f64;
    for c in ["R", "specular.G", "diffuse.B"] {
        let (a, b) = (mean(with.channel(c).unwrap()), mean(without.channel(c).unwrap()));
        let var = |f: &FrameBuffers| {
            let q = c.split('.').next().filter(|q| q.len() > 1).unwrap_or("color");
            mean(f.channel(&format!("{q}Variance.Z")).unwrap()) / p
        };
        let se = (var(&with) + var(&without)).sqrt();
        assert!((a - b).abs() < 4.0 * se, "{c}: NEE {a:.5} vs brute force {b:.5}, 4σ = {:.5}", 4.0 * se);
    }
}

#[test]
fn undeclared_effects_are_errors_naming_the_effect() {
    let mut d = scene(BASE);
    d.materials[0].kind = kpcn::sim::scene::MaterialType::Conductor;
    d.materials[0].color = Some([0.9; 3]);
    let e = d.build(1.0).err().expect("a conductor needs `glossy`");
    assert!(matches!(e, SceneError::UndeclaredEffect { effect: Effect::Glossy, .. }), "{e}");
    assert!(e.to_string().contains("add \"glossy\" to `effects`"), "{e}");

    let mut d = scene(BASE);
    d.camera.aperture = 0.1;
    assert!(matches!(d.build(1.0), Err(SceneError::UndeclaredEffect { effect: Effect::DepthOfField, .. })));
    let mut d = scene(BASE);
    d.effects.retain(|e| *e != Effect::AreaLights);
    assert!(matches!(d.build(1.0), Err(SceneError::UndeclaredEffect { effect: Effect::AreaLights, .. })));
}

#[test]
fn declared_but_unused_effects_change_nothing_and_cost_nothing() {
    let base = scene(BASE);
    let mut extra = base.clone();
    extra.effects.extend([
        Effect::Glossy,
        Effect::Transmission,
        Effect::Textures,
        Effect::DepthOfField,
        Effect::PointLights,
        Effect::Sun,
    ]);
    let o = opts(12, 8, &[4], 9);
    let (a, ca) = run(&base, &o);
    let (b, cb) = run(&extra, &o);
    assert_eq!(a, b, "identical frames");
    assert_eq!(ca, cb, "identical work");
    assert_eq!((ca.lobes.glossy, ca.lobes.transmission, ca.lens_samples), (0, 0, 0));
}

#[test]
fn each_effect_does_work_only_when_used() {
    let o = opts(12, 8, &[4], 9);
    let samples = (12 * 8 * 4) as u64;
    // Without `indirect`: one closest-hit ray per sample.
    let mut direct = scene(BASE);
    direct.effects.retain(|e| *e != Effect::Indirect);
    let (_, c) = run(&direct, &o);
    assert_eq!(c.rays, samples);
    let (_, c_ind) = run(&scene(BASE), &o);
    assert!(c_ind.rays > c.rays + samples / 4, "indirect paths trace more: {} vs {}", c_ind.rays, c.rays);
    // A thin lens draws one lens sample per camera ray.
    let mut dof = scene(BASE);
    dof.effects.push(Effect::DepthOfField);
    dof.camera.aperture = 0.05;
    assert_eq!(run(&dof, &o).1.lens_samples, samples);
    // A glossy material evaluates glossy lobes.
    let mut glossy = scene(BASE);
    glossy.effects.push(Effect::Glossy);
    glossy.materials[0].kind = kpcn::sim::scene::MaterialType::Plastic;
    assert!(run(&glossy, &o).1.lobes.glossy > 0);
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let d = kpcn::sim::families::generate("glass", 4).unwrap();
    let o = opts(20, 12, &[2, 4], 11);
    let in_pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(|| run(&d, &o));
    let (a, ca) = in_pool(1);
    let (b, cb) = in_pool(3);
    assert_eq!(a, b);
    assert_eq!(ca, cb);
}

#[test]
fn half_buffer_is_the_mean_of_the_first_half_of_the_samples() {
    let d = scene(BASE);
    let (frames, _) = run(&d, &opts(6, 4, &[4, 8], 12));
    // Both checkpoints come from one run: the 8-spp half buffer is the 4-spp mean.
    assert_eq!(frames[1].channel("diffuseA.G"), frames[0].channel("diffuse.G"));
    assert_eq!(frames[1].attribute("kpcn:spp"), Some("8"));
}
