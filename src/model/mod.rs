//! KPCN and DPCN networks in candle, their architectures, and model files.
//!
//! A branch is `layers` convolutions (`conv_size`², `channels` wide, ReLU after all but the
//! last, no padding: each layer trims `(conv_size − 1) / 2` pixels per side, so a tile is
//! fed with a halo of [`Architecture::feature_radius`]). KPCN's last layer predicts
//! `kernel_size²` weights per pixel, DPCN's 3 colours.

use crate::features::{self, Features, FrameStats, INPUT_CHANNELS, INPUT_LAYOUT};
use crate::io::layout::KpcnInputs;
use candle_core::{DType, Device, Tensor};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

pub mod multiscale;
pub mod pyramid;

/// Model file format version written in the metadata.
pub const FORMAT_VERSION: &str = "1";

/// The 3-level multi-scale KPCN that was the default until the ladder's `balanced` took its
/// place (`compact`; see `models/README.md`): a 44-px reach, so the least memory per band.
static COMPACT_MODEL: &[u8] = include_bytes!("../../models/compact.safetensors");
/// The flat KPCN shipped beside it (`small-flat`): slower, better on some renders.
static SMALL_FLAT_MODEL: &[u8] = include_bytes!("../../models/small.safetensors");
/// The default's architecture and recipe trained on spatial variance estimates
/// (`spatial`): for files without variances, such as Blender's own output.
static SPATIAL_MODEL: &[u8] = include_bytes!("../../models/spatial.safetensors");

/// The quality ladder's rungs (`--quality`, [`Architecture::ladder`]); `balanced` is also
/// the default.
static FAST_MODEL: &[u8] = include_bytes!("../../models/fast.safetensors");
static BALANCED_MODEL: &[u8] = include_bytes!("../../models/balanced.safetensors");
static HIGH_MODEL: &[u8] = include_bytes!("../../models/high.safetensors");

/// Names of the trained models shipped inside the library, for `Model::resolve`.
pub const SHIPPED: [&str; 7] = ["default", "compact", "spatial", "small-flat", "fast", "balanced", "high"];

/// Kernel prediction or direct prediction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Per-pixel softmax kernels applied to the noisy input (Bako et al. 2017).
    Kpcn,
    /// The colour predicted directly.
    Dpcn,
}

/// How a branch is built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Design {
    /// Every layer at full resolution (the paper's network).
    #[default]
    Flat,
    /// A U-Net that predicts small kernels on an image pyramid and blends the scales
    /// ([`multiscale`]); KPCN only.
    MultiScale,
}

/// A network's shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Architecture {
    /// KPCN or DPCN.
    pub kind: Kind,
    /// Flat or multi-scale.
    pub design: Design,
    /// Convolution layers per branch (flat); pooling levels (multi-scale).
    pub layers: usize,
    /// Width of the hidden layers (flat); of the full-resolution ones, growing by this much
    /// per level (multi-scale).
    pub channels: usize,
    /// Convolution size (odd).
    pub conv_size: usize,
    /// Predicted kernel size (odd; KPCN only), at every scale for multi-scale.
    pub kernel_size: usize,
    /// How the multi-scale colour pyramid treats isolated fireflies.
    pub clamp: Clamp,
    /// Which variance estimates the network was trained on, and is fed.
    pub variances: Variances,
    /// What the specular branch's kernels filter.
    pub specular: Specular,
    /// How the radiance inputs are scaled before the network sees them.
    pub exposure: Exposure,
}

/// How a model's radiance inputs are scaled (`kpcn:exposure`). Convolutions with biases
/// and ReLUs are not scale-invariant: a frame rendered 4× brighter is denoised worse
/// (BENCHMARKS.md, "Autoexposure and the shipped `balanced`"). The output is scaled back,
/// so the choice never changes the output's units.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Exposure {
    /// As rendered.
    #[default]
    Raw,
    /// Scaled so that the frame's key (the geometric mean of its 16×16 block luminances,
    /// [`crate::features::ExposureMeter`]) is 0.18, as OIDN's autoexposure does.
    Auto,
}

/// What a model's inputs are made from, beyond the file: what training must prepare alike.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Preprocessing {
    /// The variance features.
    pub variances: Variances,
    /// The radiance scale.
    pub exposure: Exposure,
}

