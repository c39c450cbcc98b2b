//! The default model on small crops of our own Cycles renders where fireflies and caustics
//! gather (issue 24's outliers): `tests/data/cycles-crops/`, 48×48 windows of corpus scenes
//! (`scripts/corpus/crops.sh`; glass lit by small area lights, spots and a point light at
//! night, one with defocus) at 4, 16 and 64 spp beside a 512-spp reference. The simulator's
//! hard cases (`hard_cases.rs`) pass where such Cycles frames failed. Every crop must come
//! out better than its noisy input, leave no outlier (a pixel far above the reference's
//! 3×3 neighbourhood), and improve with samples; the crops the default still fails are
//! listed with what they measure, and must not get worse.

use kpcn::denoise::{Denoiser, Options};
use kpcn::eval::{relmse, rgb};
use kpcn::io::FrameBuffers;
use kpcn::io::layout::Mapping;
use kpcn::model::{Model, registry};
use std::path::{Path, PathBuf};

/// The crops: scene and window origin in the corpus frame.
const CROPS: [&str; 4] = ["cyc-00052-x40y8", "cyc-00052-x200y24", "cyc-00059-x152y88", "cyc-00075-x88y104"];
const SPPS: [u32; 3] = [4, 16, 64];

/// A denoised pixel is an outlier above `OUTLIER_RATIO` × the largest reference pixel of
/// its 3×3 neighbourhood + `OUTLIER_FLOOR` (luminance as the RGB mean): a firefly kept, or
/// its energy spread into a blotch where the reference has none.
const OUTLIER_RATIO: f32 = 4.0;
const OUTLIER_FLOOR: f32 = 0.5;

/// What the default still fails: (crop, spp, outliers left). None since `balanced` ships
/// the `fine-pairs-twice` clamp; with `fine-pairs` cyc-00052-x200y24 at 4 spp kept one
/// firefly at 6.6× its neighbourhood: the middle of three on a diagonal (27.9 each where
/// the caustic's reference is 2–4, among 0.1), whose second-brightest neighbour is
/// another of the three.
const KNOWN_OUTLIERS: &[(&str, u32, usize)] = &[];

/// Crops whose error does not fall with samples (`balanced`, measured by this test with
/// `--nocapture`): (crop, relMSE at 4 / 16 / 64 spp): caustics of glass under two area
/// lights on textured metal. With the `significant` clamp (2026-12-03) they fell from
/// 0.2627 / 2.0287 / 0.6942 and 0.0318 / 0.0365 / 0.0852 (clusters of caustic hits it
/// takes), but still rise between two of the counts. With the retrained specular branch,
/// bounded to two standard errors (2026-12-03, eighth session), from 0.2647 / 0.5157 /
/// 0.3562 and 0.0319 / 0.0269 / 0.0755: the first is lower at every count (and rises by
/// 13 % and 7 %), the second's 64-spp frame is 15 % higher (its textured metal keeps less
/// detail). With the default's diffuse branch seeing ln(1 + d̃) (2026-12-07, thirty-fourth
/// session) the first is 0.2 % lower at every count, the second 5 / 7 % higher at 4 / 16 spp
/// (from 0.0301 / 0.0251), while its whole 320×180 frame is 1.008 / 0.998 / 0.984× what it
/// was (BENCHMARKS.md, "`balanced`'s diffuse branch sees ln(1 + d̃)").
const KNOWN_GROWTH: &[(&str, [f64; 3])] =
    &[("cyc-00052-x40y8", [0.2373, 0.2675, 0.2865]), ("cyc-00052-x200y24", [0.0316, 0.0268, 0.0862])];

fn crop(name: &str, what: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("tests/data/cycles-crops/{name}-{what}.exr"))
}

fn luminance(p: &[Vec<f32>; 3], i: usize) -> f32 {
    (p[0][i] + p[1][i] + p[2][i]) / 3.0
}

/// Pixels of `out` above the outlier bound of `reference` (`w` wide).
fn outliers(out: &[Vec<f32>; 3], reference: &[Vec<f32>; 3], w: usize) -> Vec<(usize, usize, f32)> {
    let h = reference[0].len() / w;
    let mut found = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let mut max = 0f32;
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    max = max.max(luminance(reference, yy * w + xx));
                }
            }
            let v = luminance(out, y * w + x);
            // A NaN is an outlier too.
            if v.is_nan() || v > OUTLIER_RATIO * max + OUTLIER_FLOOR {
                found.push((x, y, (v + OUTLIER_FLOOR) / (max + OUTLIER_FLOOR)));
            }
        }
    }
    found
}

