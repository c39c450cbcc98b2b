//! The multi-scale kernel-predicting network (ARCHITECTURE.md §Network): a small U-Net whose decoder
//! predicts 5×5 kernels at full, half and quarter resolution. Each scale's kernels are
//! applied to the noisy colour at that scale ([`colour_pyramid`]: isolated fireflies
//! clamped to their neighbours, then 2×2 box averages), and the scales are blended
//! coarse to fine, `r_s = (1 − α_s)·o_s + α_s·up(r_{s+1})`, with `α_s` a predicted
//! sigmoid and `up` bilinear ([`ScaleBlend::Lerp`]). The clamp, softmax kernels, box
//! averages, bilinear weights and that blend all pick or average values of the
//! neighbourhood, so the output stays inside the range of the noisy colour around the
//! pixel, like the paper's KPCN. [`ScaleBlend::Detail`] blends as Vogels et al. 2018,
//! `r_s = o_s + α_s·up(r_{s+1} − down(o_s))`, which keeps the fine scale's detail but not
//! that range.
//!
//! The network runs at full resolution for two 3×3 layers and a 1×1 head only; the rest
//! is at ½…⅛ resolution: 93 kFLOP per pixel for both branches, against 319 k for the
//! flat `small` preset and 10 MFLOP for the paper's network.
//!
//! Layers, in the model file's order (`L` = levels, `c_s = channels·(s + 1)`):
//! encoder `E_s` two 3×3 convolutions per scale `s = 0..=L` (after a 2×2 average pool for
//! `s > 0`); decoder `D_s` one 3×3 convolution on `nearest-up(F_{s+1}) ++ E_s` for
//! `s = L−1..1` (`F_L = E_L`, `F_s = D_s`); heads `H_s` one 1×1 convolution per kernel
//! scale `s = L−1..0` on `F_s` (`s > 0`) or `nearest-up(F_1) ++ E_0` (`s = 0`), giving `k²`
//! kernel logits plus one blend logit (not at the coarsest scale).
//!
//! The network is written once, in [`run`], over the operations of a [`Backend`]:
//! candle tensors for training ([`Graph`], differentiable) and plain planes for
//! inference (`super::pyramid`). Both call the same kernels.

use super::{Architecture, BranchWeights, Clamp, ModelError, SIGNIFICANT_ERRORS, ScaleBlend};
use crate::features::INPUT_CHANNELS;
use crate::kernel::conv::{ConvLayer, Winograd};
use crate::kernel::ops::Ops;
use crate::kernel::planes::Planes;
use candle_core::Tensor;

/// Width of scale `s`.
pub fn width(a: &Architecture, s: usize) -> usize {
    a.channels * (s + 1)
}

/// Outputs of head `s`: the kernel logits, plus a blend logit below the coarsest scale,
/// plus the gain logit at full resolution where the architecture has one
/// ([`gain_channel`]).
pub fn head_outputs(a: &Architecture, s: usize) -> usize {
    a.kernel_size * a.kernel_size + usize::from(s + 1 < a.layers) + usize::from(a.gain && s == 0)
}

/// The channel of the full-resolution head's logits that holds the gain logit
/// ([`Architecture::gain`]): after the kernel logits and the blend logit.
pub fn gain_channel(a: &Architecture) -> usize {
    a.kernel_size * a.kernel_size + usize::from(1 < a.layers)
}

/// Index of the first decoder layer and of the first head in [`layer_shapes`].
pub fn layer_offsets(a: &Architecture) -> (usize, usize) {
    let dec = 2 * (a.layers + 1);
    (dec, dec + a.layers - 1)
}

/// (out, in, size) of every convolution.
pub fn layer_shapes(a: &Architecture) -> Vec<(usize, usize, usize)> {
    let (l, k) = (a.layers, a.conv_size);
    let c = |s| width(a, s);
    let mut v = Vec::new();
    for s in 0..=l {
        v.push((c(s), if s == 0 { INPUT_CHANNELS } else { c(s - 1) }, k));
        v.push((c(s), c(s), k));
    }
    for s in (1..l).rev() {
        v.push((c(s), c(s + 1) + c(s), k));
    }
    for s in (0..l).rev() {
        v.push((head_outputs(a, s), if s == 0 { c(1) + c(0) } else { c(s) }, 1));
    }
    v
}