impl Preprocessing {
    /// The features of `inputs` as such a model sees them (the one place inference and
    /// training make them): [`Preprocessing::inputs`], then the features, made in place
    /// of owned inputs.
    pub fn features(self, inputs: std::borrow::Cow<'_, KpcnInputs>, whole: Option<FrameStats>) -> Features {
        let inputs = self.inputs(inputs);
        let whole = whole.unwrap_or_else(|| self.frame_stats(&inputs));
        Features::for_frame(inputs, whole)
    }

    /// The inputs such a model sees: a model trained on spatial variance estimates gets
    /// them, whatever the file holds. Owned inputs are changed in place; borrowed ones are
    /// copied only then.
    pub fn inputs(self, inputs: std::borrow::Cow<'_, KpcnInputs>) -> std::borrow::Cow<'_, KpcnInputs> {
        if self.variances == Variances::Spatial {
            let mut i = inputs.into_owned();
            i.estimate_variances_spatially();
            std::borrow::Cow::Owned(i)
        } else {
            inputs
        }
    }

    /// The features of inputs already made by [`Preprocessing::inputs`]; `whole` holds the
    /// whole frame's statistics when they are a band of it, else they are measured here.
    pub fn features_of(self, inputs: &KpcnInputs, whole: Option<FrameStats>) -> Features {
        let whole = whole.unwrap_or_else(|| self.frame_stats(inputs));
        Features::for_frame(std::borrow::Cow::Borrowed(inputs), whole)
    }

    /// The statistics of a whole frame that its features depend on.
    fn frame_stats(self, inputs: &KpcnInputs) -> FrameStats {
        FrameStats {
            max_depth: features::max_depth(&inputs.depth),
            exposure: if self.exposure == Exposure::Auto { features::auto_exposure(inputs) } else { 1.0 },
        }
    }
}

/// The values the specular branch's kernels filter (`kpcn:specular`). The network always
/// sees log features, `s̃ = ln(1 + s)`, and its phase-1 loss is always taken on `s̃`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Specular {
    /// `s̃` itself, as in Bako et al. 2017; the output is `exp(ŝ) − 1`. Averaging in log
    /// space is biased dark (Jensen): a 5×5 box filter of `s̃` keeps 35–48 % of a sparse
    /// specular frame's energy (firefly-0000, BENCHMARKS.md), which training can only
    /// partly undo.
    #[default]
    Log,
    /// Linear radiance `s = exp(s̃) − 1`: convex kernels of an unbiased estimate keep its
    /// energy, and the output is `ŝ` itself.
    Linear,
}

impl Specular {
    /// The value a kernel filters, from a pixel's `s̃`.
    pub fn kernel_input(self, s_tilde: f32) -> f32 {
        match self {
            Specular::Log => s_tilde,
            Specular::Linear => s_tilde.exp_m1(),
        }
    }

    /// Specular radiance from a filtered value `ŝ`: finite and at least 0.
    pub fn radiance(self, s_hat: f32) -> f32 {
        use crate::features::sanitize;
        match self {
            // ln(f32::MAX) ≈ 88.7: beyond 80 `exp` is no longer a radiance.
            Specular::Log => sanitize(sanitize(s_hat).min(80.0).exp_m1()),
            Specular::Linear => sanitize(s_hat).max(0.0),
        }
    }

    /// [`Specular::radiance`] of a batch, differentiable.
    pub fn radiance_tensor(self, s_hat: &Tensor) -> Result<Tensor, ModelError> {
        Ok(match self {
            Specular::Log => (s_hat.clamp(-80f32, 80f32)?.exp()? - 1.0)?,
            Specular::Linear => s_hat.relu()?,
        })
    }

    /// A filtered batch in the log domain of the phase-1 loss (`ln(1 + ŝ)` for linear).
    pub fn log_tensor(self, s_hat: &Tensor) -> Result<Tensor, ModelError> {
        Ok(match self {
            Specular::Log => s_hat.clone(),
            Specular::Linear => (s_hat.relu()? + 1.0)?.log()?,
        })
    }
}

/// The rungs of the model ladder, like OIDN's quality modes: the same network at three
/// widths ([`Architecture::ladder`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Quality {
    /// About 0.6× the balanced rung's time.
    Fast,
    /// The default trade-off.
    Balanced,
    /// The widest, about 1.6× the balanced rung's time.
    High,
}

