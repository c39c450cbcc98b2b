//! The denoiser's contract: finite on hostile input, convex kernels, tiled == untiled,
//! thread-count independence, golden images, and files denoised through `FileJob`.

use crate::util::{Rng, multiscale_levels, native_frame, tiny_multiscale, tiny_multiscale_levels, write};
use kpcn::denoise::{Denoised, Denoiser, FileJob, FileOptions, Options};
use kpcn::features::{EPSILON, Features, reflect};
use kpcn::io::layout::{KpcnInputs, Mapping};
use kpcn::io::{FrameBuffers, SampleFormat, WriteOptions};
use kpcn::model::{Architecture, Design, Exposure, Kind, Model};
use proptest::prelude::*;
use std::path::Path;

/// A tiny network (fast in tests) with the paper's 21×21 kernels.
fn tiny(kind: Kind, kernel: usize) -> Model {
    Model::xavier(
        Architecture {
            kind,
            design: Design::Flat,
            layers: 3,
            channels: 6,
            conv_size: 3,
            kernel_size: kernel,
            clamp: Default::default(),
            blend: Default::default(),
            variances: Default::default(),
            specular: Default::default(),
            exposure: Default::default(),
            specular_bound: None,
            diffuse_bound: None,
            diffuse_spread: None,
            diffuse_detail: None,
            gain: false,
            diffuse_input: Default::default(),
        },
        3,
    )
    .unwrap()
}

fn tiny_ms() -> Model {
    tiny_multiscale(4)
}

/// `model` seeing auto-exposed radiance.
fn auto_exposed(model: Model) -> Model {
    Model { arch: Architecture { exposure: Exposure::Auto, ..model.arch }, ..model }
}

/// `model` with both branches bounded by two standard errors.
fn bounded(model: Model) -> Model {
    Model { arch: Architecture { specular_bound: Some(2), diffuse_bound: Some(2), ..model.arch }, ..model }
}

fn run(model: Model, k: &KpcnInputs, tile: Option<usize>, threads: usize) -> Denoised {
    let d = Denoiser::new(model, Options { threads: Some(threads), max_memory_mb: 64, tile_size: tile }).unwrap();
    d.denoise(k, &|_| true).unwrap()
}

/// Random inputs; `hostile` mixes in NaN, ±Inf, negatives, 1e30 fireflies, zero albedo.
fn frame(w: usize, h: usize, seed: u64, hostile: bool) -> KpcnInputs {
    let mut rng = Rng(seed);
    let mut plane = |scale: f32| -> Vec<f32> {
        (0..w * h)
            .map(|_| {
                let u = rng.uniform_f32();
                if hostile {
                    match (u * 20.0) as u32 {
                        0 => f32::NAN,
                        1 => f32::INFINITY,
                        2 => f32::NEG_INFINITY,
                        3 => 1e30,
                        4 => -3.0,
                        5 => 0.0,
                        6 => f32::MAX,
                        _ => u * scale,
                    }
                } else {
                    u * scale
                }
            })
            .collect()
    };
    let mut rgb = |s: f32| [plane(s), plane(s), plane(s)];
    let (diffuse, specular) = (rgb(2.0), rgb(1.0));
    // As a renderer writes it: the beauty is the sum of its components (a beauty holding
    // more is carried to the output as it is, which `tests/integrity.rs` covers).
    let color = std::array::from_fn(|c| diffuse[c].iter().zip(&specular[c]).map(|(d, s)| d + s).collect());
    KpcnInputs {
        width: w,
        height: h,
        color,
        diffuse,
        specular,
        albedo: rgb(1.0),
        normal: rgb(1.0),
        depth: plane(10.0),
        visibility: None,
        color_variance: plane(0.1),
        diffuse_variance: plane(0.1),
        specular_variance: plane(0.1),
        albedo_variance: plane(0.01),
        normal_variance: plane(0.01),
        depth_variance: plane(0.1),
    }
}

fn all_finite(d: &Denoised) -> bool {
    d.color.iter().chain(&d.diffuse).chain(&d.specular).all(|p| p.iter().all(|v| v.is_finite()))
}

