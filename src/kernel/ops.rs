//! The kernels of this module as candle operations with their own backward passes, so
//! training runs the same forward code as inference and differentiates it explicitly
//! instead of through candle's composed ops (slow on CPU: BENCHMARKS.md).

use super::conv::{ConvLayer, ConvShape, conv_batch, weight_gradient};
use super::planes::{self, Planes};
use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Result, Shape, Storage, Tensor};
use rayon::prelude::*;

/// The contiguous `f32` values of a tensor operand.
fn values<'a>(s: &'a CpuStorage, l: &Layout, what: &str) -> Result<&'a [f32]> {
    let (from, to) = l
        .contiguous_offsets()
        .ok_or_else(|| candle_core::Error::Msg(format!("{what}: the operand is not contiguous")))?;
    Ok(&s.as_slice::<f32>()?[from..to])
}

/// Runs `f` on the values of a contiguous CPU tensor, in place (no copy).
fn with_values<R>(t: &Tensor, what: &str, f: impl FnOnce(&[f32]) -> Result<R>) -> Result<R> {
    let (storage, layout) = t.storage_and_layout();
    match &*storage {
        Storage::Cpu(s) => f(values(s, layout, what)?),
        _ => candle_core::bail!("{what}: kpcn's kernels run on the CPU"),
    }
}

/// The sum of `v` in 16 interleaved partial sums, then pairwise: a fixed order that
/// vectorises (a running sum is one long chain of dependent adds).
fn sum(v: &[f32]) -> f32 {
    let mut lanes = [0f32; 16];
    let chunks = v.chunks_exact(16);
    let tail: f32 = chunks.remainder().iter().sum();
    for c in chunks {
        for (l, x) in lanes.iter_mut().zip(c) {
            *l += x;
        }
    }
    for half in [8, 4, 2, 1] {
        for i in 0..half {
            lanes[i] += lanes[i + half];
        }
    }
    lanes[0] + tail
}

/// A "same" zero-padded convolution plus bias, then ReLU when `relu`: `x`
/// `[B, Cin, H, W]`, weights `[Cout, Cin, k, k]` (odd `k`), bias `[Cout]`.
struct Conv {
    relu: bool,
}

