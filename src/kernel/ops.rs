//! The kernels of this module as candle operations with their own backward passes, so
//! training runs the same forward code as inference and differentiates it explicitly
//! instead of through candle's composed ops (SPEC §5).

use super::conv::{ConvLayer, conv_batch, weight_gradient};
use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Result, Shape, Storage, Tensor};

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
        // ReLU passes the gradient where its output is positive.
        let g: Vec<f32> = with_values(&grad, "kpcn-conv gradient", |g| {
            if !self.relu {
                return Ok(g.to_vec());
            }
            with_values(out, "kpcn-conv output", |o| {
                Ok(g.iter().zip(o).map(|(&g, &o)| if o > 0.0 { g } else { 0.0 }).collect())
            })
        })?;
        let mut db = vec![0f32; cout];
        for (i, plane) in g.chunks(h * w).enumerate() {
            db[i % cout] += plane.iter().sum::<f32>();
        }
        let (dx, dw) = with_values(wt, "kpcn-conv weights", |wv| {
            let back = ConvLayer::transposed(wv, cout, cin, k);
            let dx = conv_batch(&g, b, w, h, &back, false);
            let dw = with_values(x, "kpcn-conv input", |xv| Ok(weight_gradient(xv, &g, b, w, h, cin, cout, k)))?;
            Ok((dx, dw))
        })?;
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

    /// Softmax kernels applied to the noisy colour, as [`apply_kernels`].
    pub fn apply_kernels(self, logits: &Tensor, noisy: &Tensor, k: usize) -> Result<Tensor> {
        match self {
            Ops::Kpcn => apply_kernels(logits, noisy, k),
            Ops::StockCandle => apply_kernels_composed(logits, noisy, k),
        }
    }
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