fn max_rel_diff(a: &Denoised, b: &Denoised) -> f32 {
    let mut m = 0f32;
    for (x, y) in a.color.iter().flatten().zip(b.color.iter().flatten()) {
        m = m.max((x - y).abs() / (1.0 + x.abs().max(y.abs())));
    }
    m
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn nan_inf_and_fireflies_give_finite_output(
        w in 1usize..20, h in 1usize..12, seed in 0u64..10_000, dpcn in any::<bool>()
    ) {
        let kind = if dpcn { Kind::Dpcn } else { Kind::Kpcn };
        let d = run(tiny(kind, 5), &frame(w, h, seed, true), None, 2);
        prop_assert!(all_finite(&d));
    }

    #[test]
    fn tiled_equals_untiled(w in 1usize..40, h in 1usize..30, tile in 1usize..24, seed in 0u64..10_000) {
        let k = frame(w, h, seed, false);
        let whole = run(tiny(Kind::Kpcn, 5), &k, Some(1024), 1);
        let tiled = run(tiny(Kind::Kpcn, 5), &k, Some(tile), 1);
        // Convolutions over regions of different sizes may sum in another order.
        prop_assert!(max_rel_diff(&whole, &tiled) < 1e-5, "{}", max_rel_diff(&whole, &tiled));
    }

    #[test]
    fn multiscale_tiles_equal_the_whole_frame_bit_for_bit(
        w in 1usize..48, h in 1usize..40, tile in 1usize..24, seed in 0u64..10_000, hostile in any::<bool>(),
        clamp in 0usize..7, ladder in any::<bool>(), bounded in any::<bool>(), wide in any::<bool>()
    ) {
        // Our convolutions sum every pixel in one order, so tiles (on the pooling grid, with
        // the receptive radius as halo, cut at the frame's border radius) reproduce the
        // frame exactly; hostile inputs stay finite. Every firefly clamp; 2 levels, the
        // ladder's 5, whose regions are cut at the frame's edges, and 3 levels of 32
        // channels and more, whose 3×3 layers take the Winograd path at every scale but
        // the coarsest (its regions may start on odd columns); with and without the
        // specular bound.
        let k = frame(w, h, seed, hostile);
        let model = || {
            let mut m = match (ladder, wide) {
                (true, _) => tiny_multiscale_levels(4, 5),
                (false, true) => multiscale_levels(4, 3, 32),
                (false, false) => tiny_ms(),
            };
            use kpcn::model::Clamp;
            m.arch.clamp = [
                Clamp::Hard,
                Clamp::Spread,
                Clamp::Coarse,
                Clamp::Fine,
                Clamp::FinePairs,
                Clamp::FinePairsTwice,
                Clamp::Significant,
            ][clamp];
            if bounded {
                m = self::bounded(m);
            }
            m
        };
        let whole = run(model(), &k, Some(1024), 1);
        let tiled = run(model(), &k, Some(tile), 2);
        prop_assert!(all_finite(&whole));
        prop_assert_eq!(whole, tiled);
    }
}

/// Tiles of every offset on the pooling grid see the column pairs of the Winograd path
/// (3×3 layers of 32 channels and more) where the whole frame does: at the coarsest
/// scale a region may start on an odd column, and there the path is not taken.
#[test]
fn winograd_layers_in_tiles_give_the_whole_frames_bits() {
    // Frame widths whose regions at the coarsest scale are now even, now odd.
    for w in (96..=136).step_by(8) {
        let k = frame(w, 12, 3, false);
        let whole = run(multiscale_levels(4, 3, 32), &k, Some(1024), 2);
        for tile in [8, 24] {
            assert_eq!(whole, run(multiscale_levels(4, 3, 32), &k, Some(tile), 2), "{w} wide, tiles of {tile}");
        }
    }
}

#[test]
fn multiscale_output_lies_within_the_receptive_range() {
    let (w, h) = (29, 21);
    let mut k = frame(w, h, 6, false);
    for p in &mut k.albedo {
        p.fill(0.5);
    }
    for model in [tiny_ms(), tiny_multiscale_levels(4, 5)] {
        let r = model.arch.feature_radius();
        let d = run(model, &k, Some(8), 2);
        assert_diffuse_within_neighbourhood(&d, &k, r);
    }
}