impl CustomOp3 for Conv {
    fn name(&self) -> &'static str {
        "kpcn-conv"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (b, cin, h, w) = l1.shape().dims4()?;
        let (cout, wcin, k, k2) = l2.shape().dims4()?;
        if wcin != cin || k != k2 || k % 2 == 0 || l3.shape().dims() != [cout] {
            candle_core::bail!("kpcn-conv: weights {:?} and bias {:?} for {cin} channels", l2.shape(), l3.shape());
        }
        let layer = ConvLayer::new(values(s2, l2, "kpcn-conv weights")?, values(s3, l3, "kpcn-conv bias")?, cin, k);
        let out = conv_batch(values(s1, l1, "kpcn-conv input")?, b, w, h, &layer, self.relu);
        Ok((CpuStorage::F32(out), Shape::from((b, cout, h, w))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        wt: &Tensor,
        bias: &Tensor,
        out: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (b, cin, h, w) = x.dims4()?;
        let (cout, _, k, _) = wt.dims4()?;
        let grad = grad.contiguous()?;
        // ReLU passes the gradient where its output is positive (written in parallel into a
        // pooled buffer, never zeroed first); each plane's sum goes to its channel's bias
        // gradient, in plane order.
        let mut g = super::buffers::with_capacity(b * cout * h * w);
        with_values(&grad, "kpcn-conv gradient", |grad| {
            if self.relu {
                with_values(out, "kpcn-conv output", |o| {
                    grad.par_iter().zip(o).map(|(&d, &o)| if o > 0.0 { d } else { 0.0 }).collect_into_vec(&mut g);
                    Ok(())
                })
            } else {
                grad.par_iter().copied().collect_into_vec(&mut g);
                Ok(())
            }
        })?;
        let sums: Vec<f32> = g.par_chunks(h * w).map(sum).collect();
        let mut db = vec![0f32; cout];
        for (i, s) in sums.iter().enumerate() {
            db[i % cout] += s;
        }
        let (dx, dw) = with_values(wt, "kpcn-conv weights", |wv| {
            let back = ConvLayer::transposed(wv, cout, cin, k);
            let dx = conv_batch(&g, b, w, h, &back, false);
            let dw = with_values(x, "kpcn-conv input", |xv| {
                Ok(weight_gradient(xv, &g, ConvShape { items: b, w, h, cin, cout, k }))
            })?;
            Ok((dx, dw))
        })?;
        super::buffers::recycle(g);
        Ok((
            Some(Tensor::from_vec(dx, (b, cin, h, w), x.device())?),
            Some(Tensor::from_vec(dw, (cout, cin, k, k), wt.device())?),
            Some(Tensor::from_vec(db, cout, bias.device())?),
        ))
    }
}

/// `x` `[B, Cin, H, W]` convolved with `weight` `[Cout, Cin, k, k]` (odd `k`, zero
/// padding, same size) plus `bias` `[Cout]`, then ReLU when `relu`: candle's
/// `conv2d(…, (k − 1)/2, 1, 1, 1)` on our kernels, forward and backward.
pub fn conv2d(x: &Tensor, weight: &Tensor, bias: &Tensor, relu: bool) -> Result<Tensor> {
    let (x, weight) = (x.contiguous()?, weight.contiguous()?);
    x.apply_op3(&weight, &bias.contiguous()?, Conv { relu })
}

/// Softmax kernels applied to the noisy colour (see [`super::apply`]): logits
/// `[B, k², h, w]`, noisy `[B, 3, h + 2r, w + 2r]`. The noisy colour is data and gets no
/// gradient.
struct ApplyKernels {
    k: usize,
}

impl ApplyKernels {
    fn dims(&self, logits: &Shape, noisy: &Shape) -> Result<(usize, usize, usize)> {
        let (b, n, h, w) = logits.dims4()?;
        let r = (self.k - 1) / 2;
        if n != self.k * self.k || noisy.dims4()? != (b, 3, h + 2 * r, w + 2 * r) {
            candle_core::bail!("kpcn-kernels: logits {logits:?} and noisy {noisy:?} for {}×{} kernels", self.k, self.k);
        }
        Ok((b, h, w))
    }
}

/// The three noisy planes of item `i`, each `plane` long.
fn noisy_planes(noisy: &[f32], i: usize, plane: usize) -> [Vec<f32>; 3] {
    std::array::from_fn(|c| noisy[(3 * i + c) * plane..][..plane].to_vec())
}

impl CustomOp2 for ApplyKernels {
    fn name(&self) -> &'static str {
        "kpcn-kernels"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        let (b, h, w) = self.dims(l1.shape(), l2.shape())?;
        let (k, r) = (self.k, (self.k - 1) / 2);
        let (logits, noisy) = (values(s1, l1, "kpcn-kernels logits")?, values(s2, l2, "kpcn-kernels noisy")?);
        let padded = (w + 2 * r) * (h + 2 * r);
        let mut out = Vec::with_capacity(b * 3 * h * w);
        for i in 0..b {
            let l = &logits[i * k * k * h * w..][..k * k * h * w];
            out.extend(super::apply(l, &noisy_planes(noisy, i, padded), k, w, h).concat());
        }
        Ok((CpuStorage::F32(out), Shape::from((b, 3, h, w))))
    }

