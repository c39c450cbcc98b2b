//! Training data: frames listed in a `kpcn dataset` manifest, their reference targets, an
//! importance map, and batches of patches.

use super::augment::{ChannelOrder, Orientation};
use crate::features::{Branch, Features, demodulated, log_specular, log_specular_of, sanitize, specular_of_log};
use crate::io::FrameBuffers;
use crate::io::layout::{KpcnInputs, Mapping, box3};
use crate::model::{Architecture, Exposure, ModelError, Preprocessing, Variances};
use crate::rng::SplitMix64;
use candle_core::Tensor;
use std::path::{Path, PathBuf};

/// One noisy frame with its reference.
pub struct Frame {
    /// Scene name.
    pub scene: String,
    /// Samples per pixel of the noisy input.
    pub spp: u32,
    /// The noisy frame's network inputs.
    pub features: Features,
    /// Target d̃: reference diffuse / (reference albedo + ε).
    pub target_d: [Vec<f32>; 3],
    /// Target s̃: ln(1 + reference specular).
    pub target_s: [Vec<f32>; 3],
    /// Reference colour.
    pub reference: [Vec<f32>; 3],
    /// Patch centres chosen by importance (dart throwing + error diffusion).
    importance_centres: Vec<(usize, usize)>,
    /// Patch centres chosen uniformly (the dart-thrown candidates, unpruned).
    uniform_centres: Vec<(usize, usize)>,
}

/// Candidate patch centres thrown per frame (ARCHITECTURE.md §Training: ≈400).
pub const CANDIDATES: usize = 400;
/// Centres kept per frame after pruning.
pub const KEPT: usize = 100;
/// Share of a candidate's weight that does not depend on importance, so easy regions are
/// still represented.
const IMPORTANCE_FLOOR: f32 = 0.1;

/// Up to `n` points over a `w`×`h` frame by dart throwing: uniform darts, each rejected if
/// closer than a spacing that lets `n` points fit, so the candidates cover the frame evenly.
pub fn dart_throw(w: usize, h: usize, n: usize, rng: &mut SplitMix64) -> Vec<(usize, usize)> {
    let spacing = 0.7 * ((w * h) as f64 / n.max(1) as f64).sqrt();
    let r2 = spacing * spacing;
    let mut out: Vec<(usize, usize)> = Vec::with_capacity(n);
    for _ in 0..30 * n {
        if out.len() == n {
            break;
        }
        let x = (rng.uniform_f64() * w as f64) as usize % w.max(1);
        let y = (rng.uniform_f64() * h as f64) as usize % h.max(1);
        let far = out.iter().all(|&(a, b)| {
            let (dx, dy) = (a as f64 - x as f64, b as f64 - y as f64);
            dx * dx + dy * dy >= r2
        });
        if far {
            out.push((x, y));
        }
    }
    out
}

/// Keeps about `keep` of `candidates` with density following `importance` (plus a floor):
/// error diffusion along a serpentine scan of the candidates, the 1-D analogue of
/// Floyd–Steinberg dithering, so kept points are spread rather than clumped.
pub fn error_diffusion(
    candidates: &[(usize, usize)],
    importance: &[f32],
    w: usize,
    keep: usize,
) -> Vec<(usize, usize)> {
    let mut order = candidates.to_vec();
    // Serpentine over bands of rows: nearby candidates are visited consecutively.
    let band = ((candidates.len() as f64).sqrt().max(1.0) as usize).max(1);
    let h = candidates.iter().map(|c| c.1 + 1).max().unwrap_or(1);
    let row_of = |y: usize| y * band / h;
    order.sort_by_key(|&(x, y)| {
        let r = row_of(y);
        (r, if r % 2 == 0 { x } else { w - x })
    });
    let weight = |&(x, y): &(usize, usize)| {
        IMPORTANCE_FLOOR as f64 + (1.0 - IMPORTANCE_FLOOR as f64) * importance[y * w + x].clamp(0.0, 1.0) as f64
    };
    let total: f64 = order.iter().map(weight).sum();
    if total <= 0.0 {
        return order.into_iter().take(keep).collect();
    }
    let scale = keep as f64 / total;
    let mut err = 0.0;
    let mut out = Vec::with_capacity(keep);
    for c in &order {
        err += scale * weight(c);
        if err >= 0.5 {
            out.push(*c);
            err -= 1.0;
        }
    }
    out
}