#[test]
fn linear_specular_kernels_keep_specular_inside_its_range_and_bright_frames_bright() {
    // The ladder filters linear specular radiance: every denoised specular value lies in
    // the range of the noisy specular around it (no exp of an average of logs), so a
    // frame of sparse bright specular samples keeps far more of its mean than in log.
    let (w, h) = (40, 36);
    let mut k = frame(w, h, 9, false);
    let mut rng = Rng(3);
    for c in 0..3 {
        for v in &mut k.specular[c] {
            *v = if rng.uniform_f32() < 0.05 { 40.0 } else { 0.01 };
        }
        k.color[c] = k.diffuse[c].iter().zip(&k.specular[c]).map(|(d, s)| d + s).collect();
    }
    let (mut log, mut linear) = (tiny_multiscale_levels(4, 5), tiny_multiscale_levels(4, 5));
    for (m, domain) in [(&mut log, kpcn::model::Specular::Log), (&mut linear, kpcn::model::Specular::Linear)] {
        // The clamp that keeps every scale's energy, so that only the domain differs.
        m.arch.specular = domain;
        m.arch.clamp = kpcn::model::Clamp::Spread;
    }
    let r = linear.arch.feature_radius();
    let (d_log, d_lin) = (run(log, &k, None, 2), run(linear, &k, None, 2));
    assert!(all_finite(&d_lin));
    for c in 0..3 {
        let s = &k.specular[c];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let nb = (-(r as isize)..=r as isize)
                    .flat_map(|dy| (-(r as isize)..=r as isize).map(move |dx| (dx, dy)))
                    .map(|(dx, dy)| s[reflect(y + dy, h) * w + reflect(x + dx, w)]);
                let (lo, hi) = nb.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
                let v = d_lin.specular[c][y as usize * w + x as usize];
                assert!(v >= lo * (1.0 - 1e-5) && v <= hi * (1.0 + 1e-5), "{v} outside [{lo}, {hi}] at {x},{y}");
            }
        }
    }
    let mean = |p: &[Vec<f32>; 3]| p.iter().flatten().map(|&v| v as f64).sum::<f64>() / (3 * w * h) as f64;
    let noisy = mean(&k.specular);
    // Untrained kernels are near-uniform averages: in log space they lose most of the energy.
    assert!(mean(&d_log.specular) < 0.5 * noisy, "log {} of {noisy}", mean(&d_log.specular));
    assert!(mean(&d_lin.specular) > 0.8 * noisy, "linear {} of {noisy}", mean(&d_lin.specular));
}

/// With albedo 0.5 everywhere, every denoised d̂ lies within the range of the noisy d̃ in
/// the `(2r + 1)²` window around it (reflected at the border).
fn assert_diffuse_within_neighbourhood(d: &Denoised, k: &KpcnInputs, r: usize) {
    let (w, h, r) = (k.width, k.height, r as isize);
    let f = Features::new(k);
    for c in 0..3 {
        for y in 0..h as isize {
            for x in 0..w as isize {
                let nb = (-r..=r)
                    .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
                    .map(|(dx, dy)| f.d_tilde[c][reflect(y + dy, h) * w + reflect(x + dx, w)]);
                let (lo, hi) = nb.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
                let d_hat = d.diffuse[c][y as usize * w + x as usize] / (0.5 + EPSILON);
                let tol = 1e-5 * lo.abs().max(hi.abs()).max(1.0);
                assert!(d_hat >= lo - tol && d_hat <= hi + tol, "{d_hat} outside [{lo}, {hi}] at {x},{y}");
            }
        }
    }
}

#[test]
fn an_auto_exposed_model_denoises_a_brighter_frame_to_a_brighter_result() {
    // Its inputs are scaled to one key whatever the render's exposure, and its output
    // scaled back: a frame 8× (or 1/8×) as bright gives the same image 8× (1/8×) as bright,
    // to rounding. A raw model does not (which is why the choice exists).
    let k = frame(40, 36, 21, false);
    let scaled = |k: &KpcnInputs, f: f32| {
        let mut s = k.clone();
        for p in s.color.iter_mut().chain(&mut s.diffuse).chain(&mut s.specular) {
            p.iter_mut().for_each(|v| *v *= f);
        }
        for p in [&mut s.color_variance, &mut s.diffuse_variance, &mut s.specular_variance] {
            p.iter_mut().for_each(|v| *v *= f * f);
        }
        s
    };
    let worst = |model: &Model, f: f32| {
        let (base, bright) = (run(model.clone(), &k, None, 2), run(model.clone(), &scaled(&k, f), None, 2));
        let mut m = 0f32;
        for (a, b) in base.color.iter().flatten().zip(bright.color.iter().flatten()) {
            m = m.max((b / f - a).abs() / (a.abs() + 1e-3));
        }
        m
    };
    for model in [auto_exposed(tiny_ms()), auto_exposed(tiny(Kind::Kpcn, 5))] {
        for f in [8.0, 0.125] {
            let e = worst(&model, f);
            assert!(e < 1e-3, "{:?} ×{f}: {e}", model.arch);
        }
    }
    assert!(worst(&tiny_ms(), 8.0) > 1e-2, "a raw model happens to be scale-invariant: the test proves nothing");
}

