//! KPCN and DPCN networks in candle, their architectures, and model files.
//!
//! A branch is `layers` convolutions (`conv_size`², `channels` wide, ReLU after all but the
//! last, no padding: each layer trims `(conv_size − 1) / 2` pixels per side, so a tile is
//! fed with a halo of [`Architecture::feature_radius`]). KPCN's last layer predicts
//! `kernel_size²` weights per pixel, DPCN's 3 colours.

use candle_core::{DType, Device, Tensor};
use std::path::PathBuf;

mod architecture;
mod format;
pub mod multiscale;
pub mod pyramid;
pub mod registry;
pub mod stream;

pub use architecture::{
    Architecture, Clamp, Design, DiffuseInput, Exposure, Kind, MAX_DIFFUSE_DETAIL, MAX_DIFFUSE_SPREAD, Preprocessing,
    Quality, SIGNIFICANT_ERRORS, ScaleBlend, Specular, Variances,
};
pub use format::{
    FORMAT_VERSION, model_file_with_bound, model_file_with_clamp, model_file_with_detail, model_file_with_spread,
    write_atomically,
};

/// Room for the small buffers of a denoiser's first frame (thread arenas, the kernel's
/// buffer pool), checked with the model's weights when it loads.
pub const LOADING_HEADROOM: usize = 64 << 20;

/// Errors loading, saving or running models.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// File system.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not a kpcn model file, or one of another layout or version.
    #[error("{origin}: {what} — use a model file written by this version of kpcn, or a built-in model name")]
    Format {
        /// File or preset name.
        origin: String,
        /// What is wrong.
        what: String,
    },
    /// A name that is no shipped model, preset or model file.
    #[error(
        "unknown model `{0}` — use a shipped model ({names}), a .safetensors file, or an untrained preset ({presets}; for testing)",
        names = registry::shipped_names(),
        presets = registry::PRESETS.map(|p| format!("`{p}`")).join(", ")
    )]
    UnknownPreset(String),
    /// The process is short of memory before any frame: not even the model loads.
    #[error("out of memory: loading the model needs about {} MB and the process cannot get it — raise its memory limit (ulimit -v, the farm's or container's): kpcn needs a few hundred MB for its libraries and model, plus --max-memory (the C ABI's max_memory_mb)", .0 >> 20)]
    OutOfMemory(usize),
    /// A tensor computation failed.
    #[error("network evaluation failed: {0}")]
    Candle(#[from] candle_core::Error),
}

/// One branch's weights: per layer (weight `[out, in, k, k]`, bias `[out]`), in the order
/// of [`Architecture::layer_shapes`].
#[derive(Debug, Clone)]
pub struct BranchWeights {
    /// Layers.
    pub layers: Vec<(Tensor, Tensor)>,
}

impl BranchWeights {
    /// Evaluates a flat branch on a `[1, 27, h + 2r, w + 2r]` input; returns `[1, out, h, w]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor, ModelError> {
        let mut x = x.clone();
        let n = self.layers.len();
        for (l, (w, b)) in self.layers.iter().enumerate() {
            let cout = b.dims1()?;
            x = x.conv2d(w, 0, 1, 1, 1)?.broadcast_add(&b.reshape((1, cout, 1, 1))?)?;
            if l + 1 < n {
                x = x.relu()?;
            }
        }
        Ok(x)
    }
}

/// A two-branch model.
#[derive(Debug, Clone)]
pub struct Model {
    /// Its shape.
    pub arch: Architecture,
    /// Diffuse branch.
    pub diffuse: BranchWeights,
    /// Specular branch.
    pub specular: BranchWeights,
    /// Free-text description (e.g. what it was trained on, or "untrained").
    pub description: String,
}

impl Model {
    /// Xavier-uniform weights, zero biases, from `seed`: an untrained model.
    pub fn xavier(arch: Architecture, seed: u64) -> Result<Model, ModelError> {
        arch.validate("xavier")?;
        let mut rng = crate::rng::SplitMix64(seed);
        let mut branch = || -> Result<BranchWeights, ModelError> {
            let layers = arch
                .layer_shapes()
                .into_iter()
                .map(|(o, i, k)| {
                    let a = (6.0 / ((i + o) * k * k) as f32).sqrt();
                    let w: Vec<f32> = (0..o * i * k * k).map(|_| (2.0 * rng.uniform_f32() - 1.0) * a).collect();
                    Ok((Tensor::from_vec(w, (o, i, k, k), &Device::Cpu)?, Tensor::zeros(o, DType::F32, &Device::Cpu)?))
                })
                .collect::<Result<_, ModelError>>()?;
            Ok(BranchWeights { layers })
        };
        let diffuse = branch()?;
        let specular = branch()?;
        Ok(Model { arch, diffuse, specular, description: format!("untrained (Xavier-uniform, seed {seed})") })
    }