/// Frames for training and whole held-out scenes for validation.
pub struct Dataset {
    /// Training frames.
    pub train: Vec<Frame>,
    /// Validation frames (scenes never seen in training).
    pub validation: Vec<Frame>,
    /// How many frames came from the on-disk cache.
    pub cached: usize,
}

/// Errors reading training data.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// The manifest is missing or malformed.
    #[error("{}: {msg} — make a dataset with `kpcn dataset -o DIR`", path.display())]
    Manifest {
        /// The manifest.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A check set (`--dev`) without frames.
    #[error("{}: {msg} — give --dev a folder of noisy frames and their references", path.display())]
    Check {
        /// The folder.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A frame could not be read or lacks channels.
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    /// Tensor work failed.
    #[error(transparent)]
    Model(#[from] ModelError),
}

/// A reference's colour with NaN/Inf and extreme values made finite ([`sanitize`]): what
/// relMSE and the phase-2 loss compare against.
fn clean_colour(k: &KpcnInputs) -> [Vec<f32>; 3] {
    std::array::from_fn(|c| k.color[c].iter().map(|&v| sanitize(v)).collect())
}

fn inputs(path: &Path) -> Result<KpcnInputs, DataError> {
    let fb = FrameBuffers::read(path)?;
    Ok(Mapping::for_frame(&fb, None).extract(&fb)?)
}

/// Importance of each pixel as a patch centre (ARCHITECTURE.md §Training): box-filtered relative variance of
/// the noisy colour plus the local variance of the normals, max over channels, `^(1/2.2)`,
/// capped at 1. Box filters are 3×3 applied `passes` times (≈ a wide window, cheaply).
pub fn importance(k: &KpcnInputs, passes: usize) -> Vec<f32> {
    let (w, h) = (k.width, k.height);
    let blur = |mut p: Vec<f32>| {
        for _ in 0..passes {
            p = box3(&p, w, h);
        }
        p
    };
    let rel: Vec<f32> = (0..w * h)
        .map(|i| {
            let m = (k.color[0][i] + k.color[1][i] + k.color[2][i]) / 3.0;
            sanitize(k.color_variance[i] / (m * m).max(0.01))
        })
        .collect();
    let rel = blur(rel);
    let normal_var: Vec<Vec<f32>> = k
        .normal
        .iter()
        .map(|n| {
            let mean = blur(n.iter().map(|&v| sanitize(v)).collect());
            let sq = blur(n.iter().map(|&v| sanitize(v) * sanitize(v)).collect());
            mean.iter().zip(&sq).map(|(m, s)| (s - m * m).max(0.0)).collect()
        })
        .collect();
    (0..w * h)
        .map(|i| {
            let nv = normal_var.iter().map(|p| p[i]).fold(0f32, f32::max);
            (rel[i] + nv).powf(1.0 / 2.2).min(1.0)
        })
        .collect()
}

impl Frame {
    /// The frame of `noisy` (its `features` as the model sees them) and `reference`.
    fn new(scene: String, spp: u32, noisy: &KpcnInputs, features: Features, reference: &KpcnInputs) -> Frame {
        let target_d = std::array::from_fn(|c| {
            reference.diffuse[c]
                .iter()
                .zip(&reference.albedo[c])
                .map(|(d, a)| sanitize(demodulated(sanitize(*d), sanitize(*a).max(0.0))))
                .collect()
        });
        let target_s = std::array::from_fn(|c| {
            log_specular(&reference.specular[c].iter().map(|&v| sanitize(v)).collect::<Vec<_>>())
        });
        let imp = importance(noisy, 8);
        let (w, h) = (noisy.width, noisy.height);
        // Patch positions depend on the frame only, not on the training seed.
        let tag = scene.bytes().fold(spp as u64, |a, b| crate::rng::mix(a ^ b as u64));
        let candidates = dart_throw(w, h, CANDIDATES, &mut SplitMix64(tag));
        let importance_centres = error_diffusion(&candidates, &imp, w, KEPT);
        let uniform_centres = candidates.into_iter().take(KEPT).collect();
        Frame {
            scene,
            spp,
            features,
            target_d,
            target_s,
            reference: clean_colour(reference),
            importance_centres,
            uniform_centres,
        }
    }

    /// Reassembles a frame from its stored parts (the on-disk cache):
    /// targets `[d̃, s̃, reference colour]`, centres `[importance, uniform]`.
    pub(crate) fn from_parts(
        scene: String,
        spp: u32,
        features: Features,
        [target_d, target_s, reference]: [[Vec<f32>; 3]; 3],
        [importance_centres, uniform_centres]: [Vec<(usize, usize)>; 2],
    ) -> Frame {
        Frame { scene, spp, features, target_d, target_s, reference, importance_centres, uniform_centres }
    }

    /// A patch's top-left corner for an output of `p`×`p`: one of the frame's chosen centres
    /// (by importance when `importance`, else uniform). `u` in [0, 1) picks which.
    pub fn patch_origin(&self, p: usize, u: f64, importance: bool) -> (usize, usize) {
        let (w, h) = (self.features.width, self.features.height);
        let centres = if importance { &self.importance_centres } else { &self.uniform_centres };
        let (cx, cy) = match centres.len() {
            0 => (((u * w as f64) as usize).min(w - 1), h / 2),
            n => centres[((u * n as f64) as usize).min(n - 1)],
        };
        (cx.saturating_sub(p / 2).min(w.saturating_sub(p)), cy.saturating_sub(p / 2).min(h.saturating_sub(p)))
    }

    /// The patch centres chosen for training (importance or uniform).
    pub fn centres(&self, importance: bool) -> &[(usize, usize)] {
        if importance { &self.importance_centres } else { &self.uniform_centres }
    }
}

impl Dataset {
    /// Loads the frames of a `kpcn dataset` folder; every `holdout_every`-th scene (in name
    /// order) is held out whole for validation. With `cache`, preprocessed frames are read
    /// from and written to `DIR/cache/` (see [`super::cache`]). `prep` makes the noisy
    /// frames' features as the model to train sees them: the files' own variances or the
    /// spatial estimates a file without variances gets at inference; raw or auto-exposed.
    pub fn load(dir: &Path, holdout_every: usize, cache: bool, prep: Preprocessing) -> Result<Dataset, DataError> {
        let path = dir.join("manifest.csv");
        let manifest =
            super::records::read_manifest(&path).map_err(|e| DataError::Manifest { path: path.clone(), msg: e.msg })?;
        let rows: Vec<(String, u32, PathBuf, PathBuf)> =
            manifest.into_iter().map(|r| (r.scene, r.spp, dir.join(r.file), dir.join(r.reference))).collect();
        let mut scenes: Vec<String> = rows.iter().map(|r| r.0.clone()).collect();
        scenes.sort();
        scenes.dedup();
        if scenes.is_empty() {
            return Err(DataError::Manifest { path, msg: "lists no frames".into() });
        }
        let held: Vec<&String> = if scenes.len() < 2 {
            vec![]
        } else {
            scenes.iter().skip(holdout_every - 1).step_by(holdout_every.max(1)).collect()
        };
        let mut data = Dataset { train: Vec::new(), validation: Vec::new(), cached: 0 };
        let mut reference_cache: Option<(PathBuf, KpcnInputs)> = None;
        for (scene, spp, noisy, reference) in rows {
            let key = cache.then(|| super::cache::key(&noisy, &reference)).flatten();
            let stem = noisy.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            let spatial = if prep.variances == Variances::Spatial { "-spatial" } else { "" };
            let exposed = if prep.exposure == Exposure::Auto { "-auto" } else { "" };
            let cache_path = dir.join("cache").join(format!("{stem}{spatial}{exposed}.safetensors"));
            let cached = key.as_ref().and_then(|k| super::cache::load(&cache_path, k));
            let frame = match cached {
                Some(f) => {
                    data.cached += 1;
                    f
                }
                None => {
                    if reference_cache.as_ref().is_none_or(|(p, _)| *p != reference) {
                        reference_cache = Some((reference.clone(), inputs(&reference)?));
                    }
                    let r = &reference_cache.as_ref().expect("just set").1;
                    // Patches are chosen on the variances the model sees.
                    let n = prep.inputs(std::borrow::Cow::Owned(inputs(&noisy)?)).into_owned();
                    let features = prep.features_of(&n, None);
                    let f = Frame::new(scene.clone(), spp, &n, features, r);
                    if let Some(k) = &key {
                        // A read-only dataset still trains, only without the speed-up.
                        let _ = super::cache::store(&cache_path, k, &f);
                    }
                    f
                }
            };
            if held.contains(&&scene) { data.validation.push(frame) } else { data.train.push(frame) }
        }
        Ok(data)
    }
}

/// Frames scored at every validation but never trained on: a folder of
/// `SCENE-NNNNNspp.exr` files beside their `SCENE-ref.exr` (the team's Cycles dev set, or
/// a `kpcn dataset` scene folder).
pub struct CheckSet {
    /// The frames, by file name.
    pub frames: Vec<CheckFrame>,
}

/// One frame of a [`CheckSet`].
pub struct CheckFrame {
    /// The noisy file's name.
    pub name: String,
    /// Its preprocessed inputs.
    pub features: Features,
    /// The reference colour.
    pub reference: [Vec<f32>; 3],
}

impl CheckSet {
    /// Reads every noisy frame in `dir` that has a reference; `prep` as for
    /// [`Dataset::load`]. A folder without any such frame is an error that says what it
    /// looks for.
    pub fn load(dir: &Path, prep: Preprocessing) -> Result<CheckSet, DataError> {
        let err = |msg: String| DataError::Check { path: dir.into(), msg };
        let entries = std::fs::read_dir(dir).map_err(|e| err(e.to_string()))?;
        let mut noisy: Vec<(String, PathBuf)> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter_map(|p| {
                let name = p.file_name()?.to_str()?.to_string();
                let scene = name.strip_suffix("spp.exr")?.rsplit_once('-')?;
                (scene.1.len() == 5 && scene.1.bytes().all(|b| b.is_ascii_digit()))
                    .then(|| (name.clone(), dir.join(format!("{}-ref.exr", scene.0))))
            })
            .filter(|(_, reference)| reference.is_file())
            .collect();
        noisy.sort();
        if noisy.is_empty() {
            return Err(err("no SCENE-NNNNNspp.exr beside a SCENE-ref.exr".into()));
        }
        let frames = noisy
            .into_iter()
            .map(|(name, reference)| {
                let features = prep.features(std::borrow::Cow::Owned(inputs(&dir.join(&name))?), None);
                let r = inputs(&reference)?;
                Ok(CheckFrame { name, features, reference: clean_colour(&r) })
            })
            .collect::<Result<_, DataError>>()?;
        Ok(CheckSet { frames })
    }
}

/// A batch for one branch.
pub struct Batch {
    /// Network input `[B, 27, p + 2rf, p + 2rf]`.
    pub input: Tensor,
    /// Noisy c̃ around the patch `[B, 3, p + 2rk, p + 2rk]`.
    pub noisy: Tensor,
    /// Target c̃ `[B, 3, p, p]`.
    pub target: Tensor,
    /// Noisy albedo `[B, 3, p, p]` (for recomposition).
    pub albedo: Tensor,
    /// Reference colour `[B, 3, p, p]`.
    pub reference: Tensor,
    /// Each patch's frame exposure `[B, 1, 1, 1]` (1 for raw radiance): the factor
    /// `target` and `reference` carry over the radiance the renderer wrote.
    pub exposure: Tensor,
}

fn crop(planes: [&Vec<f32>; 3], w: usize, x0: usize, y0: usize, p: usize, out: &mut Vec<f32>) {
    for plane in planes {
        for y in y0..y0 + p {
            out.extend_from_slice(&plane[y * w + x0..y * w + x0 + p]);
        }
    }
}

/// Assembles a batch of branch `b` from patches `(frame, x0, y0)` of output size `p`.
pub fn batch(
    frames: &[&Frame],
    origins: &[(usize, usize)],
    p: usize,
    arch: &Architecture,
    b: Branch,
) -> Result<Batch, DataError> {
    batch_augmented(frames, origins, &[], p, arch, b)
}

/// A bright outlier added to a training patch's noisy input only (the reference stays
/// clean), so that the loss teaches the network to remove fireflies, which a mean-seeking
/// loss would otherwise learn to keep as real light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Firefly {
    /// Column in the output patch (after orientation).
    pub x: usize,
    /// Row in the output patch.
    pub y: usize,
    /// Its radiance as a multiple of the patch's mean reference colour (+ 0.01).
    pub gain: f32,
    /// In the diffuse light (else the specular).
    pub diffuse: bool,
}

/// How one training patch is shown.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Augmentation {
    /// Mirrored and/or transposed.
    pub orientation: Orientation,
    /// Colour channels reordered (colour, albedo and references alike).
    pub channels: ChannelOrder,
    /// Outliers added to the noisy input.
    pub fireflies: Vec<Firefly>,
}

