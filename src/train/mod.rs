//! Training: patches from rendered frames (the simulator's or a Cycles corpus), each
//! branch scored on its own target in phase 1, then both on the recomposed colour in
//! phase 2 ([`Loss`]: L1 as Bako et al., or the relative loss that seeks the mean), Adam,
//! and checkpoints that resume exactly.
//!
//! Convolutions and kernel application run on our own kernels with explicit backward
//! passes ([`crate::kernel::ops`]), the same forward code as inference; `--stock-candle`
//! runs candle's own ops instead, for comparison.

pub mod augment;
pub mod cache;
pub mod curves;
pub mod data;
pub mod losses;
pub mod optimiser;
pub mod records;

use crate::features::Branch;
use crate::kernel::ops::Ops;
#[cfg(doc)]
use crate::model::Architecture;
use crate::model::{BranchWeights, Design, Kind, Model, ModelError, multiscale};
use augment::{ChannelOrder, Orientation};
use candle_core::{DType, Device, Tensor, Var};
pub use losses::{Loss, LossScale, l1, recompose, relative_l2, tonemapped_l1};
pub use optimiser::Adam;
pub use records::LogRow;

/// Trainable copies of a model's weights.
pub struct TrainableModel {
    /// Architecture and description of the model being trained.
    pub base: Model,
    /// Diffuse branch (weight, bias) per layer.
    pub diffuse: Vec<(Var, Var)>,
    /// Specular branch.
    pub specular: Vec<(Var, Var)>,
    /// The implementation the graph runs (ours unless measuring against candle's).
    pub ops: Ops,
}

fn vars(b: &BranchWeights) -> Result<Vec<(Var, Var)>, ModelError> {
    b.layers.iter().map(|(w, bias)| Ok((Var::from_tensor(w)?, Var::from_tensor(bias)?))).collect()
}

fn weights(v: &[(Var, Var)]) -> BranchWeights {
    BranchWeights { layers: v.iter().map(|(w, b)| (w.as_tensor().clone(), b.as_tensor().clone())).collect() }
}

impl TrainableModel {
    /// Makes a model's weights trainable.
    pub fn new(m: &Model) -> Result<TrainableModel, ModelError> {
        Ok(TrainableModel {
            base: m.clone(),
            diffuse: vars(&m.diffuse)?,
            specular: vars(&m.specular)?,
            ops: Ops::default(),
        })
    }

    /// All variables of a branch (or both), flattened.
    pub fn vars(&self, diffuse: bool, specular: bool) -> Vec<Var> {
        let pick = |v: &Vec<(Var, Var)>| v.iter().flat_map(|(w, b)| [w.clone(), b.clone()]).collect::<Vec<_>>();
        let mut out = Vec::new();
        if diffuse {
            out.extend(pick(&self.diffuse));
        }
        if specular {
            out.extend(pick(&self.specular));
        }
        out
    }

    /// The current weights as an inference model.
    pub fn snapshot(&self, description: &str) -> Result<Model, ModelError> {
        let copy = |v: &[(Var, Var)]| -> Result<BranchWeights, ModelError> {
            Ok(BranchWeights {
                layers: v.iter().map(|(w, b)| Ok((w.as_tensor().copy()?, b.as_tensor().copy()?))).collect::<Result<
                    _,
                    ModelError,
                >>(
                )?,
            })
        };
        Ok(Model {
            arch: self.base.arch,
            diffuse: copy(&self.diffuse)?,
            specular: copy(&self.specular)?,
            description: description.into(),
        })
    }

    /// A branch's prediction for a batch (inputs with [`Architecture::train_margins`]
    /// around the patches): d̂ or ŝ, `[B, 3, p, p]`.
    pub fn predict(&self, branch: Branch, input: &Tensor, noisy: &Tensor) -> Result<Tensor, ModelError> {
        let w = weights(match branch {
            Branch::Diffuse => &self.diffuse,
            Branch::Specular => &self.specular,
        });
        let arch = &self.base.arch;
        if arch.design == Design::MultiScale {
            let (m, _) = arch.train_margins();
            let (_, _, h, wd) = input.dims4()?;
            let graph = multiscale::Graph { arch, weights: &w, ops: self.ops };
            let out = multiscale::run(arch, &graph, input.clone(), noisy.clone())?;
            return Ok(out.narrow(2, m, h - 2 * m)?.narrow(3, m, wd - 2 * m)?);
        }
        let out = w.forward(input)?;
        match arch.kind {
            Kind::Kpcn => Ok(self.ops.apply_kernels(&out, noisy, arch.kernel_size)?),
            Kind::Dpcn => Ok(out),
        }
    }
}