impl Quality {
    /// Every rung, fastest first.
    pub const ALL: [Quality; 3] = [Quality::Fast, Quality::Balanced, Quality::High];

    /// The rung's name (`fast`, `balanced`, `high`): also its shipped model's.
    pub fn name(self) -> &'static str {
        match self {
            Quality::Fast => "fast",
            Quality::Balanced => "balanced",
            Quality::High => "high",
        }
    }
}

/// The variance features a model was trained on (`kpcn:variances`): inference feeds it
/// the same kind, whatever the file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Variances {
    /// The file's own (per-pixel sample variances or half buffers); estimated spatially
    /// only where the file has none.
    #[default]
    File,
    /// The 3×3 spatial estimate for every input, always: what a file without variances
    /// (Blender's own output) gives, so the network sees at inference what it learned on.
    Spatial,
}

/// The firefly clamp of a multi-scale network's colour pyramid (`kpcn:clamp`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Clamp {
    /// Clamped to the 8 neighbours' maximum; the excess is lost (biased dark on sparse,
    /// bright light: BENCHMARKS.md).
    #[default]
    Hard,
    /// The same clamp with the excess shared over the 3×3 neighbourhood: no energy lost.
    Spread,
}

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
    /// Unknown preset name.
    #[error(
        "unknown model `{0}` — use a shipped model (`default`, `spatial`, `small-flat`, `fast`, `balanced`, `high`), a .safetensors file, or an untrained preset (`paper`, `small`, `multiscale`, for testing)"
    )]
    UnknownPreset(String),
    /// A tensor computation failed.
    #[error("network evaluation failed: {0}")]
    Candle(#[from] candle_core::Error),
}

impl Architecture {
    /// What the model's inputs are made from.
    pub fn preprocessing(&self) -> Preprocessing {
        Preprocessing { variances: self.variances, exposure: self.exposure }
    }

    /// The paper's configuration: 9 layers, 100 channels, 5×5 convolutions, 21×21 kernels.
    pub fn paper(kind: Kind) -> Self {
        Architecture {
            kind,
            design: Design::Flat,
            layers: 9,
            channels: 100,
            conv_size: 5,
            kernel_size: 21,
            clamp: Default::default(),
            variances: Default::default(),
            specular: Default::default(),
            exposure: Default::default(),
        }
    }

    /// A small flat network: 6 layers, 32 channels, 3×3 convolutions, 11×11 kernels.
    pub fn small(kind: Kind) -> Self {
        Architecture {
            kind,
            design: Design::Flat,
            layers: 6,
            channels: 32,
            conv_size: 3,
            kernel_size: 11,
            clamp: Default::default(),
            variances: Default::default(),
            specular: Default::default(),
            exposure: Default::default(),
        }
    }

    /// The multi-scale KPCN: 3 pooling levels, 16/32/48/64 channels, 3×3 convolutions,
    /// 5×5 kernels at full, half and quarter resolution, the spreading firefly clamp.
    pub fn multiscale() -> Self {
        Architecture {
            kind: Kind::Kpcn,
            design: Design::MultiScale,
            layers: 3,
            channels: 16,
            conv_size: 3,
            kernel_size: 5,
            // The shipped default's: energy-preserving (BENCHMARKS.md).
            clamp: Clamp::Spread,
            variances: Variances::File,
            specular: Specular::Log,
            exposure: Default::default(),
        }
    }

    /// A rung of the quality ladder (`--quality`): a multi-scale KPCN with 5 pooling
    /// levels, so 5×5 kernels reach ¹⁄₁₆ resolution and the receptive radius is 188 px
    /// (OIDN's U-Net: ≈174), with full-resolution widths 8 (`fast`), 16 (`balanced`) or
    /// 24 (`high`), growing by that much per level; the spreading firefly clamp and log
    /// specular, as the default.
    pub fn ladder(quality: Quality) -> Self {
        Architecture {
            layers: 5,
            channels: match quality {
                Quality::Fast => 8,
                Quality::Balanced => 16,
                Quality::High => 24,
            },
            ..Self::multiscale()
        }
    }

