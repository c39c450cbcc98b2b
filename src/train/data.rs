//! Training data: frames listed in a `kpcn dataset` manifest, their reference targets, an
//! importance map, and batches of patches.

use crate::features::{Branch, EPSILON, Features, log_specular, sanitize};
use crate::io::FrameBuffers;
use crate::io::layout::{KpcnInputs, Mapping, box3};
use crate::model::{Architecture, ModelError};
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
    /// Cumulative distribution of patch positions (importance sampling).
    cdf: Vec<f64>,
}

/// Frames for training and whole held-out scenes for validation.
pub struct Dataset {
    /// Training frames.
    pub train: Vec<Frame>,
    /// Validation frames (scenes never seen in training).
    pub validation: Vec<Frame>,
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
    /// A frame could not be read or lacks channels.
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    /// Tensor work failed.
    #[error(transparent)]
    Model(#[from] ModelError),
}

fn inputs(path: &Path) -> Result<KpcnInputs, DataError> {
    let fb = FrameBuffers::read(path)?;
    Ok(Mapping::for_frame(&fb, None).extract(&fb)?)
}

/// Importance of each pixel as a patch centre (SPEC §4): box-filtered relative variance of
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
    fn new(scene: String, spp: u32, noisy: &KpcnInputs, reference: &KpcnInputs) -> Frame {
        let target_d = std::array::from_fn(|c| {
            reference.diffuse[c]
                .iter()
                .zip(&reference.albedo[c])
                .map(|(d, a)| sanitize(sanitize(*d) / (sanitize(*a).max(0.0) + EPSILON)))
                .collect()
        });
        let target_s = std::array::from_fn(|c| {
            log_specular(&reference.specular[c].iter().map(|&v| sanitize(v)).collect::<Vec<_>>())
        });
        let imp = importance(noisy, 8);
        // Mix in uniform so easy regions still appear.
        let mut acc = 0f64;
        let cdf = imp.iter().map(|&v| {
            acc += 0.8 * v as f64 + 0.2;
            acc
        });
        Frame {
            scene,
            spp,
            features: Features::new(noisy),
            target_d,
            target_s,
            reference: std::array::from_fn(|c| reference.color[c].iter().map(|&v| sanitize(v)).collect()),
            cdf: cdf.collect(),
        }
    }

    /// A patch's top-left corner for an output of `p`×`p`: importance-sampled when
    /// `importance`, else uniform. `u` in [0, 1).
    pub fn patch_origin(&self, p: usize, u: f64, importance: bool) -> (usize, usize) {
        let (w, h) = (self.features.width, self.features.height);
        let i = if importance {
            let t = u * self.cdf.last().copied().unwrap_or(0.0);
            self.cdf.partition_point(|&c| c < t).min(w * h - 1)
        } else {
            ((u * (w * h) as f64) as usize).min(w * h - 1)
        };
        let (cx, cy) = (i % w, i / w);
        (cx.saturating_sub(p / 2).min(w.saturating_sub(p)), cy.saturating_sub(p / 2).min(h.saturating_sub(p)))
    }
}

impl Dataset {
    /// Loads the frames of a `kpcn dataset` folder; every `holdout_every`-th scene (in name
    /// order) is held out whole for validation.
    pub fn load(dir: &Path, holdout_every: usize) -> Result<Dataset, DataError> {
        let path = dir.join("manifest.csv");
        let text = std::fs::read_to_string(&path)
            .map_err(|e| DataError::Manifest { path: path.clone(), msg: e.to_string() })?;
        let mut rows: Vec<(String, u32, PathBuf, PathBuf)> = Vec::new();
        for (n, line) in text.lines().enumerate().skip(1) {
            let c: Vec<&str> = line.split(',').collect();
            let bad = || DataError::Manifest { path: path.clone(), msg: format!("line {}: expected 8 columns", n + 1) };
            if c.len() < 7 {
                return Err(bad());
            }
            let spp = c[4].parse().map_err(|_| bad())?;
            rows.push((c[0].to_string(), spp, dir.join(c[5]), dir.join(c[6])));
        }
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
        let mut data = Dataset { train: Vec::new(), validation: Vec::new() };
        let mut reference_cache: Option<(PathBuf, KpcnInputs)> = None;
        for (scene, spp, noisy, reference) in rows {
            if reference_cache.as_ref().is_none_or(|(p, _)| *p != reference) {
                reference_cache = Some((reference.clone(), inputs(&reference)?));
            }
            let r = &reference_cache.as_ref().expect("just set").1;
            let frame = Frame::new(scene.clone(), spp, &inputs(&noisy)?, r);
            if held.contains(&&scene) { data.validation.push(frame) } else { data.train.push(frame) }
        }
        Ok(data)
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
}

fn crop(planes: &[Vec<f32>; 3], w: usize, x0: usize, y0: usize, p: usize, out: &mut Vec<f32>) {
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
    let (rf, rk) = (arch.feature_radius(), arch.kernel_radius());
    let n = frames.len();
    let (mut input, mut noisy, mut target, mut albedo, mut reference) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (f, &(x0, y0)) in frames.iter().zip(origins) {
        let fe = &f.features;
        input.extend(fe.branch_input(b, x0 as isize - rf as isize, y0 as isize - rf as isize, p + 2 * rf, p + 2 * rf));
        let c = fe.colour(b);
        noisy.extend(fe.region(
            &[&c[0], &c[1], &c[2]],
            x0 as isize - rk as isize,
            y0 as isize - rk as isize,
            p + 2 * rk,
            p + 2 * rk,
        ));
        let t = match b {
            Branch::Diffuse => &f.target_d,
            Branch::Specular => &f.target_s,
        };
        crop(t, fe.width, x0, y0, p, &mut target);
        crop(&fe.albedo, fe.width, x0, y0, p, &mut albedo);
        crop(&f.reference, fe.width, x0, y0, p, &mut reference);
    }
    let t = |v, s| super::tensor(v, s).map_err(DataError::from);
    Ok(Batch {
        input: t(input, (n, crate::features::INPUT_CHANNELS, p + 2 * rf, p + 2 * rf))?,
        noisy: t(noisy, (n, 3, p + 2 * rk, p + 2 * rk))?,
        target: t(target, (n, 3, p, p))?,
        albedo: t(albedo, (n, 3, p, p))?,
        reference: t(reference, (n, 3, p, p))?,
    })
}