/// A scalar tensor's value.
pub fn scalar(t: &Tensor) -> Result<f32, ModelError> {
    Ok(t.to_dtype(DType::F32)?.to_scalar::<f32>()?)
}

/// A tensor on the CPU from a flat vector.
pub fn tensor(data: Vec<f32>, shape: (usize, usize, usize, usize)) -> Result<Tensor, ModelError> {
    Ok(Tensor::from_vec(data, shape, &Device::Cpu)?)
}

/// How to train.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    /// Phase-1 steps (each branch alone, on its own target).
    pub phase1_steps: u64,
    /// Phase-2 steps (both branches, on the recomposed colour).
    pub phase2_steps: u64,
    /// Patches per step.
    pub batch: usize,
    /// Output patch side.
    pub patch: usize,
    /// Phase-1 learning rate.
    pub lr: f64,
    /// Phase-2 learning rate.
    pub lr_phase2: f64,
    /// Seed of patch sampling.
    pub seed: u64,
    /// Importance-sampled patches (else uniform).
    pub importance: bool,
    /// Steps between checkpoints.
    pub checkpoint_every: u64,
    /// Steps between validations.
    pub validate_every: u64,
    /// The implementation the training graph runs (candle's stock ops only to compare).
    pub ops: Ops,
    /// Cosine learning-rate decay within each phase, from its rate down to
    /// [`COSINE_FLOOR`] of it; else constant rates.
    pub cosine: bool,
    /// The loss.
    pub loss: Loss,
    /// The weight of `relmse-light`'s block term (1 by default).
    pub block_weight: f64,
    /// Where the loss charges errors.
    pub loss_scale: LossScale,
    /// Each patch in one of the square's eight orientations, drawn at random.
    pub augment: bool,
    /// Fireflies added to each patch's noisy input (never to its reference), if any.
    pub fireflies: Option<Fireflies>,
    /// Each patch's colour channels in one of the six orders, drawn at random.
    pub permute_channels: bool,
    /// Phase 1 trains only this branch (the other keeps its weights); `None`: both.
    pub only: Option<Branch>,
}

/// How many fireflies `--fireflies` adds to a patch, and how bright.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fireflies {
    /// Each patch gets 0 to `most` of them, as many patches with each count.
    pub most: u64,
    /// The dimmest as a power of ten of the patch's mean; the brightest is 10⁴ of it, and
    /// the gain is log-uniform in between.
    pub min_decades: f64,
}

impl Default for Fireflies {
    /// Up to 3 per patch, 10^1.5 (≈ 32) to 10⁴ times the patch's mean.
    fn default() -> Self {
        Fireflies { most: 3, min_decades: 1.5 }
    }
}

/// Where a cosine schedule ends, as a fraction of the phase's starting rate.
pub const COSINE_FLOOR: f64 = 0.05;

impl TrainOptions {
    /// The learning rate of step `step` (1-based, counted over both phases): a function
    /// of the step alone, so a resumed run follows the same schedule.
    pub fn learning_rate(&self, step: u64) -> f64 {
        let (base, at, len) = if step <= self.phase1_steps {
            (self.lr, step, self.phase1_steps)
        } else {
            (self.lr_phase2, step - self.phase1_steps, self.phase2_steps)
        };
        if !self.cosine || len <= 1 {
            return base;
        }
        let t = (at.saturating_sub(1)) as f64 / (len - 1) as f64;
        base * (COSINE_FLOOR + (1.0 - COSINE_FLOOR) * 0.5 * (1.0 + (std::f64::consts::PI * t).cos()))
    }
}

/// relMSE of the denoised held-out frames against their references.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Validation {
    /// Mean over frames.
    pub mean: f64,
    /// Median over frames.
    pub median: f64,
}