    /// Outputs of the last layer.
    pub fn outputs(&self) -> usize {
        match self.kind {
            Kind::Kpcn => self.kernel_size * self.kernel_size,
            Kind::Dpcn => 3,
        }
    }

    /// Pixels of context each side that the network needs: a tile is evaluated on itself
    /// plus this halo. Multi-scale: a bound on the receptive field, a multiple of
    /// [`Architecture::alignment`].
    pub fn feature_radius(&self) -> usize {
        match self.design {
            Design::Flat => self.layers * (self.conv_size - 1) / 2,
            Design::MultiScale => multiscale::receptive_radius(self),
        }
    }

    /// Pixels of noisy colour each side that the predicted kernel reads beyond the
    /// output (0 for DPCN). Multi-scale reads the noisy colour of the whole halo region.
    pub fn kernel_radius(&self) -> usize {
        match (self.design, self.kind) {
            (Design::MultiScale, _) => self.feature_radius(),
            (Design::Flat, Kind::Kpcn) => (self.kernel_size - 1) / 2,
            (Design::Flat, Kind::Dpcn) => 0,
        }
    }

    /// Context each side that a multi-scale region gets beyond the frame's edges (mirrored
    /// features). Networks that reach at most 48 px mirror their whole radius. Wider ones
    /// (the ladder's, 192 px) mirror only the real context a training patch gets around
    /// it ([`Architecture::train_margins`]), rounded up to the pooling grid: beyond that,
    /// zero padding is what the network learned, and a wider mirror costs time (at 720p a
    /// 192-px mirror would double the pixels evaluated) without telling it anything new.
    pub fn border_radius(&self) -> usize {
        let r = self.feature_radius();
        match self.design {
            Design::MultiScale if r > 48 => r.min(self.train_margins().0.next_multiple_of(self.alignment())),
            _ => r,
        }
    }

    /// Tiles and bands must start at multiples of this (the pyramid's pooling grid is the
    /// frame's, so a tile sees the same pyramid as the whole frame).
    pub fn alignment(&self) -> usize {
        match self.design {
            Design::Flat => 1,
            Design::MultiScale => 1 << self.layers,
        }
    }

    /// Context (features, noisy colour) around a training patch. Flat: exactly what the
    /// output needs. Multi-scale: a margin of real context inside the evaluated region,
    /// whose outer pixels see zero padding; the loss covers only the patch.
    pub fn train_margins(&self) -> (usize, usize) {
        match self.design {
            Design::Flat => (self.feature_radius(), self.kernel_radius()),
            Design::MultiScale => (16, 16),
        }
    }

    /// Estimated peak bytes to evaluate one branch on a `tw`×`th` tile whose region (the
    /// tile with its context) is `rw`×`rh`: the input region, the convolution's unfolded
    /// input (im2col), two activations, the logits and the noisy colour region
    /// (multi-scale: [`pyramid::bytes_per_pixel`] of the region).
    pub fn region_bytes(&self, rw: usize, rh: usize, tw: usize, th: usize) -> usize {
        let p = rw * rh;
        if self.design == Design::MultiScale {
            return p * pyramid::bytes_per_pixel(self);
        }
        let widest = self.channels.max(INPUT_CHANNELS);
        let im2col = widest * self.conv_size * self.conv_size * p;
        let logits = self.outputs() * tw * th;
        let noisy = 3 * (tw + 2 * self.kernel_radius()) * (th + 2 * self.kernel_radius());
        4 * (INPUT_CHANNELS * p + im2col + 2 * widest * p + 2 * logits + noisy)
    }

    /// (out, in, size) of every convolution, in the model file's order.
    pub fn layer_shapes(&self) -> Vec<(usize, usize, usize)> {
        match self.design {
            Design::Flat => (0..self.layers)
                .map(|l| {
                    let cin = if l == 0 { INPUT_CHANNELS } else { self.channels };
                    let cout = if l + 1 == self.layers { self.outputs() } else { self.channels };
                    (cout, cin, self.conv_size)
                })
                .collect(),
            Design::MultiScale => multiscale::layer_shapes(self),
        }
    }