#[test]
fn constant_black_and_single_pixel_frames_are_finite() {
    for (w, h) in [(1, 1), (1, 9), (9, 1), (16, 16)] {
        let mut k = frame(w, h, 1, false);
        for p in k.color.iter_mut().chain(&mut k.diffuse).chain(&mut k.specular).chain(&mut k.albedo) {
            p.fill(0.0);
        }
        let d = run(tiny(Kind::Kpcn, 21), &k, None, 1);
        assert!(all_finite(&d));
        // Black in, black out: every kernel mixes zeros.
        assert!(d.color.iter().flatten().all(|&v| v == 0.0), "{w}x{h}");
    }
}

#[test]
fn kpcn_output_lies_within_the_neighbourhood_range() {
    let (w, h, kern) = (23, 17, 21);
    let mut k = frame(w, h, 5, false);
    // Constant albedo, so d̂ = diffuse / (a + ε) is recoverable from the output.
    for p in &mut k.albedo {
        p.fill(0.5);
    }
    let d = run(tiny(Kind::Kpcn, kern), &k, Some(8), 2);
    assert_diffuse_within_neighbourhood(&d, &k, kern / 2);
}

#[test]
fn one_thread_equals_many_threads() {
    let k = frame(40, 24, 9, false);
    let a = run(tiny(Kind::Kpcn, 11), &k, Some(16), 1);
    let b = run(tiny(Kind::Kpcn, 11), &k, Some(16), 2);
    assert!(max_rel_diff(&a, &b) < 1e-6, "{}", max_rel_diff(&a, &b));
}

#[test]
fn aovs_add_up_to_the_beauty_exactly() {
    let d = run(tiny(Kind::Kpcn, 5), &frame(12, 9, 3, false), None, 1);
    for c in 0..3 {
        for i in 0..12 * 9 {
            assert_eq!(d.color[c][i], d.diffuse[c][i] + d.specular[c][i]);
        }
    }
}

#[test]
fn progress_can_cancel() {
    let d = Denoiser::new(tiny(Kind::Kpcn, 5), Options { tile_size: Some(4), ..Default::default() }).unwrap();
    let calls = std::cell::Cell::new(0);
    let caller = std::thread::current().id();
    let r = d.denoise(&frame(16, 16, 1, false), &|p| {
        // Between tiles, on the caller's thread (a C host may touch its UI here).
        assert_eq!(std::thread::current().id(), caller);
        calls.set(calls.get() + 1);
        p.done < 3
    });
    assert!(matches!(r, Err(kpcn::denoise::DenoiseError::Cancelled)));
    assert_eq!(calls.get(), 3);
}