    fn bwd(
        &self,
        logits: &Tensor,
        noisy: &Tensor,
        _: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let (b, h, w) = self.dims(logits.shape(), noisy.shape())?;
        let (k, r) = (self.k, (self.k - 1) / 2);
        let lv = logits.flatten_all()?.to_vec1::<f32>()?;
        let nv = noisy.flatten_all()?.to_vec1::<f32>()?;
        let gv = grad.contiguous()?.flatten_all()?.to_vec1::<f32>()?;
        let padded = (w + 2 * r) * (h + 2 * r);
        let mut dl = Vec::with_capacity(lv.len());
        for i in 0..b {
            let l = &lv[i * k * k * h * w..][..k * k * h * w];
            let g: [&[f32]; 3] = std::array::from_fn(|c| &gv[(3 * i + c) * h * w..][..h * w]);
            dl.extend(super::apply_backward(l, &noisy_planes(&nv, i, padded), g, k, w, h));
        }
        Ok((Some(Tensor::from_vec(dl, logits.shape(), logits.device())?), None))
    }
}

/// Softmax kernels `logits` `[B, k², h, w]` applied to `noisy` `[B, 3, h + 2r, w + 2r]`,
/// giving `[B, 3, h, w]`, differentiable in the logits.
pub fn apply_kernels(logits: &Tensor, noisy: &Tensor, k: usize) -> Result<Tensor> {
    logits.contiguous()?.apply_op2(&noisy.contiguous()?.detach(), ApplyKernels { k })
}

/// The coarse-to-fine blend ([`planes::blend`]): `fine` `[B, 3, h, w]`, `coarse`
/// `[B, 3, h/2, w/2]`, blend `logits` `[B, 1, h, w]`.
struct Blend;

impl Blend {
    fn dims(fine: &Shape, coarse: &Shape, logits: &Shape) -> Result<(usize, usize, usize, usize)> {
        let (b, c, h, w) = fine.dims4()?;
        if coarse.dims4()? != (b, c, h / 2, w / 2) || logits.dims4()? != (b, 1, h, w) || h % 2 + w % 2 != 0 {
            candle_core::bail!("kpcn-blend: fine {fine:?}, coarse {coarse:?} and logits {logits:?} do not fit");
        }
        Ok((b, c, h, w))
    }
}

impl CustomOp3 for Blend {
    fn name(&self) -> &'static str {
        "kpcn-blend"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (b, c, h, w) = Blend::dims(l1.shape(), l2.shape(), l3.shape())?;
        let (fine, coarse) = (values(s1, l1, "kpcn-blend fine")?, values(s2, l2, "kpcn-blend coarse")?);
        let logits = values(s3, l3, "kpcn-blend logits")?;
        let (n, m) = (c * h * w, c * h * w / 4);
        let mut out = Vec::with_capacity(b * n);
        for i in 0..b {
            let mut f = Planes::from_vec(c, w, h, fine[i * n..][..n].to_vec());
            let up = Planes::from_vec(c, w / 2, h / 2, coarse[i * m..][..m].to_vec()).up_bilinear();
            planes::blend(&mut f, &up, &logits[i * h * w..][..h * w]);
            out.extend_from_slice(&f.data);
        }
        Ok((CpuStorage::F32(out), Shape::from((b, c, h, w))))
    }

    fn bwd(
        &self,
        fine: &Tensor,
        coarse: &Tensor,
        logits: &Tensor,
        _: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (b, c, h, w) = Blend::dims(fine.shape(), coarse.shape(), logits.shape())?;
        let (n, m, p) = (c * h * w, c * h * w / 4, h * w);
        let grad = grad.contiguous()?;
        let (mut d_fine, mut d_coarse, mut d_logits) = (Vec::with_capacity(b * n), Vec::new(), Vec::new());
        with_values(&grad, "kpcn-blend gradient", |g| {
            with_values(fine, "kpcn-blend fine", |fv| {
                with_values(coarse, "kpcn-blend coarse", |cv| {
                    with_values(logits, "kpcn-blend logits", |lv| {
                        for i in 0..b {
                            let up = Planes::from_vec(c, w / 2, h / 2, cv[i * m..][..m].to_vec()).up_bilinear();
                            let (g, f, l) = (&g[i * n..][..n], &fv[i * n..][..n], &lv[i * p..][..p]);
                            let alpha: Vec<f32> = l.iter().map(|&l| planes::blend_weight(l)).collect();
                            let mut d_up = vec![0f32; n];
                            let mut dl = vec![0f32; p];
                            for (j, ((g, f), u)) in g.iter().zip(f).zip(&up.data).enumerate() {
                                let a = alpha[j % p];
                                d_fine.push(g * (1.0 - a));
                                d_up[j] = g * a;
                                dl[j % p] += g * (u - f);
                            }
                            // dα/dl = α(1 − α) inside the clamp, 0 where it clamps.
                            for ((d, &a), &l) in dl.iter_mut().zip(&alpha).zip(l) {
                                *d *= if l.abs() < planes::BLEND_LIMIT { a * (1.0 - a) } else { 0.0 };
                            }
                            d_logits.extend(dl);
                            d_coarse.extend_from_slice(&Planes::from_vec(c, w, h, d_up).up_bilinear_adjoint().data);
                        }
                        Ok(())
                    })
                })
            })
        })?;
        Ok((
            Some(Tensor::from_vec(d_fine, fine.shape(), fine.device())?),
            Some(Tensor::from_vec(d_coarse, coarse.shape(), coarse.device())?),
            Some(Tensor::from_vec(d_logits, logits.shape(), logits.device())?),
        ))
    }
}