    /// Multiply-adds ×2 per pixel, both branches, network and kernel application.
    pub fn flops_per_pixel(&self) -> f64 {
        match self.design {
            Design::Flat => {
                let net: f64 = self.layer_shapes().iter().map(|&(o, i, k)| 2.0 * (o * i * k * k) as f64).sum();
                let kernel = if self.kind == Kind::Kpcn { 2.0 * 3.0 * self.outputs() as f64 } else { 0.0 };
                2.0 * (net + kernel)
            }
            Design::MultiScale => 2.0 * multiscale::flops_per_pixel(self),
        }
    }

    /// Refuses impossible architectures (`origin` names the source in the error).
    pub fn validate(&self, origin: &str) -> Result<(), ModelError> {
        let bad = |what: String| Err(ModelError::Format { origin: origin.into(), what });
        if self.layers == 0
            || self.channels == 0
            || self.conv_size.is_multiple_of(2)
            || self.kernel_size.is_multiple_of(2)
        {
            return bad(format!("impossible architecture {self:?}"));
        }
        if self.design == Design::MultiScale && (self.kind != Kind::Kpcn || self.layers > 6) {
            return bad(format!("a multi-scale network is KPCN with 1–6 levels, not {self:?}"));
        }
        if self.specular == Specular::Linear && self.design != Design::MultiScale {
            return bad(format!("linear specular kernels are for multi-scale networks, not {self:?}"));
        }
        Ok(())
    }