/// [`batch`] with patch `i` shown as `augmentations[i]` (as is where the slice is short):
/// every buffer of the patch oriented alike, fireflies added to the noisy input only.
pub fn batch_augmented(
    frames: &[&Frame],
    origins: &[(usize, usize)],
    augmentations: &[Augmentation],
    p: usize,
    arch: &Architecture,
    b: Branch,
) -> Result<Batch, DataError> {
    let (rf, rk) = arch.train_margins();
    let n = frames.len();
    let (mut input, mut noisy, mut target, mut albedo, mut reference) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let none = Augmentation::default();
    for (i, (f, &(x0, y0))) in frames.iter().zip(origins).enumerate() {
        let aug = augmentations.get(i).unwrap_or(&none);
        let o = aug.orientation;
        let fe = &f.features;
        let order = aug.channels;
        let corner = (x0 as isize - rf as isize, y0 as isize - rf as isize);
        let mut patch_input = fe.branch_input_oriented(b, corner, p + 2 * rf, o, order);
        let c = order.pick(fe.colour(b)).map(Vec::as_slice);
        let region = fe.region(&c, x0 as isize - rk as isize, y0 as isize - rk as isize, p + 2 * rk, p + 2 * rk);
        let mut region = o.apply(&region, p + 2 * rk);
        let t = match b {
            Branch::Diffuse => &f.target_d,
            Branch::Specular => &f.target_s,
        };
        let mut crops = [t, &fe.albedo, &f.reference].map(|planes| {
            let mut patch = Vec::with_capacity(3 * p * p);
            crop(order.pick(planes), fe.width, x0, y0, p, &mut patch);
            o.apply(&patch, p)
        });
        // The targets at the inputs' exposure (frames keep them as rendered, for validation).
        let e = fe.exposure;
        if e != 1.0 {
            match b {
                Branch::Diffuse => crops[0].iter_mut().for_each(|v| *v = sanitize(*v * e)),
                Branch::Specular => {
                    crops[0].iter_mut().for_each(|v| *v = sanitize(log_specular_of(e * specular_of_log(*v))))
                }
            }
            crops[2].iter_mut().for_each(|v| *v = sanitize(*v * e));
        }
        // The patch's mean reference colour: what a firefly's gain multiplies.
        let level = crops[2].iter().map(|&v| v as f64).sum::<f64>() / crops[2].len().max(1) as f64 + 0.01;
        for ff in aug.fireflies.iter().filter(|ff| ff.diffuse == (b == Branch::Diffuse)) {
            let radiance = ff.gain * level as f32;
            let albedo_at = |c: usize| crops[1][c * p * p + ff.y * p + ff.x];
            add_firefly(&mut patch_input, &mut region, (ff.x, ff.y), (p, rf, rk), b, radiance, albedo_at);
        }
        arch.prepare_input(b, &mut patch_input);
        input.extend(patch_input);
        match b {
            Branch::Specular => noisy.extend(region.into_iter().map(|v| arch.specular.kernel_input(v))),
            Branch::Diffuse => noisy.extend(region),
        }
        let [t, a, r] = &mut crops;
        target.append(t);
        albedo.append(a);
        reference.append(r);
    }
    let t = |v, s| super::tensor(v, s).map_err(DataError::from);
    Ok(Batch {
        input: t(input, (n, crate::features::INPUT_CHANNELS, p + 2 * rf, p + 2 * rf))?,
        noisy: t(noisy, (n, 3, p + 2 * rk, p + 2 * rk))?,
        target: t(target, (n, 3, p, p))?,
        albedo: t(albedo, (n, 3, p, p))?,
        reference: t(reference, (n, 3, p, p))?,
        exposure: t(frames.iter().map(|f| f.features.exposure).collect(), (n, 1, 1, 1))?,
    })
}