/// The scale (0 = full resolution, `s` = `2^−s`) layer `i` of [`layer_shapes`] runs at.
pub fn layer_scale(a: &Architecture, i: usize) -> usize {
    let (dec, head) = layer_offsets(a);
    if i < dec {
        i / 2
    } else if i < head {
        a.layers - 1 - (i - dec)
    } else {
        a.layers - 1 - (i - head)
    }
}

/// Which Winograd filter the 3×3 layers at scale `s` take
/// ([`crate::kernel::conv::ConvLayer::with_winograd`]), if any: one whose tiles of
/// columns start where every region's do at that scale (regions start on multiples of
/// [`Architecture::alignment`] at full resolution), so a tile's pixels fall in the tiles
/// of columns the whole frame's do. F(4, 3) at the two finest scales, where it saves the
/// most; F(2, 3) where columns start even; the coarsest scale goes directly. F(4, 3) mixes
/// columns beyond an output's 3×3 window into its rounding, which [`column_radius`]
/// covers: on the finest scales that costs column tiles a little context (16 px for the
/// ladder), on every scale it would cost them 88.
pub fn winograd_scale(a: &Architecture, s: usize) -> Option<Winograd> {
    let start = a.alignment() >> s;
    if s < 2 && start.is_multiple_of(Winograd::F4.tile()) {
        Some(Winograd::F4)
    } else if start.is_multiple_of(Winograd::F2.tile()) {
        Some(Winograd::F2)
    } else {
        None
    }
}

/// `layer` packed for inference at scale `s`: with the Winograd panels of
/// [`winograd_scale`]'s filter, if any.
pub fn inference_layer(a: &Architecture, s: usize, layer: ConvLayer) -> ConvLayer {
    match winograd_scale(a, s) {
        Some(filter) => layer.with_winograd(filter),
        None => layer,
    }
}

/// Multiply-adds ×2 per full-resolution pixel of one branch.
pub fn flops_per_pixel(a: &Architecture) -> f64 {
    let net: f64 = layer_shapes(a)
        .iter()
        .enumerate()
        .map(|(i, &(o, n, k))| 2.0 * (o * n * k * k) as f64 / 4f64.powi(layer_scale(a, i) as i32))
        .sum();
    let kernels: f64 =
        (0..a.layers).map(|s| 2.0 * 3.0 * (a.kernel_size * a.kernel_size) as f64 / 4f64.powi(s as i32)).sum();
    net + kernels
}

/// How far (in full-resolution pixels, each side) an output pixel's value reaches,
/// rounded up to the pooling grid: beyond it, padding at a region's edge cannot change
/// the result. Computed exactly by following, through every layer, the input span
/// `[2^s·i + lo, 2^s·i + hi]` that pixel `i` of a scale-`s` tensor depends on.
pub fn receptive_radius(a: &Architecture) -> usize {
    radius(a, |_, _| 0).next_multiple_of(a.alignment())
}

/// [`receptive_radius`] along rows, where inference's F(4, 3) layers
/// ([`winograd_scale`]) read [`Winograd::extra_columns`] more columns each side into an
/// output's rounding: the context regions need across columns for tiles to give the
/// whole frame's bits. (Across rows, and in value, the reach is [`receptive_radius`].)
pub fn column_radius(a: &Architecture) -> usize {
    radius(a, |s, cin| winograd_extra(a, s, cin)).next_multiple_of(a.alignment())
}

/// Pixels of scale `s` each side that a 3×3 layer of `cin` inputs reads into an
/// output's rounding beyond its window, by its Winograd filter.
fn winograd_extra(a: &Architecture, s: usize, cin: usize) -> i64 {
    winograd_scale(a, s).filter(|w| w.takes(cin, a.conv_size)).map_or(0, Winograd::extra_columns) as i64
}

