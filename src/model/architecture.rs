//! A network's shape and what its inputs are made from: the architecture types that a
//! model file's metadata records ([`super::format`]).

use super::{ModelError, multiscale, pyramid, stream};
use crate::features::{self, Features, FrameStats, INPUT_CHANNELS};
use crate::io::layout::KpcnInputs;
use candle_core::Tensor;

/// Kernel prediction or direct prediction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
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

/// How a multi-scale network puts each scale's result together with the coarser one's
/// (`kpcn:blend`); `α` is the per-pixel blend weight the network predicts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
pub enum ScaleBlend {
    /// `(1 − α)·fine + α·up(coarse)`: where `α` is near 1 the fine scale's detail goes
    /// with its noise.
    #[default]
    Lerp,
    /// `fine + α·up(coarse − down(fine))` (Vogels et al. 2018): the coarse result replaces
    /// only the fine one's low frequencies, so detail finer than the coarse scale stays
    /// whatever `α` is. `down` is the 2×2 average, `up` the bilinear upsampling.
    Detail,
}

impl ScaleBlend {
    /// The name in a model file and on the command line.
    pub const fn name(self) -> &'static str {
        match self {
            ScaleBlend::Lerp => "lerp",
            ScaleBlend::Detail => "detail",
        }
    }
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
    /// How a multi-scale network blends each scale with the coarser one (flat: `Lerp`,
    /// unused).
    pub blend: ScaleBlend,
    /// Which variance estimates the network was trained on, and is fed.
    pub variances: Variances,
    /// What the specular branch's kernels filter.
    pub specular: Specular,
    /// How the radiance inputs are scaled before the network sees them.
    pub exposure: Exposure,
    /// The most the specular branch moves a pixel from its noisy value, in standard errors
    /// of that pixel's mean (`kpcn:specular_bound`); `None`: as far as its kernels take it.
    pub specular_bound: Option<u8>,
    /// The most the diffuse branch brightens a pixel: to the mean noisy value of its
    /// similar neighbours plus this many standard errors of a pixel's mean there
    /// (`kpcn:diffuse_bound`); `None`: as far as its kernels take it.
    pub diffuse_bound: Option<u8>,
    /// Where the light the diffuse ceiling takes goes (`kpcn:diffuse_spread`): shared out
    /// over the (2r + 1)² window around the pixel it came from, in proportion to the noisy
    /// light there and at most that light again per pixel, so that the frame keeps it where
    /// it is lit; `None`: it is lost. Only with a [`Architecture::diffuse_bound`].
    pub diffuse_spread: Option<u8>,
    /// The detail the diffuse branch smoothed away, restored (`kpcn:diffuse_detail`): over
    /// each (2r + 1)² window, the part of the noisy residual (noisy d̃ − d̂, each channel
    /// held within ±d̂) that follows the shading normal, fitted by least squares, is added
    /// back; noise, which does not follow the normal, stays out. `None`: d̂ as it is.
    pub diffuse_detail: Option<u8>,
    /// A per-pixel gain on each branch's result (multi-scale only, `kpcn:gain`): the
    /// full-resolution head predicts one more logit `g`, and the blended result is
    /// multiplied by `2σ(g)`, between 0 and 2. Kernels only average the noisy colour
    /// around a pixel, so shading finer than what they keep (a bump, the dark side of an
    /// edge the average straddles) is out of their reach; a gain is not, and keeps a
    /// black pixel black. A zero row of weights is a gain of exactly 1
    /// ([`super::Model::with_gain`]).
    pub gain: bool,
    /// How the diffuse branch's network sees `d̃` (`kpcn:diffuse_input`); its kernels
    /// always filter `d̃` itself.
    pub diffuse_input: DiffuseInput,
}

/// How the diffuse branch's network sees the demodulated diffuse `d̃`, its gradients and
/// its variance (`kpcn:diffuse_input`; the transform is [`features::log_colour_input`]).
/// The kernels it predicts filter `d̃` itself either way, so the output keeps its energy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
pub enum DiffuseInput {
    /// `d̃` as it is: linear radiance, whose 4-spp hits are orders of magnitude above
    /// their neighbours.
    #[default]
    Linear,
    /// `ln(1 + d̃)`, its gradients and its variance, as the specular branch sees `s̃`.
    Log,
}

impl DiffuseInput {
    /// The name in a model file and on the command line.
    pub const fn name(self) -> &'static str {
        match self {
            DiffuseInput::Linear => "linear",
            DiffuseInput::Log => "log",
        }
    }
}

/// The widest [`Architecture::diffuse_detail`]: the rows a band's detail reads beyond it
/// (2r) fit the thinnest band a frame is streamed in, as [`MAX_DIFFUSE_SPREAD`]'s do.
pub const MAX_DIFFUSE_DETAIL: u8 = 15;

/// The widest [`Architecture::diffuse_spread`]: the rows a band's spread reads beyond it
/// (2r + 1) fit the thinnest band a frame is streamed in (the pooling grid of a
/// multi-scale network, 32 rows at five levels), so that it needs the rows of its two
/// neighbours only.
pub const MAX_DIFFUSE_SPREAD: u8 = 15;