/// Golden images: a 48×32 crop of the Cycles example through every shipped model and the
/// untrained `small` preset (Xavier seed 0, fixed in code), each against
/// `tests/golden/spheres-48x32-<model>.exr`. Regenerate with `KPCN_BLESS=1 cargo test
/// golden`; a mismatch writes `target/golden-<model>-actual.exr` and `-diff.exr`
/// (|actual − expected|) for inspection.
#[test]
fn golden_images_of_every_shipped_model_on_a_cycles_crop() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    let input = FrameBuffers::read(&dir.join("spheres-48x32-input.exr")).unwrap();
    let k = Mapping::for_frame(&input, None).extract(&input).unwrap();
    let mut failures = Vec::new();
    for name in ["small", "default", "compact", "spatial", "small-flat", "fast", "balanced", "high"] {
        let d = run(Model::resolve(name).unwrap(), &k, None, 2);
        let mut out = FrameBuffers::new(d.width, d.height);
        out.insert_rgb("denoised", SampleFormat::Float, d.color).unwrap();
        let expected_path = dir.join(format!("spheres-48x32-{name}.exr"));
        if std::env::var_os("KPCN_BLESS").is_some() {
            out.write(&expected_path, &WriteOptions::default()).unwrap();
            continue;
        }
        let expected = FrameBuffers::read(&expected_path).expect("golden file (regenerate with KPCN_BLESS=1)");
        let mut worst = 0f32;
        let mut diff = FrameBuffers::new(d.width, d.height);
        for c in ["denoised.R", "denoised.G", "denoised.B"] {
            let (a, b) = (out.channel(c).unwrap(), expected.channel(c).unwrap());
            for (a, b) in a.iter().zip(b) {
                worst = worst.max((a - b).abs() / (1e-3 + b.abs()));
            }
            diff.insert(c, SampleFormat::Float, a.iter().zip(b).map(|(a, b)| (a - b).abs()).collect()).unwrap();
        }
        if worst > 1e-4 {
            let target = Path::new(env!("CARGO_MANIFEST_DIR")).join("target");
            out.write(&target.join(format!("golden-{name}-actual.exr")), &WriteOptions::default()).unwrap();
            diff.write(&target.join(format!("golden-{name}-diff.exr")), &WriteOptions::default()).unwrap();
            failures.push(format!("{name}: worst relative error {worst} (target/golden-{name}-*.exr)"));
        }
    }
    assert!(failures.is_empty(), "golden mismatch:\n{}", failures.join("\n"));
}

#[test]
fn a_denoiser_is_shared_between_threads() {
    fn send_sync<T: Send + Sync>(_: &T) {}
    let d = Denoiser::new(tiny(Kind::Kpcn, 5), Options { threads: Some(1), ..Default::default() }).unwrap();
    send_sync(&d);
    let k = frame(10, 6, 4, false);
    let (a, b) = std::thread::scope(|s| {
        let a = s.spawn(|| d.denoise(&k, &|_| true).unwrap());
        let b = s.spawn(|| d.denoise(&k, &|_| true).unwrap());
        (a.join().unwrap(), b.join().unwrap())
    });
    assert_eq!(a, b);
}

#[test]
fn named_host_images_denoise_like_planes() {
    use kpcn::io::NamedImages;
    // As the C ABI takes a host's images: by name, the beauty's RGB and each variance.
    let (w, h) = (9, 7);
    let k = frame(w, h, 6, false);
    let mut images = NamedImages::new(w, h);
    let one = |p: &Vec<f32>| vec![p.clone()];
    let all: [(&str, Vec<Vec<f32>>); 11] = [
        ("color", k.color.to_vec()),
        ("diffuse", k.diffuse.to_vec()),
        ("specular", k.specular.to_vec()),
        ("albedo", k.albedo.to_vec()),
        ("normal", k.normal.to_vec()),
        ("depth", one(&k.depth)),
        ("diffuseVariance", one(&k.diffuse_variance)),
        ("specularVariance", one(&k.specular_variance)),
        ("albedoVariance", one(&k.albedo_variance)),
        ("normalVariance", one(&k.normal_variance)),
        ("depthVariance", one(&k.depth_variance)),
    ];
    for (name, planes) in all {
        images.insert(name, planes).unwrap();
    }
    let named = images.inputs().unwrap();
    assert_eq!(named.diffuse, k.diffuse);
    let a = run(tiny(Kind::Kpcn, 5), &named, None, 1);
    let b = run(tiny(Kind::Kpcn, 5), &k, None, 1);
    assert_eq!(a.color, b.color);
}

/// Denoises `input` through the file path with `band` rows per band.
fn denoise_file(model: Model, input: &Path, output: &Path, band: Option<usize>, separate: bool) -> FrameBuffers {
    let d = Denoiser::new(model, Options { threads: Some(2), max_memory_mb: 64, tile_size: Some(16) }).unwrap();
    let opts = FileOptions { aovs: true, separate, band_rows: band, ..FileOptions::default() };
    FileJob::open(input, None).unwrap().run(&d, output, &opts, &|_| true).unwrap();
    FrameBuffers::read(output).unwrap()
}