/// The reach (not rounded) with every 3×3 layer at scale `s` of `cin` inputs reading
/// `extra(s, cin)` more pixels (of that scale) each side.
fn radius(a: &Architecture, extra: impl Fn(usize, usize) -> i64) -> usize {
    type Span = (i64, i64);
    let l = a.layers;
    let px = |s: usize| 1i64 << s;
    let grow = |(lo, hi): Span, by: i64| (lo - by, hi + by);
    let union = |a: Span, b: Span| (a.0.min(b.0), a.1.max(b.1));
    let c = ((a.conv_size - 1) / 2) as i64;
    let conv = |t: Span, s: usize, cin: usize| grow(t, (c + extra(s, cin)) * px(s));
    let pool = |(lo, hi): Span, s: usize| (lo, hi + px(s)); // scale s → s + 1
    let up_nearest = |(lo, hi): Span, s: usize| (lo - px(s), hi); // scale s + 1 → s
    let up_bilinear = |(lo, hi): Span, s: usize| (lo - 2 * px(s), hi + px(s));
    // Input channels of each layer, in `layer_shapes`' order.
    let cin: Vec<usize> = layer_shapes(a).iter().map(|&(_, n, _)| n).collect();
    let dec = layer_offsets(a).0;
    let mut enc: Vec<Span> = Vec::new();
    for s in 0..=l {
        let x = if s == 0 { (0, 0) } else { pool(enc[s - 1], s - 1) };
        enc.push(conv(conv(x, s, cin[2 * s]), s, cin[2 * s + 1]));
    }
    let mut feats = enc.clone();
    for (j, s) in (1..l).rev().enumerate() {
        feats[s] = conv(union(up_nearest(feats[s + 1], s), enc[s]), s, cin[dec + j]);
    }
    // Clamped to the 3×3 neighbourhood; spreading the excess reaches one pixel further.
    let reach = if a.clamp == Clamp::Spread { 2 } else { 1 };
    let mut colour: Vec<Span> = vec![(-reach, reach)];
    for s in 1..l {
        colour.push(pool(colour[s - 1], s - 1));
    }
    let r = ((a.kernel_size - 1) / 2) as i64;
    let mut out: Option<Span> = None;
    for s in (0..l).rev() {
        let logits = if s == 0 { union(up_nearest(feats[1], 0), enc[0]) } else { feats[s] };
        let o = union(logits, grow(colour[s], r * px(s)));
        out = Some(match (out, a.blend) {
            (None, _) => o,
            (Some(coarse), ScaleBlend::Lerp) => union(o, up_bilinear(coarse, s)),
            (Some(coarse), ScaleBlend::Detail) => union(o, up_bilinear(union(coarse, pool(o, s)), s)),
        });
    }
    let (lo, hi) = out.expect("at least one level");
    lo.unsigned_abs().max(hi.unsigned_abs()) as usize
}

/// The noisy colour at scales `0..levels`, each a 2×2 box average of the one above, with
/// isolated fireflies clamped at full resolution to their 8 neighbours' maximum
/// ([`Planes::clamp_to_neighbours`]) so that no full-resolution kernel can keep one.
/// What the clamp removes is lost ([`Clamp::Hard`]), shared over the 3×3 neighbourhood
/// ([`Clamp::Spread`]), averaged into the coarsest scale ([`Clamp::Coarse`]), or kept in
/// every coarser scale, which pool the unclamped colour ([`Clamp::Fine`]; with
/// [`Clamp::FinePairs`] clamped to the second-brightest neighbour, once or, with
/// [`Clamp::FinePairsTwice`], twice): smooth regions draw
/// from those, so there the energy stays without a speck. (Mid-means instead of
/// averages also stop 2-pixel fireflies, but their downward bias on skewed low-sample
/// noise cost more than they saved: measured on held-out simulator frames.)
pub fn colour_pyramid(noisy: Planes, levels: usize, clamp: Clamp) -> Vec<Planes> {
    let h = noisy.h;
    colour_pyramid_rows(noisy, levels, clamp, 0..h)
}

/// Rows each side of its own that a pixel's clamped value reads ([`colour_pyramid`]'s
/// clamps: two 3×3 passes at most).
pub const CLAMP_CONTEXT: usize = 2;