/// How a model's radiance inputs are scaled (`kpcn:exposure`). Convolutions with biases
/// and ReLUs are not scale-invariant: a frame rendered 4× brighter is denoised worse
/// (BENCHMARKS.md, "Autoexposure and the shipped `balanced`"). The output is scaled back,
/// so the choice never changes the output's units.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
pub enum Exposure {
    /// As rendered.
    #[default]
    Raw,
    /// Scaled so that the frame's key (the geometric mean of its 16×16 block luminances)
    /// is 0.18, as OIDN's autoexposure does.
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
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
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
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
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
    pub const fn name(self) -> &'static str {
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
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
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
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
pub enum Clamp {
    /// Clamped to the 8 neighbours' maximum; the excess is lost (biased dark on sparse,
    /// bright light: BENCHMARKS.md).
    #[default]
    Hard,
    /// The same clamp with the excess shared over the 3×3 neighbourhood: no energy lost.
    Spread,
    /// The same clamp with the excess averaged into the coarsest scale's colour: no
    /// energy lost, and none concentrated where the firefly was.
    Coarse,
    /// The full-resolution colour clamped, the coarser scales pooled from the unclamped
    /// colour: no energy lost at any scale the blend draws from.
    Fine,
    /// As `Fine`, clamped to the second-brightest neighbour: pairs of fireflies go too,
    /// while a line one pixel wide keeps all but its ends.
    FinePairs,
    /// `FinePairs` twice: a cluster of three (a diagonal, an L) goes too, since its ends
    /// go first; a line one pixel wide loses two pixels at each end.
    FinePairsTwice,
    /// `FinePairsTwice`, and rare bright samples taken down: a value far above its 3×3
    /// median, by more than 3 times its neighbours' own standard errors, keeps only what
    /// it shows beyond 3 of its own (from the variance features). Clusters of one-sample
    /// hits of a small bright light (a defocused highlight's rim at 64 spp) go whatever
    /// their size; a highlight every sample saw stays but for those errors. A region
    /// without variances clamps as `FinePairsTwice`.
    Significant,
}

/// Standard errors of a pixel's mean within which [`Clamp::Significant`] takes its
/// excess over its neighbourhood for noise.
pub const SIGNIFICANT_ERRORS: f32 = 3.0;

impl Clamp {
    /// The name written in model files (`kpcn:clamp`).
    pub fn name(self) -> &'static str {
        match self {
            Clamp::Hard => "hard",
            Clamp::Spread => "spread",
            Clamp::Coarse => "coarse",
            Clamp::Fine => "fine",
            Clamp::FinePairs => "fine-pairs",
            Clamp::FinePairsTwice => "fine-pairs-twice",
            Clamp::Significant => "significant",
        }
    }

    /// Whether the clamp reads each pixel's variance beside the noisy colour (a fourth
    /// plane of the colour the network is given).
    pub fn reads_variance(self) -> bool {
        self == Clamp::Significant
    }
}

impl Architecture {
    /// Branch `b`'s network input (27 CHW planes, [`Features::branch_input`]) as this
    /// model sees it, in place: the one place training and inference change it
    /// ([`DiffuseInput`]).
    pub fn prepare_input(&self, b: features::Branch, input: &mut [f32]) {
        if b == features::Branch::Diffuse && self.diffuse_input == DiffuseInput::Log {
            features::log_colour_input(input);
        }
    }

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
            blend: ScaleBlend::Lerp,
            variances: Default::default(),
            specular: Default::default(),
            exposure: Default::default(),
            specular_bound: None,
            diffuse_bound: None,
            diffuse_spread: None,
            diffuse_detail: None,
            gain: false,
            diffuse_input: DiffuseInput::Linear,
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
            blend: ScaleBlend::Lerp,
            variances: Default::default(),
            specular: Default::default(),
            exposure: Default::default(),
            specular_bound: None,
            diffuse_bound: None,
            diffuse_spread: None,
            diffuse_detail: None,
            gain: false,
            diffuse_input: DiffuseInput::Linear,
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
            blend: ScaleBlend::Lerp,
            variances: Variances::File,
            specular: Specular::Log,
            exposure: Default::default(),
            specular_bound: None,
            diffuse_bound: None,
            diffuse_spread: None,
            diffuse_detail: None,
            gain: false,
            diffuse_input: DiffuseInput::Linear,
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

    /// The network's **reach**: how far (pixels, each side) an output pixel depends on the
    /// input, the network's and the kernels' radius plus one pixel each for the
    /// backward-difference gradients and the 3×3 variance estimates
    /// ([`features::CONTEXT`]). Tiles are read with this much context; `kpcn model info`
    /// prints it.
    pub fn reach(&self) -> usize {
        self.feature_radius().max(self.kernel_radius()) + features::CONTEXT
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
    /// (multi-scale: the rows a [`super::stream::Stream`] holds, [`stream::held_rows`], of
    /// [`pyramid::bytes_per_pixel`] each).
    pub fn region_bytes(&self, rw: usize, rh: usize, tw: usize, th: usize) -> usize {
        let p = rw * rh;
        if self.design == Design::MultiScale {
            return rw * rh.min(stream::held_rows(self, rw)) * pyramid::bytes_per_pixel(self);
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
        if self.gain && self.design != Design::MultiScale {
            return bad(format!("a gain is for multi-scale networks, not {self:?}"));
        }
        if self.blend != ScaleBlend::Lerp && self.design != Design::MultiScale {
            return bad(format!("a flat network has no scales to blend, not {self:?}"));
        }
        if self.diffuse_spread.is_some() && self.diffuse_bound.is_none() {
            return bad("a diffuse spread needs a diffuse bound, whose excess it spreads".into());
        }
        if let Some(r) = self.diffuse_spread.filter(|&r| r > MAX_DIFFUSE_SPREAD) {
            return bad(format!("a diffuse spread of {r} px: at most {MAX_DIFFUSE_SPREAD}"));
        }
        if let Some(r) = self.diffuse_detail.filter(|&r| r > MAX_DIFFUSE_DETAIL) {
            return bad(format!("a diffuse detail window of radius {r} px: at most {MAX_DIFFUSE_DETAIL}"));
        }
        if self.specular == Specular::Linear && self.design != Design::MultiScale {
            return bad(format!("linear specular kernels are for multi-scale networks, not {self:?}"));
        }
        Ok(())
    }
}
