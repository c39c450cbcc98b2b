//! Inference of the multi-scale network ([`multiscale::run`], which defines it once): a
//! [`multiscale::Backend`] on plain planes with the same kernels as training,
//! [`crate::kernel::conv`] convolutions and [`crate::kernel::apply`] kernel application at
//! every scale, and none of candle's graph. [`super::stream::Stream`] runs it on windows
//! of rows; the tests here and there run it on a whole region at once.

use super::multiscale::{self, Backend};
use super::{Architecture, BranchWeights, ModelError, ScaleBlend};
use crate::features::INPUT_CHANNELS;
use crate::kernel::conv::{ConvLayer, conv, conv_rows, conv_up_concat};
use crate::kernel::planes::{Planes, add_blended, blend, gain};
use rayon::prelude::*;

/// Working bytes per region pixel, for tile budgets: the input, two full-resolution
/// activations, the head's logits, and 16 planes' worth for the colour pyramid, the
/// coarser scales and the outputs. Measured peaks on a 1344×800 region (`VmHWM`) lie
/// 4–27 % below it: 247, 367 and 449 B/px for widths 8, 16 and 24 at 5 levels; 361 for
/// the 3-level default.
pub fn bytes_per_pixel(arch: &Architecture) -> usize {
    let k2 = arch.kernel_size * arch.kernel_size;
    4 * (INPUT_CHANNELS + 2 * arch.channels + k2 + 1 + usize::from(arch.gain) + 16)
}

/// One branch's convolutions packed for [`conv`], converted from the model's tensors
/// once per [`crate::denoise::Denoiser`] rather than once per tile.
#[derive(Debug, Clone)]
pub struct Weights {
    /// Every layer, in the model file's order.
    layers: Vec<ConvLayer>,
    /// The full-resolution head split in two (see `conv_up_concat` below): the part
    /// applied to the upsampled coarse features (without bias) and the part applied to
    /// `E_0`.
    head0: [ConvLayer; 2],
}

impl Weights {
    /// Copies and packs a branch's tensors.
    pub fn new(arch: &Architecture, weights: &BranchWeights) -> Result<Weights, ModelError> {
        let mut layers = Vec::with_capacity(weights.layers.len());
        let mut last = None;
        for (i, (wt, b)) in weights.layers.iter().enumerate() {
            let (_, cin, k, _) = wt.dims4()?;
            let (wt, b) = (wt.flatten_all()?.to_vec1::<f32>()?, b.to_vec1::<f32>()?);
            let layer = ConvLayer::new(&wt, &b, cin, k);
            layers.push(multiscale::inference_layer(arch, multiscale::layer_scale(arch, i), layer));
            last = Some((wt, b, cin));
        }
        let (wt, b, cin) = last.ok_or_else(|| ModelError::Format {
            origin: "model".into(),
            what: "a multi-scale branch without layers".into(),
        })?;
        // A 1×1 layer commutes with nearest upsampling: the upsampled half of its input is
        // convolved at half resolution, four times cheaper.
        let c1 = multiscale::width(arch, 1);
        let split = |from: usize, to: usize| -> Vec<f32> {
            (0..b.len()).flat_map(|r| wt[r * cin + from..r * cin + to].to_vec()).collect()
        };
        let head0 = [
            ConvLayer::new(&split(0, c1), &vec![0.0; b.len()], c1, 1),
            ConvLayer::new(&split(c1, cin), &b, cin - c1, 1),
        ];
        Ok(Weights { layers, head0 })
    }
}

/// Denoised `c̃` (three `w × h` planes) of a `w × h` region (sides multiples of
/// [`Architecture::alignment`]) evaluated whole: `input` its 27 CHW feature planes,
/// `noisy` its `c̃` (and its variance, a fourth plane, where the clamp reads it). The
/// reference the streamed evaluation is tested against.
#[cfg(test)]
pub fn forward(
    arch: &Architecture,
    weights: &Weights,
    input: Vec<f32>,
    noisy: Vec<f32>,
    w: usize,
    h: usize,
) -> [Vec<f32>; 3] {
    let input = Planes::from_vec(INPUT_CHANNELS, w, h, input);
    let noisy = Planes::from_vec(noisy.len() / (w * h).max(1), w, h, noisy);
    let out = match multiscale::run(arch, &Region { arch, weights }, input, noisy) {
        Ok(out) => out,
        Err(e) => match e {},
    };
    let n = w * h;
    [0, 1, 2].map(|c| out.data[c * n..(c + 1) * n].to_vec())
}