/// Rows `keep` of [`colour_pyramid`] (at scale `s`, its rows `keep.start >> s` to
/// `keep.end >> s`), from `noisy`'s rows `keep` and [`CLAMP_CONTEXT`] rows each side of
/// them (fewer only where `noisy` ends with the region): the clamp reads those, the
/// coarser scales pool the rows of `keep` alone, so where `keep` starts on the grid of the
/// region's coarsest scale every scale is the whole region's, bit for bit, without
/// evaluating rows beyond what the clamp needs.
pub fn colour_pyramid_rows(noisy: Planes, levels: usize, clamp: Clamp, keep: std::ops::Range<usize>) -> Vec<Planes> {
    // A fourth plane, where the caller gives one ([`Clamp::reads_variance`]), is each
    // pixel's variance.
    let (noisy, variance) = if noisy.c == 4 {
        let n = noisy.w * noisy.h;
        let variance = noisy.plane(3).to_vec();
        let mut colour = noisy;
        colour.data.truncate(3 * n);
        colour.c = 3;
        (colour, Some(variance))
    } else {
        (noisy, None)
    };
    let (first, mut excess) = match clamp {
        Clamp::Hard => (noisy.clamp_to_neighbours().crop_rows(keep), None),
        Clamp::Spread => (noisy.clamp_to_neighbours_spreading().crop_rows(keep), None),
        Clamp::Coarse => {
            let clamped = noisy.clamp_to_neighbours();
            let excess = noisy.minus(&clamped);
            (clamped.crop_rows(keep.clone()), Some(excess.crop_rows(keep)))
        }
        Clamp::Fine | Clamp::FinePairs | Clamp::FinePairsTwice | Clamp::Significant => {
            let clamped = match (clamp, variance.as_deref()) {
                (Clamp::Fine, _) => noisy.clamp_to_neighbours(),
                (Clamp::FinePairs, _) => noisy.clamp_to_second_neighbour(),
                (Clamp::Significant, Some(variance)) => {
                    let twice = noisy.clamp_to_second_neighbour().clamp_to_second_neighbour();
                    twice.min(&noisy.clamp_insignificant(variance, SIGNIFICANT_ERRORS))
                }
                _ => noisy.clamp_to_second_neighbour().clamp_to_second_neighbour(),
            };
            let mut colour = vec![clamped.crop_rows(keep.clone())];
            if levels > 1 {
                colour.push(noisy.crop_rows(keep).avg_pool2());
            }
            for s in 2..levels {
                let c = colour[s - 1].avg_pool2();
                colour.push(c);
            }
            return colour;
        }
    };
    let mut colour = vec![first];
    for s in 1..levels {
        let c = colour[s - 1].avg_pool2();
        colour.push(c);
        excess = excess.map(|e| e.avg_pool2());
    }
    if let (Some(e), Some(coarsest)) = (excess, colour.last_mut()) {
        coarsest.add(&e);
    }
    colour
}

/// What the multi-scale network is made of, on one kind of value. Layers are named by
/// their index in [`layer_shapes`].
pub trait Backend {
    /// An activation: channels at one scale (of one region, or of a batch).
    type Value;
    /// What an operation can fail with.
    type Error;

    /// Convolution `layer` of `x`, then ReLU when `relu`.
    fn conv(&self, x: &Self::Value, layer: usize, relu: bool) -> Result<Self::Value, Self::Error>;

    /// 2×2 average pooling.
    fn pool(&self, x: &Self::Value) -> Result<Self::Value, Self::Error>;

    /// Convolution `layer` of `nearest-up(coarse) ++ skip`: the decoder's layers and the
    /// full-resolution head.
    fn conv_up_concat(
        &self,
        coarse: &Self::Value,
        skip: &Self::Value,
        layer: usize,
        relu: bool,
    ) -> Result<Self::Value, Self::Error>;

    /// The noisy colour at scales `0..levels` ([`colour_pyramid`]).
    fn colour(&self, noisy: Self::Value, levels: usize) -> Result<Vec<Self::Value>, Self::Error>;

    /// The softmax kernels of `logits` (its first `k²` channels) applied to `colour`,
    /// extended by replicating its edges.
    fn apply(&self, logits: &Self::Value, colour: &Self::Value) -> Result<Self::Value, Self::Error>;

    /// `a − b` (the same shape).
    fn sub(&self, a: &Self::Value, b: &Self::Value) -> Result<Self::Value, Self::Error>;

    /// With `α` the sigmoid of channel `k²` of `logits`: `(1 − α)·fine + α·up(coarse)`
    /// ([`ScaleBlend::Lerp`]), or `fine + α·up(coarse)` ([`ScaleBlend::Detail`], whose
    /// `coarse` is already the coarser result less `down(fine)`).
    fn blend(&self, fine: Self::Value, coarse: &Self::Value, logits: &Self::Value) -> Result<Self::Value, Self::Error>;

    /// `x·2σ(g)`, with `g` channel [`gain_channel`] of `logits` ([`Architecture::gain`]).
    fn gain(&self, x: Self::Value, logits: &Self::Value) -> Result<Self::Value, Self::Error>;
}