#[test]
fn the_default_removes_fireflies_and_caustic_noise_from_cycles_crops() {
    let model = Model::resolve(registry::auto_choice(true)).unwrap();
    let d = Denoiser::new(model, Options { threads: Some(2), ..Options::default() }).unwrap();
    let mut failures = Vec::new();
    for name in CROPS {
        let reference = FrameBuffers::read(&crop(name, "ref")).unwrap();
        let reference = [0, 1, 2].map(|c| reference.channel(["R", "G", "B"][c]).unwrap().to_vec());
        let mut errors = [0f64; 3];
        for (k, spp) in SPPS.into_iter().enumerate() {
            let fb = FrameBuffers::read(&crop(name, &format!("{spp:05}spp"))).unwrap();
            let inputs = Mapping::for_frame(&fb, None).extract(&fb).unwrap();
            let out = d.denoise(&inputs, &|_| true).unwrap().color;
            let noisy = relmse(rgb(&inputs.color), rgb(&reference));
            errors[k] = relmse(rgb(&out), rgb(&reference));
            let left = outliers(&out, &reference, fb.width());
            println!("{name} {spp:>2} spp: relMSE {:.4} (noisy {noisy:.4}), outliers {left:?}", errors[k]);
            if errors[k] >= noisy {
                failures.push(format!("{name} {spp} spp: relMSE {:.4}, noisy {noisy:.4}", errors[k]));
            }
            let allowed = KNOWN_OUTLIERS.iter().find(|g| (g.0, g.1) == (name, spp)).map_or(0, |g| g.2);
            if left.len() > allowed {
                failures.push(format!("{name} {spp} spp: {} outliers left (allowed {allowed}): {left:?}", left.len()));
            }
        }
        match KNOWN_GROWTH.iter().find(|g| g.0 == name) {
            // 5 % slack for the reference's own noise.
            None if !(errors[1] <= 1.05 * errors[0] && errors[2] <= 1.05 * errors[1]) => {
                failures.push(format!("{name}: relMSE {errors:?} at 4/16/64 spp does not fall"))
            }
            Some((_, known)) if errors.iter().zip(known).any(|(e, k)| *e > 1.05 * k) => {
                failures.push(format!("{name}: relMSE {errors:?} at 4/16/64 spp, worse than the known {known:?}"))
            }
            _ => {}
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn the_outlier_measure_finds_a_firefly_and_passes_the_reference() {
    // The bound above must catch a kept firefly, or the test above could not fail.
    let reference = FrameBuffers::read(&crop(CROPS[0], "ref")).unwrap();
    let mut planes = [0, 1, 2].map(|c| reference.channel(["R", "G", "B"][c]).unwrap().to_vec());
    assert!(outliers(&planes, &planes, 48).is_empty());
    let peak = planes.iter().flatten().fold(0f32, |a, &b| a.max(b));
    for p in &mut planes {
        p[20 * 48 + 30] = 5.0 * peak + 1.0;
    }
    let reference = [0, 1, 2].map(|c| reference.channel(["R", "G", "B"][c]).unwrap().to_vec());
    assert_eq!(outliers(&planes, &reference, 48).iter().map(|o| (o.0, o.1)).collect::<Vec<_>>(), [(30, 20)]);
}

/// Shipped models whose specular branch still returns its input (the share of specular
/// pixels it keeps exactly, measured by the test below): their softmax kernels saturated
/// to one tap while training (`--loss l1` and `relative` both reward keeping sparse
/// specular noise where it is; BENCHMARKS.md "The specular branch that never trained").
/// Each must not keep more; a retrained one leaves this list (`balanced`, 2026-12-03;
/// `fast`, 2026-12-06).
const KNOWN_IDENTITY_SPECULAR: &[(&str, f64)] = &[("high", 0.71), ("spatial", 0.71), ("compact", 0.71)];

/// The share of the specular pixels (noisy specular above 0.01) that a model returns
/// exactly as they came (within 0.1 %), over the crops at 16 spp.
fn specular_kept(model: Model) -> f64 {
    let d = Denoiser::new(model, Options { threads: Some(2), ..Options::default() }).unwrap();
    let (mut kept, mut specular) = (0usize, 0usize);
    for name in CROPS {
        let fb = FrameBuffers::read(&crop(name, "00016spp")).unwrap();
        let inputs = Mapping::for_frame(&fb, None).extract(&fb).unwrap();
        let out = d.denoise(&inputs, &|_| true).unwrap().specular;
        let rgb = |p: &[Vec<f32>; 3], i: usize| [p[0][i], p[1][i], p[2][i]];
        for i in 0..inputs.width * inputs.height {
            let (s, o) = (rgb(&inputs.specular, i), rgb(&out, i));
            if s.iter().all(|v| *v <= 0.01) {
                continue;
            }
            specular += 1;
            let same = (0..3).all(|c| (o[c] - s[c]).abs() <= 1e-3 * s[c].abs() + 1e-6);
            kept += usize::from(same);
        }
    }
    kept as f64 / specular.max(1) as f64
}

/// A specular branch whose kernels all put their weight on one tap denoises nothing: the
/// glossy, glass and emitted light of a Cycles frame came out as noisy as it went in.
#[test]
fn every_shipped_model_filters_the_specular_component() {
    let mut failures = Vec::new();
    for s in &registry::SHIPPED {
        let share = specular_kept(s.load().unwrap());
        let allowed = KNOWN_IDENTITY_SPECULAR.iter().find(|k| k.0 == s.name).map_or(0.2, |k| k.1);
        println!("{}: {:.3} of specular pixels returned as they came (allowed {allowed})", s.name, share);
        if share > allowed {
            failures
                .push(format!("{}: returns {share:.3} of the specular pixels unfiltered (allowed {allowed})", s.name));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