/// A branch's packed weights as a [`Backend`] on planes, which cannot fail.
pub(super) struct Region<'a> {
    pub(super) arch: &'a Architecture,
    pub(super) weights: &'a Weights,
}

impl Region<'_> {
    /// Rows `out` of [`Backend::conv`] of `w × h` planes that are never built: `row_of`
    /// writes their rows ([`conv_rows`]). Also [`Backend::conv_up_concat`]'s, where layer
    /// `layer` is not the split head ([`Region::splits`]).
    pub(super) fn conv_rows(
        &self,
        layer: usize,
        relu: bool,
        size: (usize, usize),
        out: std::ops::Range<usize>,
        row_of: impl Fn(usize, usize, &mut [f32]) + Sync,
    ) -> Planes {
        conv_rows(&self.weights.layers[layer], relu, size, out, row_of)
    }

    /// Whether layer `layer` is the full-resolution head, which
    /// [`Backend::conv_up_concat`] runs split in two ([`Weights`]).
    pub(super) fn splits(&self, layer: usize) -> bool {
        layer + 1 >= self.weights.layers.len()
    }
}

impl Backend for Region<'_> {
    type Value = Planes;
    type Error = std::convert::Infallible;

    fn conv(&self, x: &Planes, layer: usize, relu: bool) -> Result<Planes, Self::Error> {
        Ok(conv(x, &self.weights.layers[layer], relu))
    }

    fn pool(&self, x: &Planes) -> Result<Planes, Self::Error> {
        Ok(x.avg_pool2())
    }

    fn conv_up_concat(&self, coarse: &Planes, skip: &Planes, layer: usize, relu: bool) -> Result<Planes, Self::Error> {
        if !self.splits(layer) {
            return Ok(conv_up_concat(coarse, skip, &self.weights.layers[layer], relu));
        }
        // The full-resolution head, split (see [`Weights`]).
        let [up, own] = &self.weights.head0;
        let coarse = conv(coarse, up, false);
        let mut fine = conv(skip, own, false);
        fine.add_up_nearest(&coarse);
        if relu {
            fine.data.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        Ok(fine)
    }

    fn colour(&self, noisy: Planes, levels: usize) -> Result<Vec<Planes>, Self::Error> {
        Ok(multiscale::colour_pyramid(noisy, levels, self.arch.clamp))
    }

    fn apply(&self, logits: &Planes, colour: &Planes) -> Result<Planes, Self::Error> {
        Ok(apply_replicated(logits, colour, self.arch.kernel_size))
    }

    fn sub(&self, a: &Planes, b: &Planes) -> Result<Planes, Self::Error> {
        Ok(difference(a, b))
    }

    fn blend(&self, mut fine: Planes, coarse: &Planes, logits: &Planes) -> Result<Planes, Self::Error> {
        blend_scales(self.arch, &mut fine, &coarse.up_bilinear(), logits);
        Ok(fine)
    }

    fn gain(&self, mut x: Planes, logits: &Planes) -> Result<Planes, Self::Error> {
        gain(&mut x, logits.plane(multiscale::gain_channel(self.arch)));
        Ok(x)
    }
}

/// `a − b`, plane by plane (the same shape).
fn difference(a: &Planes, b: &Planes) -> Planes {
    assert_eq!((a.c, a.w, a.h), (b.c, b.w, b.h), "difference of planes of different sizes");
    Planes::from_vec(a.c, a.w, a.h, a.data.iter().zip(&b.data).map(|(x, y)| x - y).collect())
}