/// `(1 − α)·fine + α·up(coarse)` with `α` the clamped sigmoid of `logits` and `up`
/// bilinear ([`planes::blend`]), differentiable in all three.
pub fn blend(fine: &Tensor, coarse: &Tensor, logits: &Tensor) -> Result<Tensor> {
    fine.contiguous()?.apply_op3(&coarse.contiguous()?, &logits.contiguous()?, Blend)
}

/// `coarse` `[B, C₁, h/2, w/2]` upsampled 2× to the nearest neighbour, then `skip`
/// `[B, C₂, h, w]` after it along the channels: the decoder's input.
struct UpConcat;

impl CustomOp2 for UpConcat {
    fn name(&self) -> &'static str {
        "kpcn-up-concat"
    }

    fn cpu_fwd(&self, s1: &CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> Result<(CpuStorage, Shape)> {
        let (b, c1, h2, w2) = l1.shape().dims4()?;
        let (b2, c2, h, w) = l2.shape().dims4()?;
        if b2 != b || (h, w) != (2 * h2, 2 * w2) {
            candle_core::bail!("kpcn-up-concat: coarse {:?} does not upsample to skip {:?}", l1.shape(), l2.shape());
        }
        let (coarse, skip) = (values(s1, l1, "kpcn-up-concat coarse")?, values(s2, l2, "kpcn-up-concat skip")?);
        let (m, n) = (c1 * h2 * w2, c2 * h * w);
        let mut out = Vec::with_capacity(b * (4 * m + n));
        for i in 0..b {
            out.extend_from_slice(&Planes::from_vec(c1, w2, h2, coarse[i * m..][..m].to_vec()).up_nearest().data);
            out.extend_from_slice(&skip[i * n..][..n]);
        }
        Ok((CpuStorage::F32(out), Shape::from((b, c1 + c2, h, w))))
    }

    fn bwd(
        &self,
        coarse: &Tensor,
        skip: &Tensor,
        _: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let (b, c1, h2, w2) = coarse.dims4()?;
        let (_, c2, h, w) = skip.dims4()?;
        let grad = grad.contiguous()?;
        let (dc, ds) = with_values(&grad, "kpcn-up-concat gradient", |g| {
            let (m, n) = (4 * c1 * h2 * w2, c2 * h * w);
            let (mut dc, mut ds) = (Vec::with_capacity(b * m / 4), Vec::with_capacity(b * n));
            for i in 0..b {
                let item = &g[i * (m + n)..][..m + n];
                // Each coarse value was copied to a 2×2 block: its gradient is their sum.
                for c in 0..c1 {
                    let p = &item[c * h * w..][..h * w];
                    for y in 0..h2 {
                        let (r0, r1) = (&p[2 * y * w..][..w], &p[(2 * y + 1) * w..][..w]);
                        dc.extend((0..w2).map(|x| r0[2 * x] + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1]));
                    }
                }
                ds.extend_from_slice(&item[m..]);
            }
            Ok((dc, ds))
        })?;
        Ok((
            Some(Tensor::from_vec(dc, coarse.shape(), coarse.device())?),
            Some(Tensor::from_vec(ds, skip.shape(), skip.device())?),
        ))
    }
}