/// The multi-scale network on a region: `input` its features (27 channels) and `noisy`
/// its colour `c̃` (3 channels), sides multiples of [`Architecture::alignment`]; returns
/// the denoised `c̃`. Convolutions pad with zeros and kernels replicate the edge, so only
/// pixels at least [`receptive_radius`] inside the region equal the whole frame's.
pub fn run<B: Backend>(a: &Architecture, b: &B, input: B::Value, noisy: B::Value) -> Result<B::Value, B::Error> {
    let l = a.layers;
    let (dec, head) = layer_offsets(a);
    let mut enc: Vec<B::Value> = Vec::with_capacity(l + 1);
    let first = b.conv(&input, 0, true)?;
    drop(input);
    enc.push(b.conv(&first, 1, true)?);
    drop(first);
    for s in 1..=l {
        let x = b.conv(&b.pool(&enc[s - 1])?, 2 * s, true)?;
        enc.push(b.conv(&x, 2 * s + 1, true)?);
    }
    // F_s: the decoder's output at scale s (the encoder's at the bottom); F_0 is unused.
    let mut feats: Vec<Option<B::Value>> = (0..=l).map(|_| None).collect();
    for (j, s) in (1..l).rev().enumerate() {
        let below = feats[s + 1].as_ref().unwrap_or(&enc[s + 1]);
        feats[s] = Some(b.conv_up_concat(below, &enc[s], dec + j, true)?);
    }
    let feat = |s: usize| feats[s].as_ref().unwrap_or(&enc[s]);
    let colour = b.colour(noisy, l)?;
    let mut out: Option<B::Value> = None;
    for (j, s) in (0..l).rev().enumerate() {
        let logits = if s == 0 {
            b.conv_up_concat(feat(1), &enc[0], head + j, false)?
        } else {
            b.conv(feat(s), head + j, false)?
        };
        let o = b.apply(&logits, &colour[s])?;
        let o = match (out, a.blend) {
            (None, _) => o,
            (Some(coarse), ScaleBlend::Lerp) => b.blend(o, &coarse, &logits)?,
            (Some(coarse), ScaleBlend::Detail) => {
                let rest = b.sub(&coarse, &b.pool(&o)?)?;
                b.blend(o, &rest, &logits)?
            }
        };
        out = Some(if s == 0 && a.gain { b.gain(o, &logits)? } else { o });
    }
    Ok(out.expect("validated: at least one level"))
}

/// A branch as a candle graph on batches `[B, C, H, W]`, for training: `ops` picks our
/// kernels (with their backward passes) or candle's stock ones.
pub struct Graph<'a> {
    /// The architecture.
    pub arch: &'a Architecture,
    /// The branch's weights.
    pub weights: &'a BranchWeights,
    /// The implementation.
    pub ops: Ops,
}