/// `fine` blended in place with `up`, the coarser result already upsampled, by the blend
/// logit of `logits` (its plane `k²`), as the architecture blends ([`ScaleBlend`]).
pub(super) fn blend_scales(arch: &Architecture, fine: &mut Planes, up: &Planes, logits: &Planes) {
    let l = logits.plane(arch.kernel_size * arch.kernel_size);
    match arch.blend {
        ScaleBlend::Lerp => blend(fine, up, l),
        ScaleBlend::Detail => add_blended(fine, up, l),
    }
}

/// Softmax kernels (the first `k²` planes of `logits`) applied to `colour`, the colour
/// extended by replicating its edge pixels.
fn apply_replicated(logits: &Planes, colour: &Planes, k: usize) -> Planes {
    let (w, h) = (colour.w, colour.h);
    apply_rows(logits, &|c, y| &colour.plane(c)[y * w..][..w], 0, h, k)
}

/// [`apply_replicated`] for rows `[a, a + logits.h)` of a colour `h` rows high, read a
/// row at a time by `colour_row(channel, y)` (only rows within the kernel's radius of
/// those are read): the colour extended by replicating the rows and columns at its edges.
pub(super) fn apply_rows<'c>(
    logits: &Planes,
    colour_row: &(dyn Fn(usize, usize) -> &'c [f32] + Sync),
    a: usize,
    h: usize,
    k: usize,
) -> Planes {
    let (w, n, r) = (logits.w, logits.h, (k - 1) / 2);
    let (pw, ph) = (w + 2 * r, n + 2 * r);
    let padded: Vec<Vec<f32>> = (0..3)
        .into_par_iter()
        .map(|c| {
            let mut p = vec![0f32; pw * ph];
            p.par_chunks_mut(pw).enumerate().for_each(|(y, dst)| {
                let row = colour_row(c, (a + y).saturating_sub(r).min(h - 1));
                for (x, d) in dst.iter_mut().enumerate() {
                    *d = row[x.saturating_sub(r).min(w - 1)];
                }
            });
            p
        })
        .collect();
    let padded: [Vec<f32>; 3] = padded.try_into().expect("three planes");
    let k2 = k * k;
    let out = crate::kernel::apply(&logits.data[..k2 * w * n], &padded, k, w, n);
    Planes::from_vec(3, w, n, out.concat())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Architecture, Model, ScaleBlend};
    use candle_core::{Device, Tensor};

    #[test]
    fn our_kernels_match_the_candle_definition() {
        for blend in [ScaleBlend::Lerp, ScaleBlend::Detail] {
            matches_candle(Architecture { blend, ..Architecture::multiscale() });
        }
        // Xavier weights give the gain logit a spread of values.
        matches_candle(Architecture { gain: true, ..Architecture::multiscale() });
    }

    fn matches_candle(arch: Architecture) {
        let m = Model::xavier(arch, 5).unwrap();
        let (w, h) = (48, 40);
        let mut rng = crate::rng::SplitMix64(9);
        let input: Vec<f32> = (0..INPUT_CHANNELS * w * h).map(|_| rng.uniform_f32() - 0.5).collect();
        let noisy: Vec<f32> = (0..3 * w * h).map(|_| rng.uniform_f32() * 2.0).collect();
        let x = Tensor::from_vec(input.clone(), (1, INPUT_CHANNELS, h, w), &Device::Cpu).unwrap();
        let c = Tensor::from_vec(noisy.clone(), (1, 3, h, w), &Device::Cpu).unwrap();
        for (branch, weights) in [("diffuse", &m.diffuse), ("specular", &m.specular)] {
            let ours = forward(&arch, &Weights::new(&arch, weights).unwrap(), input.clone(), noisy.clone(), w, h);
            let graph = multiscale::Graph { arch: &arch, weights, ops: crate::kernel::ops::Ops::StockCandle };
            let theirs = multiscale::run(&arch, &graph, x.clone(), c.clone()).unwrap();
            let theirs = theirs.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            for c in 0..3 {
                for i in 0..w * h {
                    let (a, b) = (ours[c][i], theirs[c * w * h + i]);
                    assert!(
                        (a - b).abs() < 1e-4 * (1.0 + b.abs()),
                        "{:?} (gain {}) {branch} channel {c} pixel {i}: {a} vs {b}",
                        arch.blend,
                        arch.gain
                    );
                }
            }
        }
    }

    #[test]
    fn the_detail_blend_keeps_what_is_finer_than_the_coarse_scale() {
        // A checkerboard of 0.2 and 1.0 at the fine scale, a flat 0.5 at the coarse one
        // (what its 2×2 average, 0.6, is brought to), the blend weight saturated at 1.
        let (w, h) = (8, 8);
        let fine =
            Planes::from_vec(1, w, h, (0..w * h).map(|i| if (i % w + i / w) % 2 == 0 { 0.2 } else { 1.0 }).collect());
        let coarse = Planes::from_vec(1, w / 2, h / 2, vec![0.5; w * h / 4]);
        let mut logits = Planes::zeros(26, w, h);
        logits.data[25 * w * h..].fill(30.0);
        let arch = |blend| Architecture { blend, ..Architecture::multiscale() };
        let region = |a: &Architecture| {
            // Only the blend runs: the weights are never read.
            let weights = Weights::new(a, &Model::xavier(*a, 0).unwrap().diffuse).unwrap();
            let r = Region { arch: a, weights: &weights };
            match a.blend {
                ScaleBlend::Lerp => r.blend(fine.clone(), &coarse, &logits),
                ScaleBlend::Detail => r.blend(fine.clone(), &r.sub(&coarse, &fine.avg_pool2()).unwrap(), &logits),
            }
            .unwrap()
        };
        // Interpolated, the result is the coarse scale: the pattern is gone.
        let lerp = region(&arch(ScaleBlend::Lerp));
        assert!(lerp.data.iter().all(|&v| (v - 0.5).abs() < 1e-6), "{:?}", lerp.data);
        // With the detail blend, the pattern keeps its full contrast about the new mean.
        let detail = region(&arch(ScaleBlend::Detail));
        for (i, (&d, &f)) in detail.data.iter().zip(&fine.data).enumerate() {
            assert!((d - (f - 0.1)).abs() < 1e-6, "pixel {i}: {d}, want {}", f - 0.1);
        }
    }

    #[test]
    fn a_detail_blended_region_equals_the_whole_frame_inside_its_receptive_radius() {
        // The receptive radius bounds what a region's edge can change: the halo tiles and
        // bands are evaluated with.
        let arch = Architecture { blend: ScaleBlend::Detail, ..Architecture::multiscale() };
        let m = Model::xavier(arch, 3).unwrap();
        let weights = Weights::new(&arch, &m.diffuse).unwrap();
        let (r, a) = (arch.feature_radius(), arch.alignment());
        let (w, h) = (2 * r + 2 * a, 2 * r + 2 * a);
        let mut rng = crate::rng::SplitMix64(4);
        let input: Vec<f32> = (0..INPUT_CHANNELS * w * h).map(|_| rng.uniform_f32() - 0.5).collect();
        let noisy: Vec<f32> = (0..3 * w * h).map(|_| rng.uniform_f32() * 2.0).collect();
        let whole = forward(&arch, &weights, input.clone(), noisy.clone(), w, h);
        // The frame less one aligned band on every side.
        let (x0, sw, sh) = (a, w - 2 * a, h - 2 * a);
        let crop = |planes: &[f32], c: usize| -> Vec<f32> {
            (0..c)
                .flat_map(|ch| (x0..x0 + sh).flat_map(move |y| (x0..x0 + sw).map(move |x| (ch, y, x))))
                .map(|(ch, y, x)| planes[(ch * h + y) * w + x])
                .collect()
        };
        let part = forward(&arch, &weights, crop(&input, INPUT_CHANNELS), crop(&noisy, 3), sw, sh);
        for c in 0..3 {
            for y in r..sh - r {
                for x in r..sw - r {
                    let (p, f) = (part[c][y * sw + x], whole[c][(y + x0) * w + x + x0]);
                    assert!((p - f).abs() <= 1e-5 * (1.0 + f.abs()), "channel {c} at ({x}, {y}): {p} vs {f}");
                }
            }
        }
    }
}
