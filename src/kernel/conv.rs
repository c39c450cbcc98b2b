//! Direct 2-D convolution on CHW planes for inference, with zero padding ("same" size).
//!
//! Candle's CPU conv2d spends most of its time in im2col for the narrow layers of the
//! multi-scale network (SPEC §5: ≈15 GFLOP/s at 32 → 32). This one keeps a block of
//! 4 output channels × 16 pixels in AVX2 registers and streams the input rows through
//! fused multiply-adds, with no unfolded copy. Every output value is summed in the same
//! order (input channel, row, column) wherever it lies in the plane, so a tile's pixels
//! equal the whole frame's bit for bit.

use rayon::prelude::*;

/// Channel-major planes: `c` planes of `w × h`.
#[derive(Debug, Clone, PartialEq)]
pub struct Planes {
    /// Channels.
    pub c: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
    /// `c × h × w` values.
    pub data: Vec<f32>,
}

impl Planes {
    /// Zeros.
    pub fn zeros(c: usize, w: usize, h: usize) -> Planes {
        Planes { c, w, h, data: vec![0.0; c * w * h] }
    }

    /// Wraps CHW data.
    pub fn from_vec(c: usize, w: usize, h: usize, data: Vec<f32>) -> Planes {
        assert_eq!(data.len(), c * w * h, "CHW data of {c}×{h}×{w}");
        Planes { c, w, h, data }
    }

    /// Plane `i`.
    pub fn plane(&self, i: usize) -> &[f32] {
        &self.data[i * self.w * self.h..(i + 1) * self.w * self.h]
    }

    /// `self` then `other` (same size), channel-wise.
    pub fn concat(mut self, other: &Planes) -> Planes {
        assert_eq!((self.w, self.h), (other.w, other.h), "concatenated planes differ in size");
        self.data.extend_from_slice(&other.data);
        self.c += other.c;
        self
    }

    /// 2×2 box average (sides halved, rounding down).
    pub fn avg_pool2(&self) -> Planes {
        let (w, h) = (self.w / 2, self.h / 2);
        let mut out = Planes::zeros(self.c, w, h);
        for c in 0..self.c {
            let src = self.plane(c);
            let dst = &mut out.data[c * w * h..(c + 1) * w * h];
            for y in 0..h {
                let (r0, r1) = (&src[2 * y * self.w..], &src[(2 * y + 1) * self.w..]);
                for x in 0..w {
                    dst[y * w + x] = (r0[2 * x] + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1]) * 0.25;
                }
            }
        }
        out
    }

    /// Every value clamped to the largest of its 8 neighbours (edges replicated): an
    /// isolated outlier (a firefly) takes its brightest neighbour's value, while anything
    /// at least two pixels wide (an edge, a line, a highlight) keeps its extent, its peak
    /// lowered at most to its second-brightest pixel. The result is still a value of the
    /// neighbourhood, so a convex filter of it stays in the range of the original.
    pub fn clamp_to_neighbours(&self) -> Planes {
        let (w, h) = (self.w, self.h);
        let mut out = self.clone();
        for c in 0..self.c {
            let src = self.plane(c);
            let dst = &mut out.data[c * w * h..(c + 1) * w * h];
            for y in 0..h {
                let rows = [y.saturating_sub(1), y, (y + 1).min(h - 1)].map(|r| &src[r * w..(r + 1) * w]);
                for x in 0..w {
                    let cols = [x.saturating_sub(1), x, (x + 1).min(w - 1)];
                    let mut most = f32::NEG_INFINITY;
                    for (i, row) in rows.iter().enumerate() {
                        for (j, &cx) in cols.iter().enumerate() {
                            if (i, j) != (1, 1) {
                                most = most.max(row[cx]);
                            }
                        }
                    }
                    dst[y * w + x] = src[y * w + x].min(most);
                }
            }
        }
        out
    }

    /// 2× nearest-neighbour upsampling.
    pub fn up_nearest(&self) -> Planes {
        let (w, h) = (self.w * 2, self.h * 2);
        let mut out = Planes::zeros(self.c, w, h);
        for c in 0..self.c {
            let src = self.plane(c);
            let dst = &mut out.data[c * w * h..(c + 1) * w * h];
            for (y, row) in dst.chunks_mut(w).enumerate() {
                let s = &src[(y / 2) * self.w..][..self.w];
                for (x, v) in row.iter_mut().enumerate() {
                    *v = s[x / 2];
                }
            }
        }
        out
    }

    /// 2× bilinear upsampling, pixel centres at half-integers, edges replicated: ¾ of the
    /// parent plus ¼ of its neighbour on the output's side, along each axis.
    pub fn up_bilinear(&self) -> Planes {
        let (w, h) = (self.w * 2, self.h * 2);
        let mut out = Planes::zeros(self.c, w, h);
        let mut wide = vec![0f32; w * self.h];
        for c in 0..self.c {
            let src = self.plane(c);
            for y in 0..self.h {
                let s = &src[y * self.w..][..self.w];
                for x in 0..self.w {
                    let (before, after) = (s[x.saturating_sub(1)], s[(x + 1).min(self.w - 1)]);
                    wide[y * w + 2 * x] = s[x] * 0.75 + before * 0.25;
                    wide[y * w + 2 * x + 1] = s[x] * 0.75 + after * 0.25;
                }
            }
            let dst = &mut out.data[c * w * h..(c + 1) * w * h];
            for y in 0..self.h {
                let (above, below) = (y.saturating_sub(1), (y + 1).min(self.h - 1));
                for x in 0..w {
                    let v = wide[y * w + x];
                    dst[2 * y * w + x] = v * 0.75 + wide[above * w + x] * 0.25;
                    dst[(2 * y + 1) * w + x] = v * 0.75 + wide[below * w + x] * 0.25;
                }
            }
        }
        out
    }
}