    /// The same model with a gain ([`Architecture::gain`]) of exactly 1: the
    /// full-resolution head of each branch gains a row of zero weights and a zero bias, so
    /// every output keeps its bits until training moves them. A model that has a gain is
    /// returned as it is.
    pub fn with_gain(mut self) -> Result<Model, ModelError> {
        if self.arch.gain {
            return Ok(self);
        }
        let arch = Architecture { gain: true, ..self.arch };
        arch.validate("with_gain")?;
        for branch in [&mut self.diffuse, &mut self.specular] {
            let (w, b) = branch.layers.last_mut().ok_or_else(|| ModelError::Format {
                origin: "with_gain".into(),
                what: "a branch without layers".into(),
            })?;
            *w = Tensor::cat(&[&*w, &w.narrow(0, 0, 1)?.zeros_like()?], 0)?;
            *b = Tensor::cat(&[&*b, &b.narrow(0, 0, 1)?.zeros_like()?], 0)?;
        }
        self.arch = arch;
        Ok(self)
    }

    /// Whether the description marks it untrained.
    pub fn is_untrained(&self) -> bool {
        self.description.starts_with("untrained")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::Branch;
    use std::path::Path;

    #[test]
    fn budgets_pick_smaller_tiles_for_bigger_networks() {
        use crate::tile::{Axis, Reach, size_for_regions};
        let budget = 256 << 20;
        let side = |a: Architecture, budget: usize, w: usize, h: usize| {
            let r = a.feature_radius().max(a.kernel_radius());
            let reach = Reach::square(r, r, 1);
            size_for_regions(
                Axis::whole(w),
                Axis::whole(h),
                &reach,
                16,
                |rw, rh, tw, th| a.region_bytes(rw, rh, tw, th),
                budget,
            )
        };
        let (paper, small) = (Architecture::paper(Kind::Kpcn), Architecture::small(Kind::Kpcn));
        let (tp, ts) = (side(paper, budget, 1920, 1080), side(small, budget, 1920, 1080));
        assert!(tp.0 * tp.1 < ts.0 * ts.1, "{tp:?} vs {ts:?}");
        assert!(paper.region_bytes(tp.0 + 2 * 18, tp.1 + 2 * 18, tp.0, tp.1) <= budget);
        assert_eq!(side(small, usize::MAX, 40, 20), (48, 32));
    }

    #[test]
    fn a_gain_of_zero_weights_keeps_every_bit_and_is_recorded() {
        use crate::features::INPUT_CHANNELS;
        let model = Model::resolve("balanced").unwrap();
        let gained = model.clone().with_gain().unwrap();
        assert!(gained.arch.gain && !model.arch.gain);
        let read = Model::from_bytes(&gained.to_bytes().unwrap(), "mem").unwrap();
        assert!(read.arch.gain, "the gain is recorded in the file");
        let (w, h) = (64, 64);
        let mut rng = crate::rng::SplitMix64(7);
        let input: Vec<f32> = (0..INPUT_CHANNELS * w * h).map(|_| rng.uniform_f32() - 0.5).collect();
        let noisy: Vec<f32> =
            (0..4 * w * h).map(|_| if rng.uniform_f32() < 0.02 { 40.0 } else { rng.uniform_f32() }).collect();
        for (a, b) in [(&model.diffuse, &read.diffuse), (&model.specular, &read.specular)] {
            let run = |arch: &Architecture, weights: &BranchWeights| {
                let weights = pyramid::Weights::new(arch, weights).unwrap();
                pyramid::forward(arch, &weights, input.clone(), noisy.clone(), w, h)
            };
            let bits = |v: [Vec<f32>; 3]| v.concat().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert!(bits(run(&model.arch, a)) == bits(run(&read.arch, b)), "a zero gain changed the output");
        }
        // Not for flat networks, and a second call changes nothing.
        assert!(Model::xavier(Architecture::small(Kind::Kpcn), 0).unwrap().with_gain().is_err());
        assert_eq!(read.clone().with_gain().unwrap().diffuse.layers.len(), read.diffuse.layers.len());
    }

    #[test]
    fn the_network_matches_a_hand_computed_convolution() {
        // One 3×3 layer, 27 → 3 (DPCN), weights 1 on input channel 0 only, bias 0.5.
        let arch = Architecture {
            kind: Kind::Dpcn,
            design: Design::Flat,
            layers: 1,
            channels: 3,
            conv_size: 3,
            kernel_size: 1,
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
        };
        let mut w = vec![0f32; 3 * 27 * 9];
        for o in 0..3 {
            for t in 0..9 {
                w[o * 27 * 9 + t] = (o + 1) as f32;
            }
        }
        let layer =
            (Tensor::from_vec(w, (3, 27, 3, 3), &Device::Cpu).unwrap(), Tensor::full(0.5f32, 3, &Device::Cpu).unwrap());
        let m = Model {
            arch,
            diffuse: BranchWeights { layers: vec![layer.clone()] },
            specular: BranchWeights { layers: vec![layer] },
            description: String::new(),
        };
        // Input 4×4 with channel 0 = x + 4y, other channels noise that must not matter... except
        // that weights on them are 0.
        let mut x = vec![0f32; 27 * 16];
        for i in 0..16 {
            x[i] = i as f32;
            x[16 + i] = 100.0;
        }
        let t = Tensor::from_vec(x, (1, 27, 4, 4), &Device::Cpu).unwrap();
        let out = m.diffuse.forward(&t).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        // Valid 3×3 box sums of the ramp at output (0,0): pixels (0..3, 0..3) → sum = 9·5 = 45.
        let sums = [45.0f32, 54.0, 81.0, 90.0];
        for o in 0..3 {
            for (p, s) in sums.iter().enumerate() {
                assert_eq!(out[o * 4 + p], (o + 1) as f32 * s + 0.5);
            }
        }
    }

    #[test]
    fn model_files_round_trip_and_refuse_other_layouts() {
        let m = Model::xavier(
            Architecture {
                kind: Kind::Kpcn,
                design: Design::Flat,
                layers: 2,
                channels: 4,
                conv_size: 3,
                kernel_size: 3,
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
            7,
        )
        .unwrap();
        let bytes = m.to_bytes().unwrap();
        let back = Model::from_bytes(&bytes, "mem").unwrap();
        assert_eq!(back.arch, m.arch);
        assert_eq!(back.description, m.description);
        let a = m.diffuse.layers[1].0.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let b = back.diffuse.layers[1].0.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert_eq!(a, b);

        let mut meta = m.arch.metadata();
        meta.insert("kpcn:input_layout".into(), "kpcn28-2019".into());
        let t = Tensor::zeros(1, DType::F32, &Device::Cpu).unwrap();
        let other = safetensors::serialize([("x", &t)], Some(meta)).unwrap();
        let e = Model::from_bytes(&other, "old.safetensors").unwrap_err().to_string();
        assert!(e.contains("input layout `kpcn28-2019`"), "{e}");
        let e = Model::from_bytes(b"not a model", "junk.safetensors").unwrap_err().to_string();
        assert!(e.contains("junk.safetensors: not a safetensors file"), "{e}");
    }

    #[test]
    fn the_scale_blend_is_written_read_and_checked() {
        let m = Model::xavier(Architecture { blend: ScaleBlend::Detail, ..Architecture::multiscale() }, 5).unwrap();
        assert_eq!(Model::from_bytes(&m.to_bytes().unwrap(), "mem").unwrap().arch.blend, ScaleBlend::Detail);
        // A file from before the choice interpolates.
        let mut meta = m.arch.metadata();
        meta.remove("kpcn:blend");
        let t = Tensor::zeros(1, DType::F32, &Device::Cpu).unwrap();
        let e = Model::from_bytes(&safetensors::serialize([("x", &t)], Some(meta.clone())).unwrap(), "old.safetensors");
        // Its weights are missing, but its architecture was read: the error is about them.
        let e = e.unwrap_err().to_string();
        assert!(!e.contains("blend"), "{e}");
        meta.insert("kpcn:blend".into(), "swirl".into());
        let e = Model::from_bytes(&safetensors::serialize([("x", &t)], Some(meta)).unwrap(), "odd.safetensors");
        let e = e.unwrap_err().to_string();
        assert!(e.contains("odd.safetensors") && e.contains("unknown scale blend `swirl`"), "{e}");
        let flat = Architecture { blend: ScaleBlend::Detail, ..Architecture::small(Kind::Kpcn) };
        assert!(flat.validate("mem").unwrap_err().to_string().contains("no scales to blend"));
    }

    #[test]
    fn bounds_are_written_read_lifted_and_checked() {
        let m = Model::xavier(Architecture::ladder(Quality::Fast), 5).unwrap();
        let bytes = m.to_bytes().unwrap();
        let bounded = model_file_with_bound(&bytes, Branch::Specular, Some(2), "mem").unwrap();
        let bounded = model_file_with_bound(&bounded, Branch::Diffuse, Some(3), "mem").unwrap();
        let b = Model::from_bytes(&bounded, "mem").unwrap();
        assert_eq!(b.arch, Architecture { specular_bound: Some(2), diffuse_bound: Some(3), ..m.arch });
        let w = |m: &Model| m.specular.layers[0].0.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert_eq!(w(&b), w(&m), "weights kept bit for bit");
        let lifted = model_file_with_bound(&bounded, Branch::Specular, None, "mem").unwrap();
        let lifted = model_file_with_bound(&lifted, Branch::Diffuse, None, "mem").unwrap();
        assert_eq!(Model::from_bytes(&lifted, "mem").unwrap().arch, m.arch);
        for key in ["kpcn:specular_bound", "kpcn:diffuse_bound"] {
            let mut meta = m.arch.metadata();
            meta.insert(key.into(), "two".into());
            let t = Tensor::zeros(1, DType::F32, &Device::Cpu).unwrap();
            let odd = safetensors::serialize([("x", &t)], Some(meta)).unwrap();
            let e = Model::from_bytes(&odd, "odd.safetensors").unwrap_err().to_string();
            assert!(e.contains("odd.safetensors") && e.contains(&format!("`{key}` is `two`")), "{e}");
        }
    }

    #[test]
    fn a_diffuse_spread_is_written_read_lifted_with_its_bound_and_checked() {
        let m = Model::xavier(Architecture::ladder(Quality::Fast), 5).unwrap();
        let bytes = m.to_bytes().unwrap();
        let e = model_file_with_spread(&bytes, Some(7), "mem").unwrap_err().to_string();
        assert!(e.contains("needs a diffuse bound"), "{e}");
        let bounded = model_file_with_bound(&bytes, Branch::Diffuse, Some(1), "mem").unwrap();
        let spread = model_file_with_spread(&bounded, Some(7), "mem").unwrap();
        let arch = Model::from_bytes(&spread, "mem").unwrap().arch;
        assert_eq!(arch, Architecture { diffuse_bound: Some(1), diffuse_spread: Some(7), ..m.arch });
        let lost = model_file_with_spread(&spread, None, "mem").unwrap();
        assert_eq!(Model::from_bytes(&lost, "mem").unwrap().arch.diffuse_spread, None);
        let lifted = model_file_with_bound(&spread, Branch::Diffuse, None, "mem").unwrap();
        assert_eq!(Model::from_bytes(&lifted, "mem").unwrap().arch, m.arch);
        let mut meta = arch.metadata();
        meta.insert("kpcn:diffuse_spread".into(), "0".into());
        let t = Tensor::zeros(1, DType::F32, &Device::Cpu).unwrap();
        let odd = safetensors::serialize([("x", &t)], Some(meta)).unwrap();
        let e = Model::from_bytes(&odd, "odd.safetensors").unwrap_err().to_string();
        assert!(e.contains("odd.safetensors") && e.contains("`kpcn:diffuse_spread` is `0`"), "{e}");
    }

    #[test]
    fn a_diffuse_detail_is_written_read_removed_and_checked() {
        let m = Model::xavier(Architecture::ladder(Quality::Fast), 5).unwrap();
        let bytes = m.to_bytes().unwrap();
        let detail = model_file_with_detail(&bytes, Some(7), "mem").unwrap();
        let arch = Model::from_bytes(&detail, "mem").unwrap().arch;
        assert_eq!(arch, Architecture { diffuse_detail: Some(7), ..m.arch });
        let removed = model_file_with_detail(&detail, None, "mem").unwrap();
        assert_eq!(Model::from_bytes(&removed, "mem").unwrap().arch, m.arch);
        let e = model_file_with_detail(&bytes, Some(MAX_DIFFUSE_DETAIL + 1), "mem").unwrap_err().to_string();
        assert!(e.contains("at most 15"), "{e}");
        let mut meta = arch.metadata();
        meta.insert("kpcn:diffuse_detail".into(), "wide".into());
        let t = Tensor::zeros(1, DType::F32, &Device::Cpu).unwrap();
        let odd = safetensors::serialize([("x", &t)], Some(meta)).unwrap();
        let e = Model::from_bytes(&odd, "odd.safetensors").unwrap_err().to_string();
        assert!(e.contains("odd.safetensors") && e.contains("`kpcn:diffuse_detail` is `wide`"), "{e}");
    }

    #[test]
    fn every_rung_of_the_ladder_is_shipped_with_its_architecture() {
        for q in Quality::ALL {
            let m = Model::resolve(q.name()).unwrap();
            // The presets see raw radiance and linear diffuse; `balanced` was fine-tuned
            // auto-exposed, and its diffuse branch to see ln(1 + d̃).
            let balanced = q == Quality::Balanced;
            let exposure = if balanced { Exposure::Auto } else { Exposure::Raw };
            let diffuse_input = if balanced { DiffuseInput::Log } else { DiffuseInput::Linear };
            // `fast` and `balanced` (the default) had their specular branches retrained, and
            // ship with the `significant` clamp, the specular branch bounded, the diffuse
            // branch under a ceiling (`kpcn model bound`) and with its detail restored
            // (`kpcn model detail`); `high` as trained, with the clamp chosen on our corpus
            // (`kpcn model clamp`; models/README.md).
            let steps = q != Quality::High;
            let clamp = if steps { Clamp::Significant } else { Clamp::FinePairsTwice };
            let after = |v: u8| steps.then_some(v);
            let (specular_bound, diffuse_bound, diffuse_detail) = (after(2), after(2), after(7));
            let want = Architecture {
                exposure,
                clamp,
                specular_bound,
                diffuse_bound,
                diffuse_detail,
                diffuse_input,
                ..Architecture::ladder(q)
            };
            assert_eq!(m.arch, want, "{}", q.name());
            assert!(!m.is_untrained() && m.arch.feature_radius() >= 170, "{}", q.name());
        }
        // `spatial` ships under the same ceiling (its errors from the window's median
        // variance) and with its detail restored, its specular branch unbounded.
        let s = Model::resolve("spatial").unwrap().arch;
        assert_eq!(
            (s.variances, s.diffuse_bound, s.diffuse_detail, s.specular_bound),
            (Variances::Spatial, Some(2), Some(7), None)
        );
    }

    #[test]
    fn half_precision_files_load_as_f32_within_f16_rounding() {
        let m = Model::xavier(Architecture::ladder(Quality::Fast), 3).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let (full, half) = (dir.path().join("full.safetensors"), dir.path().join("half.safetensors"));
        m.save(&full).unwrap();
        m.save_half(&half).unwrap();
        let size = |p: &Path| std::fs::metadata(p).unwrap().len();
        assert!(size(&half) * 10 < size(&full) * 6, "{} against {}", size(&half), size(&full));
        let back = Model::load(&half).unwrap();
        assert_eq!(back.arch, m.arch);
        for (a, b) in m.diffuse.layers.iter().zip(&back.diffuse.layers) {
            assert_eq!(b.0.dtype(), DType::F32);
            let a = a.0.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let b = b.0.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= 1e-3 * x.abs().max(1e-4)), "rounded to f16");
        }
    }

    #[test]
    fn the_embedded_default_is_balanced_and_compact_the_3_level_network() {
        let (d, b) = (Model::embedded_default().unwrap(), Model::shipped_rung(Quality::Balanced).unwrap());
        assert_eq!((d.arch, &d.description), (b.arch, &b.description));
        let c = Model::resolve("compact").unwrap();
        assert_eq!(
            c.arch,
            Architecture { exposure: Exposure::Auto, clamp: Clamp::FinePairsTwice, ..Architecture::multiscale() }
        );
    }
}