/// The decoder's input: `coarse` upsampled 2× to the nearest neighbour, then `skip`,
/// along the channels; differentiable in both.
pub fn up_concat(coarse: &Tensor, skip: &Tensor) -> Result<Tensor> {
    coarse.contiguous()?.apply_op2(&skip.contiguous()?, UpConcat)
}

/// Which implementation a training graph runs: ours (the default), or candle's stock
/// `conv2d` and a kernel application composed of candle ops, kept to measure against.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Ops {
    /// [`conv2d`] and [`apply_kernels`]: our kernels and backward passes.
    #[default]
    Kpcn,
    /// Candle's `conv2d` and composed ops, differentiated by candle's autograd.
    StockCandle,
}

impl Ops {
    /// A "same" convolution plus bias, then ReLU when `relu`, as [`conv2d`].
    pub fn conv2d(self, x: &Tensor, weight: &Tensor, bias: &Tensor, relu: bool) -> Result<Tensor> {
        match self {
            Ops::Kpcn => conv2d(x, weight, bias, relu),
            Ops::StockCandle => {
                let (cout, _, k, _) = weight.dims4()?;
                let y = x.conv2d(weight, (k - 1) / 2, 1, 1, 1)?.broadcast_add(&bias.reshape((1, cout, 1, 1))?)?;
                if relu { y.relu() } else { Ok(y) }
            }
        }
    }

    /// The decoder's input, as [`up_concat`].
    pub fn up_concat(self, coarse: &Tensor, skip: &Tensor) -> Result<Tensor> {
        match self {
            Ops::Kpcn => up_concat(coarse, skip),
            Ops::StockCandle => {
                // Broadcasts, not candle 0.11's `upsample_nearest2d`: its backward overwrites
                // instead of adding to the gradient of a tensor that has other uses.
                let (b, c, h, w) = coarse.dims4()?;
                let up = coarse.reshape((b, c, h, 1, w, 1))?.broadcast_as((b, c, h, 2, w, 2))?.contiguous()?;
                Tensor::cat(&[up.reshape((b, c, 2 * h, 2 * w))?, skip.clone()], 1)
            }
        }
    }

    /// The coarse-to-fine blend, as [`blend`].
    pub fn blend(self, fine: &Tensor, coarse: &Tensor, logits: &Tensor) -> Result<Tensor> {
        match self {
            Ops::Kpcn => blend(fine, coarse, logits),
            Ops::StockCandle => {
                let alpha = blend_weight_composed(logits)?;
                let up = up_bilinear_composed(coarse)?;
                fine.broadcast_mul(&(1.0 - &alpha)?)? + up.broadcast_mul(&alpha)?
            }
        }
    }

    /// Softmax kernels applied to the noisy colour, as [`apply_kernels`].
    pub fn apply_kernels(self, logits: &Tensor, noisy: &Tensor, k: usize) -> Result<Tensor> {
        match self {
            Ops::Kpcn => apply_kernels(logits, noisy, k),
            Ops::StockCandle => apply_kernels_composed(logits, noisy, k),
        }
    }
}