#[test]
fn streamed_bands_equal_the_whole_frame_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    // Depth grows downwards, so a band's own largest depth differs from the frame's.
    let mut fb = native_frame(37, 41, 5, &[]);
    let depth: Vec<f32> = (0..37 * 41).map(|i| (i / 37) as f32 * 0.5 + 0.1).collect();
    fb.insert("depth.Z", SampleFormat::Float, depth).unwrap();
    let input = write(&fb, dir.path(), "in.exr");
    let k = Mapping::for_frame(&fb, None).extract(&fb).unwrap();
    for model in [
        tiny(Kind::Kpcn, 5),
        tiny(Kind::Dpcn, 5),
        tiny_ms(),
        tiny_multiscale_levels(4, 5),
        auto_exposed(tiny_ms()),
        bounded(tiny_multiscale_levels(4, 5)),
    ] {
        let whole = run(model.clone(), &k, Some(16), 2);
        // Multi-scale bands are rounded up to its pooling grid (4 rows).
        for band in [Some(1), Some(4), Some(7), None] {
            let out = denoise_file(model.clone(), &input, &dir.path().join("out.exr"), band, false);
            for (layer, planes) in [("denoised", &whole.color), ("denoised_diffuse", &whole.diffuse)] {
                for (c, plane) in ["R", "G", "B"].iter().zip(planes) {
                    let got = out.channel(&format!("{layer}.{c}")).unwrap();
                    assert_eq!(got, plane.as_slice(), "{:?} band {band:?} {layer}.{c}", model.arch);
                }
            }
            // Every input channel is copied unchanged.
            for p in fb.planes() {
                assert!(out.channel(&p.name) == Some(p.data.as_slice()), "{} differs", p.name);
            }
            assert_eq!(out.planes().len(), fb.planes().len() + 9);
            assert_eq!(out.attribute("kpcn:scene"), Some("fixture"));
        }
    }
    // --separate reads only the network's channels and writes only the new layers.
    let sep = denoise_file(tiny(Kind::Kpcn, 5), &input, &dir.path().join("sep.exr"), Some(6), true);
    let names: Vec<&str> = sep.channel_names().collect();
    assert_eq!(names.len(), 9, "{names:?}");
    let whole = run(tiny(Kind::Kpcn, 5), &k, Some(16), 2);
    assert_eq!(sep.channel("denoised.G").unwrap(), whole.color[1].as_slice());
}

#[test]
fn a_streamed_frame_whose_copies_do_not_fit_reads_them_again_and_gives_the_same_bits() {
    // A wide frame, and the budgets from which the tiny network's streams fit and from
    // which its bands' copied channels, kept until their result comes out, fit beside
    // them. Between the two the encoder decodes them again, in pieces of what it writes
    // at a time (80 rows of these 12 channels): bands of 96 rows are cut in two. Every
    // way gives the whole frame's result and copies every channel unchanged.
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (3000, 120);
    let fb = native_frame(w, h, 9, &[]);
    let input = write(&fb, dir.path(), "in.exr");
    let k = Mapping::for_frame(&fb, None).extract(&fb).unwrap();
    let model = tiny_ms();
    let whole = run(model.clone(), &k, None, 2);
    let channels = fb.planes().len();
    let denoiser =
        |mb| Denoiser::new(model.clone(), Options { threads: Some(2), max_memory_mb: mb, tile_size: None }).unwrap();
    let kept =
        |d: &Denoiser, band| kpcn::denoise::Bands::new(d, w, h, Some(band)).held_copies_bytes(d, channels).is_some();
    let streams_from = (1..1024).find(|&mb| denoiser(mb).streams(w)).expect("the streams fit somewhere");
    let kept_from = (1..1024).find(|&mb| kept(&denoiser(mb), 8)).expect("the copies fit somewhere");
    assert!(streams_from < kept_from, "streams from {streams_from} MB, copies kept from {kept_from} MB");
    for (mb, band) in [(streams_from, 8), (streams_from, 96), (kept_from, 8)] {
        let d = denoiser(mb);
        assert_eq!(kept(&d, band), mb == kept_from);
        let opts = FileOptions { band_rows: Some(band), ..FileOptions::default() };
        let out_path = dir.path().join(format!("out-{mb}-{band}.exr"));
        FileJob::open(&input, None).unwrap().run(&d, &out_path, &opts, &|_| true).unwrap();
        let out = FrameBuffers::read(&out_path).unwrap();
        for (c, plane) in ["R", "G", "B"].iter().zip(&whole.color) {
            assert_eq!(out.channel(&format!("denoised.{c}")).unwrap(), plane.as_slice(), "{mb} MB denoised.{c}");
        }
        for p in fb.planes() {
            assert!(out.channel(&p.name) == Some(p.data.as_slice()), "{mb} MB, bands of {band}: {} differs", p.name);
        }
    }
}

