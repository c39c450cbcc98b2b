//! The weight gradient of a convolution, for training; the input gradient is the forward
//! pass with transposed weights ([`ConvLayer::transposed`](super::ConvLayer::transposed)).

use super::super::simd::Isa;
use super::ConvShape;
use rayon::prelude::*;
use std::borrow::Cow;
use std::ops::Range;

/// `c` planes of `w × h` (`input`) zero-padded by `r` each side, written into `buf`
/// (resized). Channels are copied in parallel, and only the border is zeroed.
fn pad_into(buf: &mut Vec<f32>, input: &[f32], c: usize, w: usize, h: usize, r: usize) {
    let (pw, ph) = (w + 2 * r, h + 2 * r);
    // Every value is written below (border rows and columns, then the interior), so a
    // reused buffer of the right length needs no clearing.
    buf.resize(c * pw * ph, 0.0);
    buf.par_chunks_mut(pw * ph).zip(input.par_chunks(w * h)).for_each(|(dst, src)| {
        dst[..r * pw].fill(0.0);
        dst[(h + r) * pw..].fill(0.0);
        for y in 0..h {
            let row = &mut dst[(y + r) * pw..][..pw];
            row[..r].fill(0.0);
            row[r..r + w].copy_from_slice(&src[y * w..][..w]);
            row[r + w..].fill(0.0);
        }
    });
}

/// The weight gradient of a "same" convolution, `[cout][cin][k][k]`: for each tap, the
/// sum over items and pixels of `grad[co]·input[ci]` shifted by the tap. `input` and
/// `grad` hold `items` consecutive images of `cin` and `cout` planes of `w × h`.
pub fn weight_gradient(input: &[f32], grad: &[f32], shape: ConvShape) -> Vec<f32> {
    weight_gradient_on(Isa::detect(), input, grad, shape)
}