    fn metadata(&self) -> HashMap<String, String> {
        let kind = match self.kind {
            Kind::Kpcn => "kpcn",
            Kind::Dpcn => "dpcn",
        };
        [
            ("kpcn:format", FORMAT_VERSION.to_string()),
            ("kpcn:input_layout", INPUT_LAYOUT.to_string()),
            ("kpcn:kind", kind.to_string()),
            ("kpcn:design", (if self.design == Design::MultiScale { "multiscale" } else { "flat" }).to_string()),
            ("kpcn:layers", self.layers.to_string()),
            ("kpcn:channels", self.channels.to_string()),
            ("kpcn:conv_size", self.conv_size.to_string()),
            ("kpcn:kernel_size", self.kernel_size.to_string()),
            ("kpcn:clamp", (if self.clamp == Clamp::Spread { "spread" } else { "hard" }).to_string()),
            ("kpcn:variances", (if self.variances == Variances::Spatial { "spatial" } else { "file" }).to_string()),
            ("kpcn:specular", (if self.specular == Specular::Linear { "linear" } else { "log" }).to_string()),
            ("kpcn:exposure", (if self.exposure == Exposure::Auto { "auto" } else { "raw" }).to_string()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }

    fn from_metadata(m: &HashMap<String, String>, origin: &str) -> Result<Self, ModelError> {
        let err = |what: String| ModelError::Format { origin: origin.into(), what };
        let get = |k: &str| m.get(k).ok_or_else(|| err(format!("metadata lacks `{k}` (not a kpcn model file?)")));
        let version = get("kpcn:format")?;
        if version != FORMAT_VERSION {
            return Err(err(format!("model format {version}, this kpcn reads format {FORMAT_VERSION}")));
        }
        let layout = get("kpcn:input_layout")?;
        if layout != INPUT_LAYOUT {
            return Err(err(format!("input layout `{layout}`, this kpcn feeds `{INPUT_LAYOUT}`")));
        }
        let num = |k: &str| -> Result<usize, ModelError> {
            get(k)?.parse().map_err(|_| err(format!("metadata `{k}` is not a number")))
        };
        let kind = match get("kpcn:kind")?.as_str() {
            "kpcn" => Kind::Kpcn,
            "dpcn" => Kind::Dpcn,
            other => return Err(err(format!("unknown network kind `{other}`"))),
        };
        // Files from before multi-scale networks have no design: flat.
        let design = match m.get("kpcn:design").map(String::as_str) {
            None | Some("flat") => Design::Flat,
            Some("multiscale") => Design::MultiScale,
            Some(other) => return Err(err(format!("unknown network design `{other}`"))),
        };
        let a = Architecture {
            kind,
            design,
            layers: num("kpcn:layers")?,
            channels: num("kpcn:channels")?,
            conv_size: num("kpcn:conv_size")?,
            kernel_size: num("kpcn:kernel_size")?,
            // Files from before the choice clamp hard.
            clamp: match m.get("kpcn:clamp").map(String::as_str) {
                None | Some("hard") => Clamp::Hard,
                Some("spread") => Clamp::Spread,
                Some(other) => return Err(err(format!("unknown firefly clamp `{other}`"))),
            },
            // Files from before the choice were trained on the files' variances.
            variances: match m.get("kpcn:variances").map(String::as_str) {
                None | Some("file") => Variances::File,
                Some("spatial") => Variances::Spatial,
                Some(other) => return Err(err(format!("unknown variance features `{other}`"))),
            },
            // Files from before the choice filter log specular.
            specular: match m.get("kpcn:specular").map(String::as_str) {
                None | Some("log") => Specular::Log,
                Some("linear") => Specular::Linear,
                Some(other) => return Err(err(format!("unknown specular domain `{other}`"))),
            },
            // Files from before the choice see raw radiance.
            exposure: match m.get("kpcn:exposure").map(String::as_str) {
                None | Some("raw") => Exposure::Raw,
                Some("auto") => Exposure::Auto,
                Some(other) => return Err(err(format!("unknown exposure `{other}`"))),
            },
        };
        a.validate(origin)?;
        Ok(a)
    }
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

    /// Whether the description marks it untrained.
    pub fn is_untrained(&self) -> bool {
        self.description.starts_with("untrained")
    }

    /// The default model: the quality ladder's `balanced` rung.
    pub fn embedded_default() -> Result<Model, ModelError> {
        Self::shipped_rung(Quality::Balanced)
    }

    /// A shipped model (`default` = `balanced`, `compact`, `spatial`, `small-flat`, the
    /// ladder's `fast`, `balanced`, `high`), a preset name (`paper`, `small`, `multiscale`: untrained, Xavier seed 0; see
    /// [`Model::is_untrained`]) or a file path.
    pub fn resolve(name: &str) -> Result<Model, ModelError> {
        match name {
            "default" => Self::embedded_default(),
            "compact" => Self::from_bytes(COMPACT_MODEL, "shipped model compact"),
            "small-flat" => Self::from_bytes(SMALL_FLAT_MODEL, "shipped model small-flat"),
            "fast" => Self::shipped_rung(Quality::Fast),
            "balanced" => Self::shipped_rung(Quality::Balanced),
            "high" => Self::shipped_rung(Quality::High),
            "spatial" => Self::from_bytes(SPATIAL_MODEL, "shipped model spatial"),
            "paper" => Self::xavier(Architecture::paper(Kind::Kpcn), 0),
            "small" => Self::xavier(Architecture::small(Kind::Kpcn), 0),
            "multiscale" => Self::xavier(Architecture::multiscale(), 0),
            "paper-dpcn" => Self::xavier(Architecture::paper(Kind::Dpcn), 0),
            "small-dpcn" => Self::xavier(Architecture::small(Kind::Dpcn), 0),
            p if p.ends_with(".safetensors") => Self::load(Path::new(p)),
            other => Err(ModelError::UnknownPreset(other.into())),
        }
    }

    /// The shipped model of a rung of the quality ladder.
    pub fn shipped_rung(q: Quality) -> Result<Model, ModelError> {
        let bytes = match q {
            Quality::Fast => FAST_MODEL,
            Quality::Balanced => BALANCED_MODEL,
            Quality::High => HIGH_MODEL,
        };
        Self::from_bytes(bytes, &format!("shipped model {}", q.name()))
    }

    /// Reads a model file.
    pub fn load(path: &Path) -> Result<Model, ModelError> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io { path: path.into(), source })?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Parses model-file bytes (`origin` names them in errors).
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Model, ModelError> {
        let err = |what: String| ModelError::Format { origin: origin.into(), what };
        let (_, meta) =
            safetensors::SafeTensors::read_metadata(bytes).map_err(|e| err(format!("not a safetensors file ({e})")))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let arch = Architecture::from_metadata(&meta, origin)?;
        let tensors = candle_core::safetensors::load_buffer(bytes, &Device::Cpu)?;
        let branch = |name: &str| -> Result<BranchWeights, ModelError> {
            let layers = arch
                .layer_shapes()
                .into_iter()
                .enumerate()
                .map(|(l, (o, i, k))| {
                    let get = |t: &str, shape: &[usize]| -> Result<Tensor, ModelError> {
                        let key = format!("{name}.{l}.{t}");
                        let v = tensors.get(&key).ok_or_else(|| err(format!("tensor `{key}` is missing")))?;
                        if v.dims() != shape {
                            return Err(err(format!("tensor `{key}` has shape {:?}, expected {shape:?}", v.dims())));
                        }
                        Ok(v.to_dtype(DType::F32)?)
                    };
                    Ok((get("weight", &[o, i, k, k])?, get("bias", &[o])?))
                })
                .collect::<Result<_, ModelError>>()?;
            Ok(BranchWeights { layers })
        };
        Ok(Model {
            arch,
            diffuse: branch("diffuse")?,
            specular: branch("specular")?,
            description: meta.get("kpcn:description").cloned().unwrap_or_default(),
        })
    }

    /// Serialises the model with its metadata.
    pub fn to_bytes(&self) -> Result<Vec<u8>, ModelError> {
        self.to_bytes_with(Vec::new(), HashMap::new())
    }

    /// Serialises the model plus extra tensors and metadata (training checkpoints); the
    /// result still loads as a model.
    pub fn to_bytes_with(
        &self,
        extra: Vec<(String, Tensor)>,
        extra_meta: HashMap<String, String>,
    ) -> Result<Vec<u8>, ModelError> {
        let mut meta = self.arch.metadata();
        meta.insert("kpcn:description".into(), self.description.clone());
        meta.extend(extra_meta);
        let mut named = extra;
        for (name, b) in [("diffuse", &self.diffuse), ("specular", &self.specular)] {
            for (l, (w, bias)) in b.layers.iter().enumerate() {
                named.push((format!("{name}.{l}.weight"), w.clone()));
                named.push((format!("{name}.{l}.bias"), bias.clone()));
            }
        }
        let views: Vec<(String, candle_core::Tensor)> = named;
        safetensors::serialize(views.iter().map(|(n, t)| (n.as_str(), t)), Some(meta))
            .map_err(|e| ModelError::Format { origin: "serialise".into(), what: e.to_string() })
    }

    /// Writes the model file (through a temporary file, renamed into place).
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        write_atomically(path, &self.to_bytes()?)
    }