/// Adds `radiance` (grey) at output pixel `at` of one patch's branch input (c̃, its
/// gradients and its variance) and of its noisy region (c̃), as a single very bright
/// sample would: c̃ rises by the demodulated radiance (diffuse) or to ln(e^c̃ + radiance)
/// (specular), the backward differences of that pixel and of its right and lower
/// neighbours change by as much, and the variance of the mean by its square.
fn add_firefly(
    input: &mut [f32],
    region: &mut [f32],
    (x, y): (usize, usize),
    (p, rf, rk): (usize, usize, usize),
    b: Branch,
    radiance: f32,
    albedo: impl Fn(usize) -> f32,
) {
    let (si, sn) = (p + 2 * rf, p + 2 * rk);
    let plane = si * si;
    let (ix, iy) = (x + rf, y + rf);
    for c in 0..3 {
        let i = c * plane + iy * si + ix;
        let before = input[i];
        let after = match b {
            Branch::Diffuse => before + demodulated(radiance, albedo(c).max(0.0)),
            Branch::Specular => (before.exp() + radiance).ln(),
        };
        let delta = sanitize(after - before);
        input[i] = sanitize(after);
        region[c * sn * sn + (y + rk) * sn + x + rk] = sanitize(after);
        // Gradients along x (channels 3..6) and y (13..16) of c̃.
        input[(3 + c) * plane + iy * si + ix] += delta;
        if ix + 1 < si {
            input[(3 + c) * plane + iy * si + ix + 1] -= delta;
        }
        input[(13 + c) * plane + iy * si + ix] += delta;
        if iy + 1 < si {
            input[(13 + c) * plane + (iy + 1) * si + ix] -= delta;
        }
        // The branch's variance (channel 23, the channel average) grows by delta²/3.
        input[23 * plane + iy * si + ix] = sanitize(input[23 * plane + iy * si + ix] + delta * delta / 3.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn darts_keep_their_spacing_and_fill_the_frame() {
        let (w, h) = (320, 180);
        let pts = dart_throw(w, h, CANDIDATES, &mut SplitMix64(7));
        assert_eq!(pts.len(), CANDIDATES);
        let spacing = 0.7 * ((w * h) as f64 / CANDIDATES as f64).sqrt();
        for (i, a) in pts.iter().enumerate() {
            assert!(a.0 < w && a.1 < h);
            for b in &pts[..i] {
                let d = ((a.0 as f64 - b.0 as f64).powi(2) + (a.1 as f64 - b.1 as f64).powi(2)).sqrt();
                assert!(d >= spacing, "{a:?} {b:?} {d}");
            }
        }
        // Every quarter of the frame gets about a quarter of the darts.
        let left_top = pts.iter().filter(|p| p.0 < w / 2 && p.1 < h / 2).count();
        assert!((70..=130).contains(&left_top), "{left_top}");
    }

    #[test]
    fn error_diffusion_follows_importance_and_keeps_easy_regions() {
        let (w, h) = (320, 180);
        // The right half is hard (importance 1), the left half easy (0).
        let imp: Vec<f32> = (0..w * h).map(|i| if i % w >= w / 2 { 1.0 } else { 0.0 }).collect();
        let cand = dart_throw(w, h, CANDIDATES, &mut SplitMix64(3));
        let kept = error_diffusion(&cand, &imp, w, KEPT);
        assert!((KEPT - 2..=KEPT + 2).contains(&kept.len()), "{}", kept.len());
        let hard = kept.iter().filter(|p| p.0 >= w / 2).count();
        let easy = kept.len() - hard;
        // Expected split 1.0 : 0.1 of the weight → about 91 : 9.
        assert!(hard > 80 && easy >= 4, "hard {hard} easy {easy}");
        // Uniform importance keeps an even spread.
        let flat = error_diffusion(&cand, &vec![0.5; w * h], w, KEPT);
        let right = flat.iter().filter(|p| p.0 >= w / 2).count();
        assert!((35..=65).contains(&right), "{right}");
    }
}