/// `fine + α·up(coarse)`, with `α` the sigmoid of `logits` (`[B, 1, H, W]`, clamped to
/// ±[`planes::BLEND_LIMIT`]) and `up` [`Planes::up_bilinear`]: the detail-keeping blend
/// ([`planes::add_blended`]), composed of candle ops, which candle's autograd
/// differentiates.
pub fn add_blended(fine: &Tensor, coarse: &Tensor, logits: &Tensor) -> Result<Tensor> {
    fine + up_bilinear_composed(coarse)?.broadcast_mul(&blend_weight_composed(logits)?)?
}

/// `x·2σ(g)`, with `σ(g)` [`planes::blend_weight`] of `logits` (`[B, 1, H, W]`): the
/// multi-scale network's gain ([`planes::gain`]), composed of candle ops.
pub fn gained(x: &Tensor, logits: &Tensor) -> Result<Tensor> {
    x.broadcast_mul(&(blend_weight_composed(logits)? * 2.0)?)
}

/// [`planes::blend_weight`] of every logit, composed of candle ops.
fn blend_weight_composed(logits: &Tensor) -> Result<Tensor> {
    let limit = planes::BLEND_LIMIT as f64;
    (logits.clamp(-limit, limit)?.neg()?.exp()? + 1.0)?.recip()
}

/// [`Planes::up_bilinear`] of `[B, C, H, W]` composed of candle ops: ¾ of each parent
/// plus ¼ of its neighbour on the output's side (edges replicated), along each axis.
fn up_bilinear_composed(x: &Tensor) -> Result<Tensor> {
    let along = |x: &Tensor, dim: usize| -> Result<Tensor> {
        let n = x.dim(dim)?;
        let before = x.pad_with_same(dim, 1, 0)?.narrow(dim, 0, n)?;
        let after = x.pad_with_same(dim, 0, 1)?.narrow(dim, 1, n)?;
        let even = ((x * 0.75)? + (before * 0.25)?)?;
        let odd = ((x * 0.75)? + (after * 0.25)?)?;
        let mut dims = x.dims().to_vec();
        dims[dim] *= 2;
        Tensor::stack(&[even, odd], dim + 1)?.reshape(dims)
    };
    along(&along(x, 3)?, 2)
}