impl Backend for Graph<'_> {
    type Value = Tensor;
    type Error = ModelError;

    fn conv(&self, x: &Tensor, layer: usize, relu: bool) -> Result<Tensor, ModelError> {
        let (wt, b) = &self.weights.layers[layer];
        Ok(self.ops.conv2d(x, wt, b, relu)?)
    }

    fn pool(&self, x: &Tensor) -> Result<Tensor, ModelError> {
        Ok(x.avg_pool2d(2)?)
    }

    fn conv_up_concat(&self, coarse: &Tensor, skip: &Tensor, layer: usize, relu: bool) -> Result<Tensor, ModelError> {
        self.conv(&self.ops.up_concat(coarse, skip)?, layer, relu)
    }

    fn colour(&self, noisy: Tensor, levels: usize) -> Result<Vec<Tensor>, ModelError> {
        // The noisy colour is data, not a function of the weights: its pyramid needs no
        // gradient and is built by the same code as at inference.
        let (b, _, hh, ww) = noisy.dims4()?;
        let items: Vec<Vec<Planes>> = (0..b)
            .map(|i| {
                let data = noisy.get(i)?.flatten_all()?.to_vec1()?;
                Ok(colour_pyramid(Planes::from_vec(3, ww, hh, data), levels, self.arch.clamp))
            })
            .collect::<Result<_, ModelError>>()?;
        (0..levels)
            .map(|s| {
                let data: Vec<f32> = items.iter().flat_map(|p| p[s].data.iter().copied()).collect();
                Ok(Tensor::from_vec(data, (b, 3, hh >> s, ww >> s), noisy.device())?)
            })
            .collect()
    }

    fn apply(&self, logits: &Tensor, colour: &Tensor) -> Result<Tensor, ModelError> {
        let (k, r) = (self.arch.kernel_size, (self.arch.kernel_size - 1) / 2);
        let padded = colour.pad_with_same(2, r, r)?.pad_with_same(3, r, r)?;
        Ok(self.ops.apply_kernels(&logits.narrow(1, 0, k * k)?, &padded, k)?)
    }

    fn sub(&self, a: &Tensor, b: &Tensor) -> Result<Tensor, ModelError> {
        Ok((a - b)?)
    }

    fn blend(&self, fine: Tensor, coarse: &Tensor, logits: &Tensor) -> Result<Tensor, ModelError> {
        let k2 = self.arch.kernel_size * self.arch.kernel_size;
        let logits = logits.narrow(1, k2, 1)?;
        Ok(match self.arch.blend {
            ScaleBlend::Lerp => self.ops.blend(&fine, coarse, &logits)?,
            ScaleBlend::Detail => crate::kernel::ops::add_blended(&fine, coarse, &logits)?,
        })
    }

    fn gain(&self, x: Tensor, logits: &Tensor) -> Result<Tensor, ModelError> {
        Ok(crate::kernel::ops::gained(&x, &logits.narrow(1, gain_channel(self.arch), 1)?)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn winograd_tiles_start_where_every_regions_columns_start() {
        // Regions start on multiples of the alignment at full resolution; at scale s on
        // multiples of alignment >> s, which the filter's tile must divide.
        for a in [Architecture::ladder(crate::model::Quality::Balanced), Architecture::multiscale()] {
            let filters: Vec<Option<Winograd>> = (0..=a.layers).map(|s| winograd_scale(&a, s)).collect();
            for (s, f) in filters.iter().enumerate() {
                assert!(f.is_none_or(|f| (a.alignment() >> s).is_multiple_of(f.tile())), "scale {s}: {f:?}");
            }
            assert_eq!(filters[..2], [Some(Winograd::F4); 2], "F(4, 3) at the finest scales");
            assert_eq!(filters[a.layers], None, "the coarsest scale goes directly");
        }
    }

    #[test]
    fn the_column_radius_adds_f43s_extra_columns() {
        // The ladder's F(4, 3) layers: E_0's two (27 and 16 inputs), E_1's two and D_1,
        // on the deepest path, each reading two more pixels of its scale each side:
        // 2·1 + 2·1 + 2·2 + 2·2 + 2·2 = 16 px.
        let a = Architecture::ladder(crate::model::Quality::Balanced);
        assert_eq!(radius(&a, |s, cin| winograd_extra(&a, s, cin)) - radius(&a, |_, _| 0), 16);
        assert_eq!(column_radius(&a) % a.alignment(), 0);
        assert!(column_radius(&a) >= receptive_radius(&a));
        // F(4, 3) on every scale it could take would cost 88.
        let every = |s: usize, cin: usize| {
            let f4 = (a.alignment() >> s).is_multiple_of(4) && Winograd::F4.takes(cin, 3);
            if f4 { 2 } else { 0 }
        };
        assert_eq!(radius(&a, every) - radius(&a, |_, _| 0), 88);
    }

    #[test]
    fn an_isolated_firefly_reaches_no_scale() {
        let (w, h) = (16, 8);
        let mut x = vec![0.25f32; 3 * w * h];
        x[5 * w + 9] = 1e4; // red channel only
        let pyramid = colour_pyramid(Planes::from_vec(3, w, h, x), 3, Clamp::Hard);
        assert_eq!(pyramid.iter().map(|p| (p.w, p.h)).collect::<Vec<_>>(), [(16, 8), (8, 4), (4, 2)]);
        for p in &pyramid {
            assert!(p.data.iter().all(|&v| v == 0.25), "{:?}", p.data);
        }
    }

    #[test]
    fn rows_of_the_pyramid_from_their_own_rows_and_the_clamps_context_are_the_whole_ones_bits() {
        // Fireflies, pairs of them and a bright edge on noise, with a variance plane; every
        // clamp; rows from the coarsest scale's grid (4 rows for 3 scales) with the
        // clamp's context, cut by the region's top and bottom or not.
        let (w, h, levels) = (11, 24, 3);
        let mut x = crate::rng::SplitMix64(5).centred(4 * w * h);
        x.iter_mut().for_each(|v| *v = v.abs());
        for (i, v) in [(3 * w + 4, 1e4), (9 * w + 2, 300.0), (9 * w + 3, 280.0), (20 * w + 10, 5e3)] {
            x[i] = v;
        }
        x[15 * w..16 * w].iter_mut().for_each(|v| *v = 40.0);
        let clamps = [Clamp::Hard, Clamp::Spread, Clamp::Coarse, Clamp::Fine];
        for clamp in clamps.into_iter().chain([Clamp::FinePairs, Clamp::FinePairsTwice, Clamp::Significant]) {
            let whole = colour_pyramid(Planes::from_vec(4, w, h, x.clone()), levels, clamp);
            for (a, b) in [(0usize, 8usize), (4, 12), (8, 24), (12, 16), (0, 24), (20, 24)] {
                let (lo, hi) = (a.saturating_sub(CLAMP_CONTEXT), (b + CLAMP_CONTEXT).min(h));
                let window: Vec<f32> = (0..4).flat_map(|c| x[(c * h + lo) * w..(c * h + hi) * w].to_vec()).collect();
                let rows = colour_pyramid_rows(Planes::from_vec(4, w, hi - lo, window), levels, clamp, a - lo..b - lo);
                for (s, (got, all)) in rows.iter().zip(&whole).enumerate() {
                    let want = all.clone().crop_rows(a >> s..b >> s);
                    let bits = |p: &Planes| p.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(got), bits(&want), "{clamp:?}, rows {a}..{b}, scale {s}");
                }
            }
        }
    }

    #[test]
    fn the_energy_keeping_clamps_keep_a_firefly_out_of_full_resolution_only() {
        let (w, h) = (16, 8);
        let mut x = vec![0.25f32; 3 * w * h];
        x[5 * w + 9] = 1e4 + 0.25;
        let sum = |p: &Planes| p.plane(0).iter().map(|&v| v as f64).sum::<f64>() * (w * h / (p.w * p.h)) as f64;
        let total = sum(&Planes::from_vec(3, w, h, x.clone()));
        for clamp in [Clamp::Coarse, Clamp::Fine, Clamp::FinePairs] {
            let pyramid = colour_pyramid(Planes::from_vec(3, w, h, x.clone()), 3, clamp);
            assert!(pyramid[0].data.iter().all(|&v| v == 0.25), "{clamp:?}: the speck is kept at full resolution");
            // The coarsest scale holds the whole energy (scaled by its pixels' area)…
            assert!((sum(&pyramid[2]) - total).abs() < 1e-6 * total, "{clamp:?}");
            // …and `fine` the middle one too, where `coarse` keeps it out.
            let middle = (sum(&pyramid[1]) - total).abs() < 1e-6 * total;
            assert_eq!(middle, clamp != Clamp::Coarse, "{clamp:?}");
        }
    }

    #[test]
    fn pairs_of_fireflies_reach_full_resolution_only_past_the_single_clamp() {
        // Two adjacent outliers: each is the other's brightest neighbour, so the single
        // clamp keeps both; clamped to the second-brightest neighbour, neither stays. A
        // line three pixels long keeps its middle either way.
        let (w, h) = (12, 8);
        let mut x = vec![0.25f32; 3 * w * h];
        x[3 * w + 4] = 1e3;
        x[3 * w + 5] = 1e3;
        for c in 7..10 {
            x[6 * w + c] = 2.0;
        }
        let level0 = |clamp| colour_pyramid(Planes::from_vec(3, w, h, x.clone()), 2, clamp).swap_remove(0);
        let (single, pairs) = (level0(Clamp::Fine), level0(Clamp::FinePairs));
        assert_eq!((single.data[3 * w + 4], single.data[3 * w + 5]), (1e3, 1e3));
        assert_eq!((pairs.data[3 * w + 4], pairs.data[3 * w + 5]), (0.25, 0.25));
        assert_eq!(pairs.data[6 * w + 8], 2.0, "a line's middle stays");
    }

    #[test]
    fn a_diagonal_triple_of_fireflies_goes_only_with_the_pairs_clamp_twice() {
        // The middle of three on a diagonal has two of them as neighbours: `fine-pairs`
        // keeps it (a Cycles caustic at 4 spp, tests/cycles_crops.rs); run twice, the ends
        // go first, then the middle. A line seven pixels long keeps its middle three.
        let (w, h) = (14, 10);
        let mut x = vec![0.25f32; 3 * w * h];
        for d in 0..3 {
            x[(2 + d) * w + 3 + d] = 1e3;
        }
        for c in 4..11 {
            x[8 * w + c] = 2.0;
        }
        let level0 = |clamp| colour_pyramid(Planes::from_vec(3, w, h, x.clone()), 2, clamp).swap_remove(0);
        let (pairs, twice) = (level0(Clamp::FinePairs), level0(Clamp::FinePairsTwice));
        assert_eq!(pairs.data[3 * w + 4], 1e3, "fine-pairs keeps the middle");
        assert!((0..3).all(|d| twice.data[(2 + d) * w + 3 + d] == 0.25), "twice, none stays");
        assert!((6..9).all(|c| twice.data[8 * w + c] == 2.0), "a line's middle stays");
        assert!([4, 5, 9, 10].iter().all(|&c| twice.data[8 * w + c] < 2.0), "its two end pixels each side go");
    }

    #[test]
    fn a_cluster_of_one_sample_hits_goes_only_with_the_significance_clamp() {
        // The rim of a defocused bulb at 64 spp (the dev set's `bokeh`): a 2×2 block of four
        // pixels that one sample each of a light of 307 reached (4.8, a standard error of
        // 4.8), on a background every sample saw alike (0.018, no variance). Its pixels
        // have one another as neighbours, so `fine-pairs-twice` keeps them; the
        // significance clamp takes them to the background. Beside them, a highlight as large
        // that every sample saw (4.8, a standard error of 0.1) loses only its three errors,
        // and the edge of an emitter (7 in 2 of 4 samples, beside 14 that every sample saw)
        // stays.
        let (w, h) = (16, 12);
        let (mut x, mut var) = (vec![0.018f32; 4 * w * h], vec![0f32; w * h]);
        let set = |x: &mut Vec<f32>, var: &mut Vec<f32>, (px, py): (usize, usize), v: f32, e: f32| {
            for c in 0..3 {
                x[c * w * h + py * w + px] = v;
            }
            var[py * w + px] = e * e;
        };
        for p in [(3, 3), (4, 3), (3, 4), (4, 4)] {
            set(&mut x, &mut var, p, 4.8, 4.8);
        }
        for p in [(10, 3), (11, 3), (10, 4), (11, 4)] {
            set(&mut x, &mut var, p, 4.8, 0.1);
        }
        for px in 8..14 {
            set(&mut x, &mut var, (px, 8), 14.0, 0.0);
        }
        set(&mut x, &mut var, (10, 9), 7.0, 4.1);
        x[3 * w * h..].copy_from_slice(&var);
        let twice = colour_pyramid(Planes::from_vec(4, w, h, x.clone()), 2, Clamp::FinePairsTwice);
        let significant = colour_pyramid(Planes::from_vec(4, w, h, x.clone()), 2, Clamp::Significant);
        let (t, s) = (&twice[0], &significant[0]);
        assert_eq!((t.c, s.c, significant[1].c), (3, 3, 3), "the variance is read, not passed on");
        assert!(
            [(3, 3), (4, 3), (3, 4), (4, 4)].iter().all(|&(px, py)| t.data[py * w + px] == 4.8),
            "twice keeps them"
        );
        assert!([(3, 3), (4, 3), (3, 4), (4, 4)].iter().all(|&(px, py)| s.data[py * w + px] == 0.018), "they go");
        assert!((s.data[3 * w + 10] - 4.5).abs() < 1e-5, "the highlight keeps all but 3 errors");
        assert_eq!(s.data[9 * w + 10], 7.0, "the emitter's edge stays");
        // Coarser scales pool the unclamped colour: the hits' light is kept there.
        assert_eq!(significant[1], twice[1]);
        // Without a variance plane it is `fine-pairs-twice`.
        x.truncate(3 * w * h);
        assert_eq!(colour_pyramid(Planes::from_vec(3, w, h, x), 2, Clamp::Significant)[0], *t);
    }

    #[test]
    fn the_receptive_radius_covers_the_kernels_and_sits_on_the_grid() {
        let a = Architecture::multiscale();
        let r = receptive_radius(&a);
        assert_eq!(r % a.alignment(), 0);
        // The coarsest kernels alone reach (k − 1)/2 quarter-resolution pixels.
        assert!(r >= (a.kernel_size - 1) / 2 * (1 << (a.layers - 1)), "{r}");
    }
}