    /// Writes the model file with every weight rounded to half precision (f16): half the
    /// bytes, for shipping. Loading widens the weights back to f32.
    pub fn save_half(&self, path: &Path) -> Result<(), ModelError> {
        let half = |b: &BranchWeights| -> Result<BranchWeights, ModelError> {
            let layers = b
                .layers
                .iter()
                .map(|(w, bias)| Ok((w.to_dtype(DType::F16)?, bias.to_dtype(DType::F16)?)))
                .collect::<Result<_, ModelError>>()?;
            Ok(BranchWeights { layers })
        };
        let m = Model { diffuse: half(&self.diffuse)?, specular: half(&self.specular)?, ..self.clone() };
        write_atomically(path, &m.to_bytes()?)
    }
}

/// Writes `bytes` to `path` through a temporary file renamed into place.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), ModelError> {
    crate::io::atomic::write_atomically(path, bytes).map_err(|source| ModelError::Io { path: path.into(), source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budgets_pick_smaller_tiles_for_bigger_networks() {
        use crate::tile::{Axis, Reach, size_for_regions};
        let budget = 256 << 20;
        let side = |a: Architecture, budget: usize, w: usize, h: usize| {
            let r = a.feature_radius().max(a.kernel_radius());
            let reach = Reach { radius: r, border: r, align: 1 };
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
            variances: Default::default(),
            specular: Default::default(),
            exposure: Default::default(),
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
                variances: Default::default(),
                specular: Default::default(),
                exposure: Default::default(),
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
    fn every_rung_of_the_ladder_is_shipped_with_its_architecture() {
        for q in Quality::ALL {
            let m = Model::resolve(q.name()).unwrap();
            // The presets see raw radiance; `balanced` was fine-tuned auto-exposed.
            let exposure = if q == Quality::Balanced { Exposure::Auto } else { Exposure::Raw };
            assert_eq!(m.arch, Architecture { exposure, ..Architecture::ladder(q) }, "{}", q.name());
            assert!(!m.is_untrained() && m.arch.feature_radius() >= 170, "{}", q.name());
        }
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
        assert_eq!(c.arch, Architecture { exposure: Exposure::Auto, ..Architecture::multiscale() });
    }
}