/// [`weight_gradient`] on the given instruction set.
fn weight_gradient_on(isa: Isa, input: &[f32], grad: &[f32], shape: ConvShape) -> Vec<f32> {
    let ConvShape { items, w, h, cin, cout, k } = shape;
    let (r, k2, plane) = (k.saturating_sub(1) / 2, k * k, w * h);
    assert_eq!(input.len(), items * cin * plane, "input of {items} images of {cin}×{h}×{w}");
    assert_eq!(grad.len(), items * cout * plane, "gradient of {items} images of {cout}×{h}×{w}");
    // Every plane is laid out in rows of `pw` floats: the input zero-padded, the gradient
    // with `2r` zero columns. Gradient pixel `p = y·pw + x` then meets padded input
    // `p + ky·pw + kx` for tap (ky, kx), so rows form one flat run and vectors cross row
    // ends: a 24-pixel-wide patch fills 24 of every 26 lanes, not 24 of 32. The zero
    // columns add nothing. A 1×1 convolution uses both planes in place.
    let (pw, ph) = (w + 2 * r, h + 2 * r);
    let (splane, gplane) = (pw * ph, pw * h);
    let src: Cow<[f32]> = if r == 0 {
        Cow::Borrowed(input)
    } else {
        let mut pad = Vec::new();
        pad_into(&mut pad, input, items * cin, w, h, r);
        // The last plane's last taps read `2r` floats past it (times zero gradient).
        pad.resize(pad.len() + 2 * r, 0.0);
        Cow::Owned(pad)
    };
    #[cfg(target_arch = "x86_64")]
    if k == 3 && cout > 16 && isa != Isa::Scalar {
        return by_channel::weight_gradient(isa, &src, grad, shape);
    }
    let g: Cow<[f32]> = if r == 0 {
        Cow::Borrowed(grad)
    } else {
        let mut g = vec![0f32; items * cout * gplane];
        g.par_chunks_mut(pw).zip(grad.par_chunks(w)).for_each(|(d, s)| d[..w].copy_from_slice(s));
        Cow::Owned(g)
    };
    // Register blocks: 3 output channels × 1 input channel × 9 taps for 3×3, 4 × 6 for
    // 1×1 (27 and 24 accumulators: more FMAs per load, which bounds these loops), each
    // summed as 16 lanes kept in memory between runs of pixels, so a run's planes stay in
    // cache while every block uses them. One task per output-channel block
    // owns its values and sums items, runs and lanes in a fixed order, so results do not
    // depend on threads.
    let (mb, nb) = if k == 1 { (4, 6) } else { (3, 1) };
    let (co_blocks, ci_blocks) = (cout.div_ceil(mb), cin.div_ceil(nb));
    let block = mb * nb * k2;
    let per_block = ci_blocks * block;
    let run = (32768 / cin.max(1)).next_multiple_of(16).clamp(16, gplane.max(16));
    // One task per group of output-channel blocks and half of the images: a run of
    // pixels of every input channel is read from memory once per group (the runs of a
    // large 1×1 layer would otherwise stream from memory once per block), and the halves
    // keep both threads busy when there are few groups. Group sizes (from the thread
    // count and ~256 KiB of lanes) change no value's order of summation; each value sums
    // its half's images, runs and lanes in one fixed order, then the halves in order.
    let group = co_blocks.div_ceil(2 * rayon::current_num_threads()).clamp(1, (65536 / (per_block * 16)).max(1));
    let groups = co_blocks.div_ceil(group);
    let halves = items.clamp(1, 2);
    let partial: Vec<Vec<f32>> = (0..groups * halves)
        .into_par_iter()
        .map(|t| {
            let (gr, half) = (t / halves, t % halves);
            let cbs = gr * group..((gr + 1) * group).min(co_blocks);
            let images = half * items / halves..(half + 1) * items / halves;
            let mut lanes = vec![0f32; cbs.len() * per_block * 16];
            for (i, p0) in images.flat_map(|i| (0..gplane).step_by(run).map(move |p0| (i, p0))) {
                let pixels = p0..(p0 + run).min(gplane);
                for (cb, lanes) in cbs.clone().zip(lanes.chunks_mut(per_block * 16)) {
                    let co = cb * mb;
                    let m = (cout - co).min(mb);
                    for (cj, acc) in lanes.chunks_mut(block * 16).enumerate() {
                        let ci = cj * nb;
                        let n = (cin - ci).min(nb);
                        let t = Taps {
                            src: &src[(i * cin + ci) * splane..],
                            grad: &g[(i * cout + co) * gplane..][..m * gplane],
                            splane,
                            gplane,
                            pw,
                        };
                        // The block shapes the vector kernels are built for; others go scalar.
                        #[allow(unused_macros)] // unused off x86-64
                        macro_rules! blocks {
                            ($sum:ident) => {
                                match (m, n, k) {
                                    (1..=3, 1, 3) => {
                                        with_const!(m, M => t.$sum::<M, 1, 3>(pixels.clone(), nb, acc), [3 2] else 1)
                                    }
                                    (1..=4, 1..=6, 1) => with_const!(m, M => with_const!(n, N =>
                                        t.$sum::<M, N, 1>(pixels.clone(), nb, acc), [6 5 4 3 2] else 1), [4 3 2] else 1),
                                    _ => t.sum_scalar(m, n, k, nb, pixels.clone(), acc),
                                }
                            };
                        }
                        #[cfg(target_arch = "x86_64")]
                        match isa {
                            // SAFETY: AVX-512F is available (detected).
                            Isa::Avx512 => unsafe { blocks!(sum_avx512) },
                            // SAFETY: AVX2 and FMA are available (detected).
                            Isa::Avx2 => unsafe { blocks!(sum_avx2) },
                            Isa::Scalar => t.sum_scalar(m, n, k, nb, pixels.clone(), acc),
                        }
                        #[cfg(not(target_arch = "x86_64"))]
                        t.sum_scalar(m, n, k, nb, pixels.clone(), acc);
                    }
                }
            }
            lanes
        })
        .collect();
    let blocks: Vec<f32> = partial
        .chunks(halves)
        .flat_map(|halves| {
            let mut lanes = halves[0].clone();
            for other in &halves[1..] {
                lanes.iter_mut().zip(other).for_each(|(a, b)| *a += b);
            }
            lanes
                .chunks_exact(16)
                .map(|lane| {
                    // A pairwise tree, which vectorises (a running sum is a 16-add
                    // latency chain per value, a fifth of the whole on narrow layers).
                    let mut v: [f32; 16] = lane.try_into().expect("16 lanes");
                    for half in [8, 4, 2, 1] {
                        for i in 0..half {
                            v[i] += v[i + half];
                        }
                    }
                    v[0]
                })
                .collect::<Vec<f32>>()
        })
        .collect();
    // Blocks are [co block][ci block][mb][nb][k²]; the result is [cout][cin][k²].
    let mut out = vec![0f32; cout * cin * k2];
    for co in 0..cout {
        for ci in 0..cin {
            let block = (co / mb) * ci_blocks + ci / nb;
            let from = ((block * mb + co % mb) * nb + ci % nb) * k2;
            out[(co * cin + ci) * k2..][..k2].copy_from_slice(&blocks[from..from + k2]);
        }
    }
    out
}