/// [`apply_kernels`] composed of candle ops (softmax with the maximum subtracted, then one
/// shifted product per tap), which candle's autograd differentiates.
fn apply_kernels_composed(logits: &Tensor, noisy: &Tensor, k: usize) -> Result<Tensor> {
    let (_, _, h, w) = logits.dims4()?;
    let max = logits.max_keepdim(1)?.detach();
    let e = logits.broadcast_sub(&max)?.exp()?;
    let weights = e.broadcast_div(&e.sum_keepdim(1)?)?;
    let mut acc = noisy.narrow(2, 0, h)?.narrow(3, 0, w)?.broadcast_mul(&weights.narrow(1, 0, 1)?)?;
    for n in 1..k * k {
        let patch = noisy.narrow(2, n / k, h)?.narrow(3, n % k, w)?;
        acc = (acc + patch.broadcast_mul(&weights.narrow(1, n, 1)?)?)?;
    }
    Ok(acc)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use candle_core::{Device, Var};

    /// `Σ f(x)·g` and its gradient in `x`, by candle's autograd.
    fn grad_of(f: impl Fn(&Tensor) -> Tensor, x: &Var, g: &Tensor) -> (Vec<f32>, Vec<f32>) {
        let y = f(x.as_tensor());
        let grads = (&y * g).unwrap().sum_all().unwrap().backward().unwrap();
        let dx = grads.get(x.as_tensor()).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        (y.flatten_all().unwrap().to_vec1().unwrap(), dx)
    }

    fn close(what: &str, a: &[f32], b: &[f32], tol: f32) {
        assert_eq!(a.len(), b.len(), "{what}");
        for (i, (a, b)) in a.iter().zip(b).enumerate() {
            assert!((a - b).abs() <= tol * (1.0 + b.abs()), "{what} at {i}: {a} vs {b}");
        }
    }

    #[test]
    fn convolution_matches_candle_forward_and_backward() {
        let dev = Device::Cpu;
        for (b, cin, cout, k, h, w) in [(2, 5, 7, 3, 6, 19), (1, 9, 3, 1, 4, 33), (3, 16, 16, 3, 8, 40)] {
            let x = Var::from_vec(SplitMix64(1).centred(b * cin * h * w), (b, cin, h, w), &dev).unwrap();
            let wt = Var::from_vec(SplitMix64(2).centred(cout * cin * k * k), (cout, cin, k, k), &dev).unwrap();
            let bias = Var::from_vec(SplitMix64(3).centred(cout), cout, &dev).unwrap();
            let g = Tensor::from_vec(SplitMix64(4).centred(b * cout * h * w), (b, cout, h, w), &dev).unwrap();
            let relu = k == 3;
            let ours = |x: &Tensor| Ops::Kpcn.conv2d(x, wt.as_tensor(), bias.as_tensor(), relu).unwrap();
            let theirs = |x: &Tensor| Ops::StockCandle.conv2d(x, wt.as_tensor(), bias.as_tensor(), relu).unwrap();
            let (y0, dx0) = grad_of(ours, &x, &g);
            let (y1, dx1) = grad_of(theirs, &x, &g);
            close("output", &y0, &y1, 1e-5);
            close("input gradient", &dx0, &dx1, 1e-4);
            for (name, var) in [("weight", &wt), ("bias", &bias)] {
                let d = |f: &dyn Fn(&Tensor) -> Tensor| -> Vec<f32> {
                    let grads = (f(x.as_tensor()) * &g).unwrap().sum_all().unwrap().backward().unwrap();
                    grads.get(var.as_tensor()).unwrap().flatten_all().unwrap().to_vec1().unwrap()
                };
                close(&format!("{name} gradient"), &d(&ours), &d(&theirs), 1e-4);
            }
        }
    }

    #[test]
    fn kernel_application_matches_its_composed_definition() {
        let dev = Device::Cpu;
        let (k, h, w) = (5, 4, 6);
        let lv: Vec<f32> = SplitMix64(8).centred(k * k * h * w).iter().map(|v| v * 6.0).collect();
        let logits = Var::from_vec(lv, (2, k * k, h, w / 2), &dev).unwrap();
        let noisy =
            Tensor::from_vec(SplitMix64(9).centred(2 * 3 * (h + 4) * (w / 2 + 4)), (2, 3, h + 4, w / 2 + 4), &dev)
                .unwrap();
        let g = Tensor::from_vec(SplitMix64(10).centred(3 * h * w), (2, 3, h, w / 2), &dev).unwrap();
        let (y0, d0) = grad_of(|l| Ops::Kpcn.apply_kernels(l, &noisy, k).unwrap(), &logits, &g);
        let (y1, d1) = grad_of(|l| Ops::StockCandle.apply_kernels(l, &noisy, k).unwrap(), &logits, &g);
        close("output", &y0, &y1, 1e-5);
        close("logit gradient", &d0, &d1, 1e-4);
    }

    #[test]
    fn the_blend_matches_its_composed_definition() {
        let dev = Device::Cpu;
        let (b, h, w) = (2, 6, 8);
        let fine = Var::from_vec(SplitMix64(11).centred(b * 3 * h * w), (b, 3, h, w), &dev).unwrap();
        let coarse = Var::from_vec(SplitMix64(12).centred(b * 3 * h * w / 4), (b, 3, h / 2, w / 2), &dev).unwrap();
        let mut lv: Vec<f32> = SplitMix64(13).centred(b * h * w).iter().map(|v| v * 8.0).collect();
        lv[3] = 45.0; // clamped: no gradient
        let logits = Var::from_vec(lv, (b, 1, h, w), &dev).unwrap();
        let g = Tensor::from_vec(SplitMix64(14).centred(b * 3 * h * w), (b, 3, h, w), &dev).unwrap();
        let run = |ops: Ops| {
            let y = ops.blend(fine.as_tensor(), coarse.as_tensor(), logits.as_tensor()).unwrap();
            let grads = (&y * &g).unwrap().sum_all().unwrap().backward().unwrap();
            let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let d = |v: &Var| flat(grads.get(v.as_tensor()).unwrap());
            [flat(&y), d(&fine), d(&coarse), d(&logits)]
        };
        let (ours, theirs) = (run(Ops::Kpcn), run(Ops::StockCandle));
        for (name, (a, b)) in ["output", "fine", "coarse", "logit"].iter().zip(ours.iter().zip(&theirs)) {
            close(name, a, b, 1e-5);
        }
    }

    #[test]
    fn the_decoder_input_matches_its_composed_definition() {
        let dev = Device::Cpu;
        let coarse = Var::from_vec(SplitMix64(15).centred(2 * 3 * 2 * 3), (2, 3, 2, 3), &dev).unwrap();
        let skip = Var::from_vec(SplitMix64(16).centred(2 * 2 * 4 * 6), (2, 2, 4, 6), &dev).unwrap();
        let g = Tensor::from_vec(SplitMix64(17).centred(2 * 5 * 4 * 6), (2, 5, 4, 6), &dev).unwrap();
        let run = |ops: Ops| {
            let y = ops.up_concat(coarse.as_tensor(), skip.as_tensor()).unwrap();
            let grads = (&y * &g).unwrap().sum_all().unwrap().backward().unwrap();
            let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            [flat(&y), flat(grads.get(coarse.as_tensor()).unwrap()), flat(grads.get(skip.as_tensor()).unwrap())]
        };
        let (ours, theirs) = (run(Ops::Kpcn), run(Ops::StockCandle));
        for (name, (a, b)) in ["output", "coarse", "skip"].iter().zip(ours.iter().zip(&theirs)) {
            close(name, a, b, 1e-6);
        }
    }

    #[test]
    fn kernel_gradients_match_finite_differences() {
        let dev = Device::Cpu;
        let (k, h, w) = (3, 3, 4);
        let lv = SplitMix64(5).centred(k * k * h * w).iter().map(|v| v * 4.0).collect::<Vec<_>>();
        let noisy = Tensor::from_vec(SplitMix64(6).centred(3 * (h + 2) * (w + 2)), (1, 3, h + 2, w + 2), &dev).unwrap();
        let g = Tensor::from_vec(SplitMix64(7).centred(3 * h * w), (1, 3, h, w), &dev).unwrap();
        let loss = |l: &[f32]| -> f64 {
            let lt = Tensor::from_vec(l.to_vec(), (1, k * k, h, w), &dev).unwrap();
            let y = apply_kernels(&lt, &noisy, k).unwrap();
            let y = y.to_dtype(candle_core::DType::F64).unwrap();
            (y * g.to_dtype(candle_core::DType::F64).unwrap()).unwrap().sum_all().unwrap().to_scalar().unwrap()
        };
        let logits = Var::from_vec(lv.clone(), (1, k * k, h, w), &dev).unwrap();
        let (_, analytic) = grad_of(|l| apply_kernels(l, &noisy, k).unwrap(), &logits, &g);
        for i in (0..lv.len()).step_by(7) {
            let (mut up, mut down) = (lv.clone(), lv.clone());
            up[i] += 1e-2;
            down[i] -= 1e-2;
            let numeric = (loss(&up) - loss(&down)) / 2e-2;
            assert!((numeric as f32 - analytic[i]).abs() < 2e-3, "logit {i}: {numeric} vs {}", analytic[i]);
        }
    }
}