/// A raw pointer that rows written by different threads share; each row is written by
/// exactly one task.
#[derive(Clone, Copy)]
struct RowsPtr(*mut f32);
unsafe impl Send for RowsPtr {}
unsafe impl Sync for RowsPtr {}

impl RowsPtr {
    /// The pointer (a method, so closures capture the `Sync` wrapper, not the field).
    fn get(self) -> *mut f32 {
        self.0
    }
}

/// `k×k` convolution (odd `k`) of `input` with `weight` `[out][in][k][k]` plus `bias`,
/// zero padding so the output has the input's size; ReLU when `relu`.
pub fn conv(input: &Planes, weight: &[f32], bias: &[f32], k: usize, relu: bool) -> Planes {
    let (cin, cout) = (input.c, bias.len());
    assert_eq!(weight.len(), cout * cin * k * k, "weights are [{cout}][{cin}][{k}][{k}]");
    let r = (k - 1) / 2;
    let (w, h) = (input.w, input.h);
    let (pw, ph) = (w + 2 * r, h + 2 * r);
    // Zero-padded copy, so the inner loops never test borders.
    let padded: std::borrow::Cow<[f32]> = if r == 0 {
        std::borrow::Cow::Borrowed(&input.data)
    } else {
        let mut p = vec![0f32; cin * pw * ph];
        for c in 0..cin {
            for y in 0..h {
                p[c * pw * ph + (y + r) * pw + r..][..w].copy_from_slice(&input.plane(c)[y * w..][..w]);
            }
        }
        std::borrow::Cow::Owned(p)
    };
    let mut out = Planes::zeros(cout, w, h);
    let ptr = RowsPtr(out.data.as_mut_ptr());
    let job = Job { padded: &padded, weight, bias, cin, cout, k, w, h, pw, ph, relu };
    (0..h).into_par_iter().for_each(|y| {
        // SAFETY: row `y` of every output plane is written by this task only, inside the
        // buffer (`y < h`); `out` outlives the parallel loop.
        unsafe { job.row(y, ptr.get()) }
    });
    out
}

struct Job<'a> {
    padded: &'a [f32],
    weight: &'a [f32],
    bias: &'a [f32],
    cin: usize,
    cout: usize,
    k: usize,
    w: usize,
    h: usize,
    pw: usize,
    ph: usize,
    relu: bool,
}