/// One weight-gradient task's planes, laid out as in `weight_gradient_on`: input
/// channels from `src`'s start, `splane` floats apart, and `m` output channels'
/// gradients, `gplane` floats apart.
struct Taps<'a> {
    src: &'a [f32],
    grad: &'a [f32],
    splane: usize,
    gplane: usize,
    pw: usize,
}

/// Defines a vector [`Taps`] kernel: the sums of [`Taps::sum_scalar`] for `M` gradients,
/// `N ≤ nb` input channels and `K × K` taps, `$lanes` pixels at a time into the first
/// `$lanes` of 16 lanes. One body for every instruction set; what differs is passed in:
/// the vector type's zero, the mask of the `left` pixels still to go, a masked load, a
/// fused multiply-add, and the accumulators' load and store.
macro_rules! taps_kernel {
    (
        $(#[$attr:meta])* $name:ident, $lanes:literal, $zero:expr,
        mask |$left:ident| $mask:expr,
        load |$ptr:ident, $m:ident| $load:expr,
        $fma:path,
        get |$q:ident| $get:expr,
        put |$d:ident, $v:ident| $put:expr $(,)?
    ) => {
        $(#[$attr])*
        #[allow(clippy::needless_range_loop)] // indices name the accumulator block's axes
        unsafe fn $name<const M: usize, const N: usize, const K: usize>(
            &self,
            pixels: Range<usize>,
            nb: usize,
            out: &mut [f32],
        ) {
            use std::arch::x86_64::*;
            assert!(self.fits(M, N, K, &pixels, nb, out.len()), "a weight-gradient block outside its planes");
            let at = |j: usize, c: usize, ky: usize, kx: usize| (((j * nb + c) * K + ky) * K + kx) * 16;
            let (pw, sp, gp) = (self.pw, self.splane, self.gplane);
            // SAFETY: masked lanes are not read; the rest stay inside the slices (checked).
            unsafe {
                let mut acc = [[[[$zero; K]; K]; N]; M];
                for j in 0..M {
                    for c in 0..N {
                        for ky in 0..K {
                            for kx in 0..K {
                                let $q = out.as_ptr().add(at(j, c, ky, kx));
                                acc[j][c][ky][kx] = $get;
                            }
                        }
                    }
                }
                for p in pixels.clone().step_by($lanes) {
                    let $left = pixels.end - p;
                    let $m = $mask;
                    let mut g = [$zero; M];
                    for (j, gv) in g.iter_mut().enumerate() {
                        let $ptr = self.grad.as_ptr().add(j * gp + p);
                        *gv = $load;
                    }
                    for c in 0..N {
                        for ky in 0..K {
                            let row = self.src.as_ptr().add(c * sp + ky * pw + p);
                            for kx in 0..K {
                                let $ptr = row.add(kx);
                                let v = $load;
                                for j in 0..M {
                                    acc[j][c][ky][kx] = $fma(g[j], v, acc[j][c][ky][kx]);
                                }
                            }
                        }
                    }
                }
                for j in 0..M {
                    for c in 0..N {
                        for ky in 0..K {
                            for kx in 0..K {
                                let ($d, $v) = (out.as_mut_ptr().add(at(j, c, ky, kx)), acc[j][c][ky][kx]);
                                $put;
                            }
                        }
                    }
                }
            }
        }
    };
}

impl Taps<'_> {
    /// Whether a block of `m` gradients × `n` input channels × `k²` taps over `pixels`
    /// stays inside the planes and an accumulator slice of `out` floats (lanes laid out
    /// for `nb`).
    fn fits(&self, m: usize, n: usize, k: usize, pixels: &Range<usize>, nb: usize, out: usize) -> bool {
        pixels.end <= self.gplane
            && self.grad.len() >= m * self.gplane
            && self.src.len() >= (n.max(1) - 1) * self.splane + pixels.end + (k - 1) * (self.pw + 1)
            && n <= nb
            && out >= m * nb * k * k * 16
    }

    /// Adds `Σ grad[j][p]·src[c][p + ky·pw + kx]` over `pixels` at each of the `k²` taps
    /// to lane 0 of `acc[((j·nb + c)·k² + tap)·16..]`.
    #[allow(clippy::too_many_arguments)]
    fn sum_scalar(&self, m: usize, n: usize, k: usize, nb: usize, pixels: Range<usize>, acc: &mut [f32]) {
        for j in 0..m {
            let g = &self.grad[j * self.gplane..][pixels.clone()];
            for c in 0..n {
                for ky in 0..k {
                    for kx in 0..k {
                        let src = &self.src[c * self.splane + ky * self.pw + kx..][pixels.clone()];
                        let s = g.iter().zip(src).map(|(a, b)| a * b).sum::<f32>();
                        acc[(((j * nb + c) * k + ky) * k + kx) * 16] += s;
                    }
                }
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    taps_kernel! {
        /// [`Taps::sum_scalar`] with AVX-512, 16 pixels at a time.
        ///
        /// # Safety
        /// AVX-512F is available.
        #[target_feature(enable = "avx512f")]
        sum_avx512, 16, _mm512_setzero_ps(),
        mask |left| crate::kernel::simd::mask16(left),
        load |ptr, mask| _mm512_maskz_loadu_ps(mask, ptr),
        _mm512_fmadd_ps,
        get |q| _mm512_loadu_ps(q),
        put |d, v| _mm512_storeu_ps(d, v),
    }

    #[cfg(target_arch = "x86_64")]
    taps_kernel! {
        /// [`Taps::sum_scalar`] with AVX2, 8 pixels at a time.
        ///
        /// # Safety
        /// AVX2 and FMA are available.
        #[target_feature(enable = "avx2,fma")]
        sum_avx2, 8, _mm256_setzero_ps(),
        mask |left| _mm256_cmpgt_epi32(_mm256_set1_epi32(left.min(8) as i32), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7)),
        load |ptr, mask| _mm256_maskload_ps(ptr, mask),
        _mm256_fmadd_ps,
        get |q| _mm256_loadu_ps(q),
        put |d, v| _mm256_storeu_ps(d, v),
    }
}

/// The weight gradient of 3×3 layers with more than 16 output channels, with the output
/// channels in the vector lanes: the gradient is transposed to channels-last once, and
/// each pixel then costs one aligned load per 16 output channels and one broadcast per
/// tap, against 27 fused multiply-adds (the pixel-vector kernels of [`Taps`] load every
/// tap's shifted row, mostly across cache lines). No lane is wasted at row ends, and each
/// value is one lane summed over images and pixels in order.
#[cfg(target_arch = "x86_64")]
mod by_channel {
    use crate::kernel::conv::ConvShape;
    use crate::kernel::simd::Isa;
    use rayon::prelude::*;

    /// `src`: `items·cin` zero-padded planes (`(w + 2) × (h + 2)`); `grad`: `items·cout`
    /// planes of `w × h`. Returns `[cout][cin][3][3]`.
    pub(super) fn weight_gradient(isa: Isa, src: &[f32], grad: &[f32], shape: ConvShape) -> Vec<f32> {
        let ConvShape { items, w, h, cin, cout, .. } = shape;
        let lanes = if isa == Isa::Avx512 { 16 } else { 8 };
        let (plane, pw, splane, cp) = (w * h, w + 2, (w + 2) * (h + 2), cout.next_multiple_of(lanes));
        // The channels-last gradient `[item][pixel][cp]`, 64-byte aligned so that no load
        // crosses a cache line.
        let mut store = vec![0f32; items * plane * cp + 16];
        let skip = store.as_ptr().align_offset(64).min(16);
        let gt = &mut store[skip..skip + items * plane * cp];
        gt.par_chunks_mut(plane * cp).enumerate().for_each(|(i, dst)| {
            for co in 0..cout {
                for (p, &v) in grad[(i * cout + co) * plane..][..plane].iter().enumerate() {
                    dst[p * cp + co] = v;
                }
            }
        });
        let gt = &*gt;
        // Blocks of up to 3 vectors of output channels (27 accumulators).
        let vecs = cp / lanes;
        let mv = if vecs % 3 == 0 || vecs > 4 { 3 } else { vecs.min(2) };
        let blocks: Vec<(usize, usize)> = (0..vecs).step_by(mv).map(|v| (v, (vecs - v).min(mv))).collect();
        // Tasks: a block × a group of input channels; rows go in runs of ~256 pixels, so
        // a run's gradient stays in L1 while each channel of the group uses it.
        let group = 4;
        let run = (256 / w.max(1)).max(1);
        let ci_groups = cin.div_ceil(group);
        let sums: Vec<Vec<f32>> = (0..blocks.len() * ci_groups)
            .into_par_iter()
            .map(|t| {
                let ((v0, m), c0) = (blocks[t / ci_groups], t % ci_groups * group);
                let channels = c0..(c0 + group).min(cin);
                let mut acc = vec![0f32; channels.len() * 3 * 9 * lanes];
                for i in 0..items {
                    for y0 in (0..h).step_by(run) {
                        let rows = y0..(y0 + run).min(h);
                        for (ci, acc) in channels.clone().zip(acc.chunks_mut(3 * 9 * lanes)) {
                            let job = Job {
                                gt: gt[i * plane * cp + v0 * lanes..].as_ptr(),
                                cp,
                                src: &src[(i * cin + ci) * splane..][..splane],
                                w,
                                pw,
                                rows: rows.clone(),
                            };
                            // SAFETY: the instructions are available (detected); `job`'s
                            // pointers cover `m` vectors of every pixel of the rows.
                            unsafe {
                                match isa {
                                    Isa::Avx512 => with_const!(m, M => job.sum_avx512::<M>(acc), [3 2] else 1),
                                    _ => with_const!(m, M => job.sum_avx2::<M>(acc), [3 2] else 1),
                                }
                            }
                        }
                    }
                }
                acc
            })
            .collect();
        let mut out = vec![0f32; cout * cin * 9];
        for (t, acc) in sums.iter().enumerate() {
            let ((v0, m), c0) = (blocks[t / ci_groups], t % ci_groups * group);
            for (n, acc) in acc.chunks(3 * 9 * lanes).enumerate() {
                let ci = c0 + n;
                for v in 0..m {
                    for tap in 0..9 {
                        for l in 0..lanes {
                            let co = (v0 + v) * lanes + l;
                            if co < cout && ci < cin {
                                out[(co * cin + ci) * 9 + tap] = acc[(v * 9 + tap) * lanes + l];
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// One call's operands: the channels-last gradient at pixel 0 of the block's first
    /// vector, one input channel's padded plane, and the rows to sum.
    struct Job<'a> {
        gt: *const f32,
        cp: usize,
        src: &'a [f32],
        w: usize,
        pw: usize,
        rows: std::ops::Range<usize>,
    }

    /// Defines a kernel adding, for `M` vectors of output channels and the 9 taps,
    /// `Σ gt[p][co]·src[p + tap]` over the job's rows to `acc[(v·9 + tap)·lanes + l]`.
    macro_rules! by_channel_kernel {
        ($(#[$attr:meta])* $name:ident, $lanes:literal, $load:ident, $store:ident, $set1:ident, $fma:ident) => {
            $(#[$attr])*
            #[allow(clippy::needless_range_loop)] // indices name the accumulator block's axes
            unsafe fn $name<const M: usize>(&self, acc: &mut [f32]) {
                use std::arch::x86_64::*;
                let (w, pw, cp) = (self.w, self.pw, self.cp);
                assert!(acc.len() >= M * 9 * $lanes && (self.rows.end + 1) * pw + w + 1 < self.src.len());
                // SAFETY: the gradient holds M vectors at every pixel of the rows (caller);
                // the largest source index is (rows.end + 1)·pw + w + 1 (checked).
                unsafe {
                    let mut a = [[$set1(0.0); 9]; M];
                    for v in 0..M {
                        for t in 0..9 {
                            a[v][t] = $load(acc.as_ptr().add((v * 9 + t) * $lanes));
                        }
                    }
                    let src = self.src.as_ptr();
                    for y in self.rows.clone() {
                        let g_row = self.gt.add(y * w * cp);
                        let s_row = src.add(y * pw);
                        for x in 0..w {
                            let mut g = [$set1(0.0); M];
                            for v in 0..M {
                                g[v] = $load(g_row.add(x * cp + v * $lanes));
                            }
                            for ky in 0..3 {
                                for kx in 0..3 {
                                    let s = $set1(*s_row.add(ky * pw + x + kx));
                                    for v in 0..M {
                                        a[v][ky * 3 + kx] = $fma(g[v], s, a[v][ky * 3 + kx]);
                                    }
                                }
                            }
                        }
                    }
                    for v in 0..M {
                        for t in 0..9 {
                            $store(acc.as_mut_ptr().add((v * 9 + t) * $lanes), a[v][t]);
                        }
                    }
                }
            }
        };
    }

    impl Job<'_> {
        by_channel_kernel! {
            /// 16 output channels per vector.
            ///
            /// # Safety
            /// AVX-512F is available.
            #[target_feature(enable = "avx512f")]
            sum_avx512, 16, _mm512_loadu_ps, _mm512_storeu_ps, _mm512_set1_ps, _mm512_fmadd_ps
        }

        by_channel_kernel! {
            /// 8 output channels per vector.
            ///
            /// # Safety
            /// AVX2 and FMA are available.
            #[target_feature(enable = "avx2,fma")]
            sum_avx2, 8, _mm256_loadu_ps, _mm256_storeu_ps, _mm256_set1_ps, _mm256_fmadd_ps
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::conv::{ConvLayer, conv_batch};
    use crate::rng::SplitMix64;
    use candle_core::{Device, Tensor};

    #[test]
    fn gradients_match_candle() {
        use candle_core::Var;
        // 3×3 and 1×1, channel counts around the register blocks.
        // More than 16 outputs take the channel-vector path (3 and 2 vectors with AVX-512).
        for (cin, cout, k, w, h) in
            [(5, 7, 3, 19, 6), (9, 6, 1, 21, 5), (3, 2, 3, 33, 2), (5, 37, 3, 19, 6), (6, 20, 3, 9, 7)]
        {
            let x = SplitMix64(11).centred(2 * cin * w * h);
            let wt = SplitMix64(12).centred(cout * cin * k * k);
            let g = SplitMix64(13).centred(2 * cout * w * h);
            // Candle's autograd: loss = Σ conv(x)·g.
            let xv = Var::from_vec(x.clone(), (2, cin, h, w), &Device::Cpu).unwrap();
            let wv = Var::from_vec(wt.clone(), (cout, cin, k, k), &Device::Cpu).unwrap();
            let gt = Tensor::from_vec(g.clone(), (2, cout, h, w), &Device::Cpu).unwrap();
            let y = xv.as_tensor().conv2d(wv.as_tensor(), (k - 1) / 2, 1, 1, 1).unwrap();
            let grads = (y * gt).unwrap().sum_all().unwrap().backward().unwrap();
            let dx = grads.get(xv.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let dw = grads.get(wv.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();

            let back = ConvLayer::transposed(&wt, cout, cin, k);
            let ours_dx = conv_batch(&g, 2, w, h, &back, false);
            let shape = ConvShape { items: 2, w, h, cin, cout, k };
            let ours_dw = weight_gradient(&x, &g, shape);
            let mut checks = vec![("input", ours_dx, &dx), ("weight", ours_dw, &dw)];
            let scalar = weight_gradient_on(Isa::Scalar, &x, &g, shape);
            checks.push(("weight (scalar)", scalar, &dw));
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                checks.push(("weight (AVX2)", weight_gradient_on(Isa::Avx2, &x, &g, shape), &dw));
            }
            for (name, a, b) in checks {
                assert_eq!(a.len(), b.len());
                for (i, (a, b)) in a.iter().zip(b.iter()).enumerate() {
                    assert!(
                        (a - b).abs() < 1e-4 * (1.0 + b.abs()),
                        "{cin}→{cout} k{k} {name} gradient {i}: {a} vs {b}"
                    );
                }
            }
        }
    }
}