/// Errors of a training run.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// Tensor or model-file work failed.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// Data problems.
    #[error(transparent)]
    Data(#[from] data::DataError),
    /// Validation denoising failed.
    #[error(transparent)]
    Denoise(#[from] crate::denoise::DenoiseError),
    /// Nothing to train on.
    #[error(
        "the dataset has no training frames of at least {0}×{0} pixels — render larger frames or use a smaller --patch"
    )]
    NoData(usize),
    /// A checkpoint that does not belong to this run.
    #[error("{0}")]
    Checkpoint(String),
    /// Options that do not fit the network.
    #[error("{0}")]
    Options(String),
}

/// Checkpoint file inside the output folder: the model plus optimiser state; it also loads
/// as a model.
pub const CHECKPOINT: &str = "checkpoint.safetensors";

/// A training run: model, optimisers, sampler state.
pub struct Trainer<'a> {
    /// The weights being trained.
    pub model: TrainableModel,
    data: &'a data::Dataset,
    opts: TrainOptions,
    adam_d: Adam,
    adam_s: Adam,
    adam_c: Adam,
    rng: crate::rng::SplitMix64,
    /// Steps done.
    pub step: u64,
}

impl<'a> Trainer<'a> {
    /// Starts from `model`.
    pub fn new(model: &Model, data: &'a data::Dataset, opts: TrainOptions) -> Result<Trainer<'a>, TrainError> {
        let usable = data.train.iter().any(|f| f.features.width >= opts.patch && f.features.height >= opts.patch);
        if !usable {
            return Err(TrainError::NoData(opts.patch));
        }
        let (margin, _) = model.arch.train_margins();
        let align = model.arch.alignment();
        if !(opts.patch + 2 * margin).is_multiple_of(align) {
            return Err(TrainError::Options(format!(
                "--patch {} does not suit this network: patch + {} context pixels must be a multiple of {align} (try --patch {})",
                opts.patch,
                2 * margin,
                (opts.patch + 2 * margin).next_multiple_of(align) - 2 * margin
            )));
        }
        let mut model = TrainableModel::new(model)?;
        model.ops = opts.ops;
        Ok(Trainer {
            adam_d: Adam::new(&model.vars(true, false), opts.lr)?,
            adam_s: Adam::new(&model.vars(false, true), opts.lr)?,
            adam_c: Adam::new(&model.vars(true, true), opts.lr_phase2)?,
            model,
            data,
            rng: crate::rng::SplitMix64(opts.seed),
            opts,
            step: 0,
        })
    }

    /// Continues from a checkpoint written by [`Trainer::save`].
    pub fn resume(
        path: &std::path::Path,
        data: &'a data::Dataset,
        opts: TrainOptions,
    ) -> Result<Trainer<'a>, TrainError> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io { path: path.into(), source })?;
        let model = Model::from_bytes(&bytes, &path.display().to_string())?;
        let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)
            .map_err(|e| TrainError::Checkpoint(format!("{}: {e}", path.display())))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let num = |k: &str| -> Result<u64, TrainError> {
            meta.get(k).and_then(|v| v.parse().ok()).ok_or_else(|| {
                TrainError::Checkpoint(format!("{}: not a training checkpoint (no `{k}`)", path.display()))
            })
        };
        let (step, rng) = (num("kpcn:train_step")?, num("kpcn:train_rng")?);
        let tensors = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu).map_err(ModelError::from)?;
        let mut t = Trainer::new(&model, data, opts)?;
        let sub = |prefix: &str| -> std::collections::HashMap<String, Tensor> {
            tensors
                .iter()
                .filter_map(|(k, v)| k.strip_prefix(prefix).map(|r| (format!("adam.{r}"), v.clone())))
                .collect()
        };
        t.adam_d.restore(&sub("adam_d."), step.min(t.opts.phase1_steps))?;
        t.adam_s.restore(&sub("adam_s."), step.min(t.opts.phase1_steps))?;
        t.adam_c.restore(&sub("adam_c."), step.saturating_sub(t.opts.phase1_steps))?;
        t.rng = crate::rng::SplitMix64(rng);
        t.step = step;
        Ok(t)
    }

    /// Writes a checkpoint (atomically).
    pub fn save(&self, path: &std::path::Path) -> Result<(), TrainError> {
        let model = self.model.snapshot(&format!("training checkpoint, step {}", self.step))?;
        let mut extra = Vec::new();
        for (prefix, adam) in [("adam_d.", &self.adam_d), ("adam_s.", &self.adam_s), ("adam_c.", &self.adam_c)] {
            extra.extend(adam.state().into_iter().map(|(k, v)| (format!("{prefix}{}", &k["adam.".len()..]), v)));
        }
        let meta = [("kpcn:train_step", self.step.to_string()), ("kpcn:train_rng", self.rng.0.to_string())]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect();
        crate::model::write_atomically(path, &model.to_bytes_with(extra, meta)?)?;
        Ok(())
    }

    /// Whether all steps are done.
    pub fn finished(&self) -> bool {
        self.step >= self.opts.phase1_steps + self.opts.phase2_steps
    }

    fn sample(&mut self) -> (Vec<&'a data::Frame>, Vec<(usize, usize)>, Vec<data::Augmentation>) {
        let p = self.opts.patch;
        let usable: Vec<&data::Frame> =
            self.data.train.iter().filter(|f| f.features.width >= p && f.features.height >= p).collect();
        let mut patches = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..self.opts.batch {
            let f = usable[(self.rng.next_u64() % usable.len() as u64) as usize];
            patches.0.push(f);
            patches.1.push(f.patch_origin(p, self.rng.uniform_f64(), self.opts.importance));
            // Drawn only when asked for, so runs without them keep their patch sequence.
            let mut aug = data::Augmentation::default();
            if self.opts.augment {
                aug.orientation = Orientation::from_index(self.rng.next_u64() % 8);
            }
            if self.opts.permute_channels {
                aug.channels = ChannelOrder::from_index(self.rng.next_u64() % 6);
            }
            if let Some(ff) = self.opts.fireflies {
                for _ in 0..self.rng.next_u64() % (ff.most + 1) {
                    let (x, y) = ((self.rng.next_u64() % p as u64) as usize, (self.rng.next_u64() % p as u64) as usize);
                    let gain = 10f64.powf(ff.min_decades + (4.0 - ff.min_decades) * self.rng.uniform_f64()) as f32;
                    let diffuse = self.rng.next_u64().is_multiple_of(2);
                    aug.fireflies.push(data::Firefly { x, y, gain, diffuse });
                }
            }
            patches.2.push(aug);
        }
        patches
    }

    /// One optimisation step.
    pub fn train_step(&mut self) -> Result<LogRow, TrainError> {
        let t = std::time::Instant::now();
        let (frames, origins, augmentations) = self.sample();
        let arch = self.model.base.arch;
        let p = self.opts.patch;
        let bd = data::batch_augmented(&frames, &origins, &augmentations, p, &arch, Branch::Diffuse)?;
        let bs = data::batch_augmented(&frames, &origins, &augmentations, p, &arch, Branch::Specular)?;
        self.step += 1;
        let mut row = LogRow {
            step: self.step,
            phase: 1,
            loss_diffuse: f64::NAN,
            loss_specular: f64::NAN,
            loss_combined: f64::NAN,
            validation_relmse: None,
            validation_median_relmse: None,
            patches_per_second: 0.0,
            dev_relmse: None,
        };
        let lr = self.opts.learning_rate(self.step);
        (self.adam_d.lr, self.adam_s.lr, self.adam_c.lr) = (lr, lr, lr);
        let (loss, w) = (self.opts.loss, self.opts.block_weight);
        if self.step <= self.opts.phase1_steps {
            if self.opts.only != Some(Branch::Specular) {
                let d_hat = self.model.predict(Branch::Diffuse, &bd.input, &bd.noisy)?;
                let ld = loss.radiance(&d_hat, &bd.target, w, self.exposure(&bd))?;
                self.adam_d.step(&self.model.vars(true, false), &ld)?;
                row.loss_diffuse = scalar(&ld)? as f64;
            }
            if self.opts.only != Some(Branch::Diffuse) {
                let s_hat = self.model.predict(Branch::Specular, &bs.input, &bs.noisy)?;
                let ls = loss.specular(arch.specular, &s_hat, &bs.target, w, self.exposure(&bs))?;
                self.adam_s.step(&self.model.vars(false, true), &ls)?;
                row.loss_specular = scalar(&ls)? as f64;
            }
        } else {
            row.phase = 2;
            let d = self.model.predict(Branch::Diffuse, &bd.input, &bd.noisy)?;
            let s = self.model.predict(Branch::Specular, &bs.input, &bs.noisy)?;
            let c = recompose(&bd.albedo, &d, &s, arch.specular)?;
            let lc = loss.radiance(&c, &bd.reference, w, self.exposure(&bd))?;
            self.adam_c.step(&self.model.vars(true, true), &lc)?;
            row.loss_combined = scalar(&lc)? as f64;
        }
        row.patches_per_second = self.opts.batch as f64 / t.elapsed().as_secs_f64().max(1e-9);
        Ok(row)
    }

    /// What the loss divides a batch by first: its patches' exposures, where
    /// [`TrainOptions::loss_scale`] asks for the rendered scale.
    fn exposure<'b>(&self, batch: &'b data::Batch) -> Option<&'b Tensor> {
        (self.opts.loss_scale == LossScale::Rendered).then_some(&batch.exposure)
    }

    /// Mean relMSE of the denoised held-out frames (None without validation frames).
    pub fn validate(&self) -> Result<Option<Validation>, TrainError> {
        if self.data.validation.is_empty() {
            return Ok(None);
        }
        let mut errors = self.relmse(self.data.validation.iter().map(|f| (&f.features, &f.reference)))?;
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        errors.sort_by(f64::total_cmp);
        let n = errors.len();
        let median = if n % 2 == 1 { errors[n / 2] } else { (errors[n / 2 - 1] + errors[n / 2]) / 2.0 };
        Ok(Some(Validation { mean, median }))
    }

    /// Geometric mean relMSE of a check set's denoised frames (None when it is empty): how
    /// the Cycles dev set's table (`benches/quality_cycles.sh`) summarises.
    pub fn check(&self, set: &data::CheckSet) -> Result<Option<f64>, TrainError> {
        if set.frames.is_empty() {
            return Ok(None);
        }
        let errors = self.relmse(set.frames.iter().map(|f| (&f.features, &f.reference)))?;
        Ok(Some((errors.iter().map(|e| e.max(1e-12).ln()).sum::<f64>() / errors.len() as f64).exp()))
    }

    /// relMSE of each frame denoised by the current weights against its reference.
    fn relmse<'f>(
        &self,
        frames: impl Iterator<Item = (&'f crate::features::Features, &'f [Vec<f32>; 3])>,
    ) -> Result<Vec<f64>, TrainError> {
        let model = self.model.snapshot("validation")?;
        let d = crate::denoise::Denoiser::new(model, crate::denoise::Options::default())?;
        frames
            .map(|(features, reference)| {
                let out = d.denoise_features(features, &|_| true)?;
                Ok(crate::eval::relmse(crate::eval::rgb(&out.color), crate::eval::rgb(reference)))
            })
            .collect()
    }

    /// The options.
    pub fn options(&self) -> &TrainOptions {
        &self.opts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cosine_schedule_starts_at_each_phase_rate_and_ends_at_its_floor() {
        let o = TrainOptions {
            phase1_steps: 101,
            phase2_steps: 11,
            batch: 1,
            patch: 8,
            lr: 1e-3,
            lr_phase2: 1e-4,
            seed: 0,
            importance: false,
            checkpoint_every: 1,
            validate_every: 1,
            ops: Default::default(),
            cosine: true,
            loss: Loss::L1,
            block_weight: 1.0,
            loss_scale: LossScale::Exposed,
            augment: false,
            fireflies: None,
            permute_channels: false,
            only: None,
        };
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(o.learning_rate(1), 1e-3));
        assert!(close(o.learning_rate(51), 1e-3 * (0.5 + COSINE_FLOOR / 2.0)));
        assert!(close(o.learning_rate(101), 1e-3 * COSINE_FLOOR));
        assert!(close(o.learning_rate(102), 1e-4));
        assert!(close(o.learning_rate(112), 1e-4 * COSINE_FLOOR));
        assert!((2..=101).all(|s| o.learning_rate(s) < o.learning_rate(s - 1)));
        let constant = TrainOptions { cosine: false, ..o };
        assert!(close(constant.learning_rate(60), 1e-3) && close(constant.learning_rate(110), 1e-4));
    }
}
