//! Inference of the multi-scale network ([`multiscale::run`], which defines it once): a
//! [`multiscale::Backend`] on plain planes with the same kernels as training,
//! [`crate::kernel::conv`] convolutions and [`crate::kernel::apply`] kernel application at
//! every scale, and none of candle's graph. [`super::stream::Stream`] runs it on windows
//! of rows; the tests here and there run it on a whole region at once.

use super::multiscale::{self, Backend};
use super::{Architecture, BranchWeights, ModelError};
use crate::features::INPUT_CHANNELS;
use crate::kernel::conv::{ConvLayer, conv, conv_up_concat};
use crate::kernel::planes::{Planes, blend};
use rayon::prelude::*;

/// Working bytes per region pixel, for tile budgets: the input, two full-resolution
/// activations, the head's logits, and 16 planes' worth for the colour pyramid, the
/// coarser scales and the outputs. Measured peaks on a 1344×800 region (`VmHWM`) lie
/// 4–27 % below it: 247, 367 and 449 B/px for widths 8, 16 and 24 at 5 levels; 361 for
/// the 3-level default.
pub fn bytes_per_pixel(arch: &Architecture) -> usize {
    let k2 = arch.kernel_size * arch.kernel_size;
    4 * (INPUT_CHANNELS + 2 * arch.channels + k2 + 1 + 16)
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
        for (wt, b) in &weights.layers {
            let (_, cin, k, _) = wt.dims4()?;
            let (wt, b) = (wt.flatten_all()?.to_vec1::<f32>()?, b.to_vec1::<f32>()?);
            layers.push(ConvLayer::new(&wt, &b, cin, k));
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
        if layer + 1 < self.weights.layers.len() {
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

    fn blend(&self, mut fine: Planes, coarse: &Planes, logits: &Planes) -> Result<Planes, Self::Error> {
        blend(&mut fine, &coarse.up_bilinear(), logits.plane(self.arch.kernel_size * self.arch.kernel_size));
        Ok(fine)
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
    use crate::model::{Architecture, Model};
    use candle_core::{Device, Tensor};

    #[test]
    fn our_kernels_match_the_candle_definition() {
        let arch = Architecture::multiscale();
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
                    assert!((a - b).abs() < 1e-4 * (1.0 + b.abs()), "{branch} channel {c} pixel {i}: {a} vs {b}");
                }
            }
        }
    }
}