#[test]
fn a_cancelled_file_denoise_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let input = write(&native_frame(20, 20, 2, &[]), dir.path(), "in.exr");
    let out = dir.path().join("out.exr");
    let d = Denoiser::new(tiny(Kind::Kpcn, 5), Options { tile_size: Some(8), ..Options::default() }).unwrap();
    let opts = FileOptions { band_rows: Some(5), ..FileOptions::default() };
    let err = FileJob::open(&input, None).unwrap().run(&d, &out, &opts, &|p| p.done < 3).unwrap_err();
    assert!(err.to_string().contains("cancelled"), "{err}");
    assert!(!out.exists());
    assert_eq!(crate::util::stray_files(dir.path(), &["in.exr"]), Vec::<String>::new());
}

/// A frame of several bands whose last chunks are missing fails before its first band (in
/// the whole-frame statistics pass, which decodes the next rows while it measures these),
/// naming the file, and leaves no output.
#[test]
fn a_frame_of_several_bands_cut_short_fails_before_its_first_band() {
    let dir = tempfile::tempdir().unwrap();
    let whole = write(&native_frame(40, 64, 3, &[]), dir.path(), "whole.exr");
    let bytes = std::fs::read(&whole).unwrap();
    let cut = dir.path().join("cut.exr");
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 4]).unwrap();
    let out = dir.path().join("out.exr");
    // A tiled network: every band's tiles come out before the next band is read.
    let d = Denoiser::new(tiny(Kind::Kpcn, 5), Options { tile_size: Some(8), ..Options::default() }).unwrap();
    let opts = FileOptions { band_rows: Some(8), ..FileOptions::default() };
    // No tile is denoised, though the first bands' rows are whole.
    let tiles = std::cell::Cell::new(0);
    let err = FileJob::open(&cut, None).unwrap().run(&d, &out, &opts, &|_| {
        tiles.set(tiles.get() + 1);
        true
    });
    let err = err.unwrap_err().to_string();
    assert!(err.contains(cut.to_str().unwrap()) && err.contains("truncated or corrupt"), "{err}");
    assert_eq!(tiles.get(), 0, "{err}");
    assert!(!out.exists());
    assert_eq!(crate::util::stray_files(dir.path(), &["whole.exr", "cut.exr"]), Vec::<String>::new());
}

/// A small `--max-memory` never cuts a wide network's frame into tiles that are mostly
/// context (the budget is raised to a region of twice its reach instead): every tile but
/// the last of a row or column is at least the reach on each side, for a band's tiles too.
#[test]
fn tiles_are_never_mostly_context_whatever_the_budget() {
    let model = Model::resolve("default").unwrap();
    let reach = model.arch.feature_radius().max(model.arch.kernel_radius());
    let d = Denoiser::new(model, Options { max_memory_mb: 16, ..Options::default() }).unwrap();
    let (w, h) = (1920, 1152);
    for (tiles, rows) in [(d.tiles(w, 0..h, h), h), (d.band_tiles(w, 200..616, 816), 416)] {
        assert!(tiles.len() > 1, "a 16 MB budget still tiles a 1080p frame");
        for t in &tiles {
            assert!(t.w >= reach || t.x + t.w == w, "{t:?} against a reach of {reach}");
            assert!(t.h >= reach || t.y + t.h == rows, "{t:?} against a reach of {reach}");
        }
    }
    // Compact's reach is small: a small budget gives it small tiles. (A tile streams
    // through the network holding some rows of it, so 16 MB is no longer small.)
    let c = Denoiser::new(Model::resolve("compact").unwrap(), Options { max_memory_mb: 4, ..Options::default() });
    assert!(c.unwrap().tiles(w, 0..h, h).iter().all(|t| t.w < reach));
}