impl Job<'_> {
    /// Output row `y` of every channel.
    ///
    /// # Safety
    /// `out` points at `cout × h × w` floats, `y < h`, and no other thread writes row `y`.
    unsafe fn row(&self, y: usize, out: *mut f32) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the CPU has AVX2 and FMA (checked above).
                return unsafe { self.row_avx2(y, out) };
            }
        }
        for co in 0..self.cout {
            for x in 0..self.w {
                let v = self.pixel(co, x, y, |a, b, c| a * b + c);
                // SAFETY: inside the buffer (caller's contract).
                unsafe { *out.add((co * self.h + y) * self.w + x) = v };
            }
        }
    }

    /// One output value, summed in the canonical order with `fma`.
    #[inline(always)]
    fn pixel(&self, co: usize, x: usize, y: usize, fma: impl Fn(f32, f32, f32) -> f32) -> f32 {
        let (k, pw, plane) = (self.k, self.pw, self.pw * self.ph);
        let mut acc = self.bias[co];
        for ci in 0..self.cin {
            let wb = &self.weight[(co * self.cin + ci) * k * k..][..k * k];
            for ky in 0..k {
                let row = &self.padded[ci * plane + (y + ky) * pw + x..];
                for kx in 0..k {
                    acc = fma(row[kx], wb[ky * k + kx], acc);
                }
            }
        }
        if self.relu { acc.max(0.0) } else { acc }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn row_avx2(&self, y: usize, out: *mut f32) {
        const CO: usize = 4;
        const X: usize = 16;
        let full_x = self.w / X * X;
        let mut co = 0;
        while co + CO <= self.cout {
            for x in (0..full_x).step_by(X) {
                // SAFETY: reads stay inside `padded` (x + 15 + k − 1 < pw), writes inside
                // row y of channels co..co + 4.
                unsafe { self.block_avx2::<CO>(co, x, y, out) };
            }
            co += CO;
        }
        while co < self.cout {
            for x in (0..full_x).step_by(X) {
                // SAFETY: as above, one channel.
                unsafe { self.block_avx2::<1>(co, x, y, out) };
            }
            co += 1;
        }
        // The tail columns, in the same order with the same fused operation.
        for co in 0..self.cout {
            for x in full_x..self.w {
                let v = self.pixel(co, x, y, f32::mul_add);
                // SAFETY: inside the buffer (caller's contract).
                unsafe { *out.add((co * self.h + y) * self.w + x) = v };
            }
        }
    }

    /// `N` output channels from `co`, 16 pixels from `x`, of row `y`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    unsafe fn block_avx2<const N: usize>(&self, co: usize, x: usize, y: usize, out: *mut f32) {
        use std::arch::x86_64::*;
        let (k, pw, plane) = (self.k, self.pw, self.pw * self.ph);
        let mut acc = [[_mm256_setzero_ps(); 2]; N];
        for (j, a) in acc.iter_mut().enumerate() {
            let b = _mm256_set1_ps(self.bias[co + j]);
            *a = [b, b];
        }
        let base = self.padded.as_ptr();
        for ci in 0..self.cin {
            for ky in 0..k {
                // SAFETY (all loads): see `row_avx2`.
                let row = unsafe { base.add(ci * plane + (y + ky) * pw + x) };
                for kx in 0..k {
                    let v0 = unsafe { _mm256_loadu_ps(row.add(kx)) };
                    let v1 = unsafe { _mm256_loadu_ps(row.add(kx + 8)) };
                    for (j, a) in acc.iter_mut().enumerate() {
                        let wv = _mm256_set1_ps(self.weight[((co + j) * self.cin + ci) * k * k + ky * k + kx]);
                        a[0] = _mm256_fmadd_ps(v0, wv, a[0]);
                        a[1] = _mm256_fmadd_ps(v1, wv, a[1]);
                    }
                }
            }
        }
        let zero = _mm256_setzero_ps();
        for (j, a) in acc.iter().enumerate() {
            let (a0, a1) =
                if self.relu { (_mm256_max_ps(a[0], zero), _mm256_max_ps(a[1], zero)) } else { (a[0], a[1]) };
            // SAFETY: 16 floats of row y of channel co + j.
            unsafe {
                let dst = out.add(((co + j) * self.h + y) * self.w + x);
                _mm256_storeu_ps(dst, a0);
                _mm256_storeu_ps(dst.add(8), a1);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use candle_core::{Device, Tensor};

    #[test]
    fn matches_candle_conv2d() {
        // Widths around the 16-pixel blocks, channel counts around the 4-channel blocks.
        for (cin, cout, k, w, h) in [(3, 5, 3, 37, 6), (8, 4, 1, 16, 3), (27, 9, 3, 20, 5), (2, 3, 3, 5, 4)] {
            let x = SplitMix64(1).centred(cin * w * h);
            let wt = SplitMix64(2).centred(cout * cin * k * k);
            let b = SplitMix64(3).centred(cout);
            let ours = conv(&Planes::from_vec(cin, w, h, x.clone()), &wt, &b, k, true);
            let xt = Tensor::from_vec(x, (1, cin, h, w), &Device::Cpu).unwrap();
            let wtt = Tensor::from_vec(wt, (cout, cin, k, k), &Device::Cpu).unwrap();
            let bt = Tensor::from_vec(b, (1, cout, 1, 1), &Device::Cpu).unwrap();
            let theirs = xt.conv2d(&wtt, (k - 1) / 2, 1, 1, 1).unwrap().broadcast_add(&bt).unwrap().relu().unwrap();
            let theirs = theirs.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            for (i, (a, b)) in ours.data.iter().zip(&theirs).enumerate() {
                assert!((a - b).abs() < 1e-5, "{cin}→{cout} k{k} {w}×{h} at {i}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn clamping_to_neighbours_removes_isolated_outliers_only() {
        let mut x = vec![0.5f32; 6 * 5];
        x[2 * 6 + 1] = 40.0; // a firefly
        x[6 + 4] = 9.0; // a two-pixel highlight
        x[2 * 6 + 4] = 8.0;
        x[4 * 6 + 5] = 0.0; // a dark pixel in a corner
        let p = Planes::from_vec(1, 6, 5, x.clone()).clamp_to_neighbours();
        let mut want = x;
        want[2 * 6 + 1] = 0.5;
        want[6 + 4] = 8.0;
        assert_eq!(p.data, want);
    }

    #[test]
    fn a_pixel_does_not_depend_on_where_the_plane_ends() {
        // The same 40×4 content seen whole and as its left 24 columns: identical bits.
        let (cin, cout) = (5, 6);
        let x = SplitMix64(4).centred(cin * 40 * 4);
        let wt = SplitMix64(5).centred(cout * cin * 9);
        let b = SplitMix64(6).centred(cout);
        let whole = conv(&Planes::from_vec(cin, 40, 4, x.clone()), &wt, &b, 3, false);
        let left: Vec<f32> = x.chunks(40).flat_map(|r| r[..24].to_vec()).collect();
        let part = conv(&Planes::from_vec(cin, 24, 4, left), &wt, &b, 3, false);
        for c in 0..cout {
            for y in 0..4 {
                // Column 23 saw zero padding in the part; the rest must agree exactly.
                for x in 0..23 {
                    assert_eq!(part.plane(c)[y * 24 + x].to_bits(), whole.plane(c)[y * 40 + x].to_bits());
                }
            }
        }
    }

    #[test]
    fn resampling_matches_its_definition() {
        let p = Planes::from_vec(1, 4, 2, vec![0., 1., 2., 3., 4., 5., 6., 7.]);
        assert_eq!(p.avg_pool2().data, [2.5, 4.5]);
        let up = p.up_nearest();
        assert_eq!(&up.data[..8], &[0., 0., 1., 1., 2., 2., 3., 3.]);
        let row = Planes::from_vec(1, 2, 1, vec![0., 4.]).up_bilinear();
        assert_eq!(row.data, [0., 1., 3., 4., 0., 1., 3., 4.]);
    }
}

#[cfg(test)]
mod speed {
    use super::*;

    /// `cargo test --release --lib conv_throughput -- --ignored --nocapture`
    #[test]
    #[ignore = "a measurement, not a test"]
    fn conv_throughput() {
        for (cin, cout, k, w, h) in [
            (27, 16, 3, 1024, 512),
            (16, 16, 3, 1024, 512),
            (48, 32, 3, 512, 256),
            (64, 64, 3, 128, 64),
            (48, 26, 1, 1024, 512),
        ] {
            let x = Planes::from_vec(cin, w, h, vec![0.5; cin * w * h]);
            let wt = vec![0.01f32; cout * cin * k * k];
            let b = vec![0.0f32; cout];
            conv(&x, &wt, &b, k, true);
            let t = std::time::Instant::now();
            let n = 5;
            for _ in 0..n {
                std::hint::black_box(conv(&x, &wt, &b, k, true));
            }
            let s = t.elapsed().as_secs_f64() / n as f64;
            let flop = 2.0 * (cin * cout * k * k * w * h) as f64;
            println!("{cin:>3}→{cout:<3} {k}×{k} {w}×{h}: {:.1} GFLOP/s", flop / s / 1e9);
        }
    }
}
