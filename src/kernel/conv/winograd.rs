//! 3×3 convolutions of even-width planes by Winograd's minimal filtering F(2, 3) along
//! rows: two neighbouring outputs of a kernel row take 4 multiplies instead of 6, so a
//! 3×3 layer does 6 multiply-adds per input channel and output pixel rather than 9.
//!
//! Each padded input row `d` is transformed once per column pair `t` (`d0..d3 =
//! d[2t..2t + 4]`): `v0 = d0 − d2`, `v1 = d1 + d2`, `v2 = d2 − d1`, `v3 = d1 − d3`; each kernel
//! row `g` once per layer: `u0 = g0`, `u1 = (g0 + g1 + g2)/2`, `u2 = (g0 − g1 + g2)/2`,
//! `u3 = g2`. Then `m_q = Σ_(ci, ky) u_q·v_q` (one fused multiply-add per term, from zero, in
//! the order input channel, kernel row) and the pair is `bias + m0 + m1 + m2` and `bias +
//! m1 − m2 − m3`, summed in that order. Every path (AVX-512, AVX2, scalar) does exactly
//! these operations, so all give the same bits, and a pixel's value depends only on its
//! column pair, never on the rows or tiles around it. Each output's sums read only its
//! own 3×3 window's inputs (`m3` never enters the first of a pair, `m0` never the
//! second), so a value depends on exactly what the direct sum reads: regions whose halo
//! is the network's receptive radius still give the whole frame's bits. (F(4, 3), with
//! half the multiply-adds, mixes up to three more columns into each output's rounding,
//! which such halos do not cover.) The formulas are written once, for one lane's values
//! of any path (`transform_pair`, `pair_outputs`). The transformed rows of a task lie flat
//! (`rows × w/2` pairs per channel and term), so the three kernel rows are three offsets
//! in one array and segments run across row ends with no padding columns.

use super::{ConvLayer, MR};
use crate::kernel::simd::{Isa, mask16};

/// Winograd's terms per column pair.
const TERMS: usize = 4;

/// Input channels from which the transform pays: its terms are twice the input's
/// floats, and with fewer channels the traffic outweighs the multiply-adds saved
/// (16→16 and 27→16 at 1280×720 ran 10–15 % slower, 32→32 and up 7–40 % faster;
/// BENCHMARKS.md).
pub(super) const MIN_CHANNELS: usize = 32;

/// Packs a 3×3 `weight` `[cout][cin][3][3]` for [`rows`]: `ceil(cout / MR)` panels of
/// `[TERMS][cin][3][MR]` transformed kernel rows.
pub(super) fn pack(weight: &[f32], cout: usize, cin: usize) -> Vec<f32> {
    let blocks = cout.div_ceil(MR);
    let mut packed = vec![0f32; blocks * TERMS * cin * 3 * MR];
    for co in 0..cout {
        let (b, j) = (co / MR, co % MR);
        for ci in 0..cin {
            for ky in 0..3 {
                let g = &weight[((co * cin + ci) * 3 + ky) * 3..][..3];
                let u = [g[0], (g[0] + g[1] + g[2]) * 0.5, (g[0] - g[1] + g[2]) * 0.5, g[2]];
                for (q, u) in u.into_iter().enumerate() {
                    packed[(((b * TERMS + q) * cin + ci) * 3 + ky) * MR + j] = u;
                }
            }
        }
    }
    packed
}

/// Whether [`rows`] computes `layer` on planes `w` wide.
pub(super) fn applies(layer: &ConvLayer, w: usize) -> bool {
    !layer.winograd.is_empty() && w.is_multiple_of(2)
}

/// A task's rows: input planes zero-padded by one pixel, `pw = w + 2` wide, `plane`
/// floats apart, from the first input row of the first output row; outputs `out_plane`
/// floats apart from the first output row of channel 0.
pub(super) struct Rows<'a> {
    pub src: &'a [f32],
    pub plane: usize,
    pub w: usize,
    pub rows: usize,
    pub out: *mut f32,
    pub out_plane: usize,
    pub relu: bool,
}

/// Up to 16 consecutive flat pairs (running on across row ends): the first pair's
/// transformed values at `f` in a term's rows, its outputs at `2f` in an output plane.
#[derive(Clone, Copy)]
struct Segment {
    f: usize,
    /// Pairs in the segment.
    pairs: usize,
}

/// `layer` ([`applies`]) on `task`'s rows; `scratch` holds the transformed input.
///
/// # Safety
/// `task.out` is valid for `rows × w` floats of each of `cout` channels `out_plane`
/// apart, written by this thread only; `task.src` holds `rows + 2` padded rows of each
/// of `cin` planes.
pub(super) unsafe fn rows(layer: &ConvLayer, task: &Rows, isa: Isa, scratch: &mut Vec<f32>) {
    let (tw, rows, w) = (task.w / 2, task.rows, task.w);
    // Per channel and term: rows + 2 transformed rows, then 16 floats that masked reads
    // may touch. Every value read is written first, so a reused buffer needs no clearing.
    let stride = (rows + 2) * tw + 16;
    if scratch.len() < layer.cin * TERMS * stride {
        scratch.resize(layer.cin * TERMS * stride, 0.0);
    }
    for ci in 0..layer.cin {
        for j in 0..rows + 2 {
            let d = &task.src[ci * task.plane + j * (w + 2)..][..w + 2];
            let v = &mut scratch[ci * TERMS * stride + j * tw..];
            #[cfg(target_arch = "x86_64")]
            if isa == Isa::Avx512 {
                // SAFETY: AVX-512F detected; `d` holds the w + 2 values read, and `v` the
                // four strided rows of tw values written.
                unsafe { transform_avx512(d, v.as_mut_ptr(), stride, tw) };
                continue;
            }
            transform(d, v, stride, tw);
        }
    }
    let n = rows * tw;
    let segments: Vec<Segment> = (0..n).step_by(16).map(|f| Segment { f, pairs: (n - f).min(16) }).collect();
    let v = Transformed { v: scratch, stride, row: tw };
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the caller's contract; the instructions exist.
        Isa::Avx512 => return unsafe { gemm_avx512(layer, task, &v, &segments) },
        // SAFETY: as above.
        Isa::Avx2 => return unsafe { gemm_avx2(layer, task, &v, &segments) },
        Isa::Scalar => {}
    }
    for seg in &segments {
        segment_scalar(layer, task, &v, seg, 0..seg.pairs);
    }
}

/// A task's transformed input: term `q` of channel `ci` at `(ci·TERMS + q)·stride`,
/// rows `row` pairs apart.
struct Transformed<'a> {
    v: &'a [f32],
    stride: usize,
    row: usize,
}

/// Pairs `ps` of `seg`, one at a time.
#[inline(always)]
fn segment_scalar(layer: &ConvLayer, task: &Rows, v: &Transformed, seg: &Segment, ps: std::ops::Range<usize>) {
    for p in ps {
        for co in 0..layer.cout {
            let m = terms(layer, v, co, seg.f + p);
            let (e, o) = pair(m, layer.bias[co], task.relu);
            // SAFETY: inside the task's output (the caller's contract of [`rows`]).
            unsafe {
                *task.out.add(co * task.out_plane + 2 * (seg.f + p)) = e;
                *task.out.add(co * task.out_plane + 2 * (seg.f + p) + 1) = o;
            }
        }
    }
}

/// The operations every path does, on one lane's values: `f32` here, the AVX-512 and
/// AVX2 registers in `x86`, so each formula below is written once for all of them.
trait Lane: Copy {
    fn add(self, b: Self) -> Self;
    fn sub(self, b: Self) -> Self;
}

impl Lane for f32 {
    #[inline(always)]
    fn add(self, b: f32) -> f32 {
        self + b
    }
    #[inline(always)]
    fn sub(self, b: f32) -> f32 {
        self - b
    }
}

/// A pair's four terms from its four padded inputs.
#[inline(always)]
fn transform_pair<T: Lane>([d0, d1, d2, d3]: [T; 4]) -> [T; TERMS] {
    [d0.sub(d2), d1.add(d2), d2.sub(d1), d1.sub(d3)]
}

/// A pair's two outputs from its four sums (before the ReLU): the first never reads `m3`,
/// the second never `m0`.
#[inline(always)]
fn pair_outputs<T: Lane>([m0, m1, m2, m3]: [T; TERMS], bias: T) -> [T; 2] {
    [bias.add(m0).add(m1).add(m2), bias.add(m1).sub(m2).sub(m3)]
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::Lane;
    use std::arch::x86_64::*;

    /// An AVX-512 register of 16 lanes.
    #[derive(Clone, Copy)]
    pub(super) struct Z(pub __m512);

    impl Lane for Z {
        #[inline(always)]
        fn add(self, b: Z) -> Z {
            // SAFETY: values of this type exist only where AVX-512F was detected.
            Z(unsafe { _mm512_add_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn sub(self, b: Z) -> Z {
            // SAFETY: as above.
            Z(unsafe { _mm512_sub_ps(self.0, b.0) })
        }
    }

    /// An AVX register of 8 lanes.
    #[derive(Clone, Copy)]
    pub(super) struct Y(pub __m256);

    impl Lane for Y {
        #[inline(always)]
        fn add(self, b: Y) -> Y {
            // SAFETY: values of this type exist only where AVX2 was detected.
            Y(unsafe { _mm256_add_ps(self.0, b.0) })
        }
        #[inline(always)]
        fn sub(self, b: Y) -> Y {
            // SAFETY: as above.
            Y(unsafe { _mm256_sub_ps(self.0, b.0) })
        }
    }
}

/// One padded row's transform into `v` (term `q` at `q·stride`).
#[inline]
fn transform(d: &[f32], v: &mut [f32], stride: usize, tw: usize) {
    for t in 0..tw {
        let x = transform_pair([d[2 * t], d[2 * t + 1], d[2 * t + 2], d[2 * t + 3]]);
        for (q, x) in x.into_iter().enumerate() {
            v[q * stride + t] = x;
        }
    }
}

/// The four sums of output channel `co` at flat pair `f` (a plain loop, always
/// inlined, so the AVX2 path's tails get FMA instructions).
#[inline(always)]
fn terms(layer: &ConvLayer, v: &Transformed, co: usize, f: usize) -> [f32; TERMS] {
    let (b, j, cin) = (co / MR, co % MR, layer.cin);
    let mut m = [0f32; TERMS];
    for (q, acc) in m.iter_mut().enumerate() {
        let panel = &layer.winograd[(b * TERMS + q) * cin * 3 * MR..];
        for ci in 0..cin {
            for ky in 0..3 {
                let x = v.v[(ci * TERMS + q) * v.stride + f + ky * v.row];
                *acc = x.mul_add(panel[(ci * 3 + ky) * MR + j], *acc);
            }
        }
    }
    m
}

/// [`pair_outputs`] of one lane, with the ReLU.
#[inline(always)]
fn pair(m: [f32; TERMS], bias: f32, relu: bool) -> (f32, f32) {
    let [e, o] = pair_outputs(m, bias).map(|y| if relu { y.max(0.0) } else { y });
    (e, o)
}

/// [`transform`] with AVX-512, 16 pairs at a time.
///
/// # Safety
/// AVX-512F is available; `d` holds `2·tw + 2` values; `v` is valid for writes of `tw`
/// values at each of `0, stride, 2·stride, 3·stride`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn transform_avx512(d: &[f32], v: *mut f32, stride: usize, tw: usize) {
    use std::arch::x86_64::*;
    let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
    let odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
    let len = d.len();
    // SAFETY: loads are masked to `d`, stores to the tw values of each term.
    unsafe {
        let load = |at: usize| _mm512_maskz_loadu_ps(mask16(len.saturating_sub(at)), d.as_ptr().add(at.min(len)));
        for t in (0..tw).step_by(16) {
            let (a, b) = (load(2 * t), load(2 * t + 16));
            let (c, e) = (load(2 * t + 2), load(2 * t + 18));
            let (d0, d1) = (_mm512_permutex2var_ps(a, even, b), _mm512_permutex2var_ps(a, odd, b));
            let (d2, d3) = (_mm512_permutex2var_ps(c, even, e), _mm512_permutex2var_ps(c, odd, e));
            let m = mask16(tw - t);
            for (q, x) in transform_pair([d0, d1, d2, d3].map(x86::Z)).into_iter().enumerate() {
                _mm512_mask_storeu_ps(v.add(q * stride + t), m, x.0);
            }
        }
    }
}

/// Segments per AVX-512 block.
#[cfg(target_arch = "x86_64")]
const NV: usize = 3;

/// Every segment with AVX-512: blocks of `MR` output channels × [`NV`] segments.
///
/// # Safety
/// AVX-512F is available; [`rows`]' contract.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn gemm_avx512(layer: &ConvLayer, task: &Rows, v: &Transformed, segments: &[Segment]) {
    for group in segments.chunks(NV) {
        // A short last group repeats its first segment with no pairs.
        let group: [Segment; NV] =
            std::array::from_fn(|i| group.get(i).copied().unwrap_or(Segment { pairs: 0, ..group[0] }));
        for b in 0..layer.cout.div_ceil(MR) {
            let m = (layer.cout - b * MR).min(MR);
            // SAFETY: the caller's contract.
            unsafe { with_const!(m, M => block_avx512::<M>(layer, task, v, &group, b), [8 7 6 5 4 3 2] else 1) };
        }
    }
}

/// `M` output channels of panel `b` at `group`'s pairs.
///
/// # Safety
/// As [`gemm_avx512`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn block_avx512<const M: usize>(
    layer: &ConvLayer,
    task: &Rows,
    v: &Transformed,
    group: &[Segment; NV],
    b: usize,
) {
    use std::arch::x86_64::*;
    let cin = layer.cin;
    // SAFETY: masked loads stay in the transformed rows (each term's rows end with 16
    // spare floats), masked stores in the task's output; pointers to masked-off lanes
    // are only formed (`wrapping_add`), never read.
    unsafe {
        // Per output channel and segment, the four terms' sums.
        let mut sums = [[[_mm512_setzero_ps(); TERMS]; NV]; M];
        for q in 0..TERMS {
            let mut acc = [[_mm512_setzero_ps(); NV]; M];
            let mut wp = layer.winograd.as_ptr().add((b * TERMS + q) * cin * 3 * MR);
            for ci in 0..cin {
                let rows = v.v.as_ptr().wrapping_add((ci * TERMS + q) * v.stride);
                for ky in 0..3 {
                    let mut x = [_mm512_setzero_ps(); NV];
                    for (i, xi) in x.iter_mut().enumerate() {
                        let at = rows.wrapping_add(group[i].f + ky * v.row);
                        *xi = _mm512_maskz_loadu_ps(mask16(group[i].pairs), at);
                    }
                    for (j, accj) in acc.iter_mut().enumerate() {
                        let wv = _mm512_set1_ps(*wp.add(j));
                        for i in 0..NV {
                            accj[i] = _mm512_fmadd_ps(x[i], wv, accj[i]);
                        }
                    }
                    wp = wp.add(MR);
                }
            }
            for (sj, accj) in sums.iter_mut().zip(&acc) {
                for (s, a) in sj.iter_mut().zip(accj) {
                    s[q] = *a;
                }
            }
        }
        let lo = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
        let hi = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
        let zero = _mm512_setzero_ps();
        for (j, sj) in sums.iter().enumerate() {
            let bias = _mm512_set1_ps(layer.bias[b * MR + j]);
            let dst = task.out.wrapping_add((b * MR + j) * task.out_plane);
            for (m, seg) in sj.iter().zip(group) {
                let [e, o] = pair_outputs(m.map(x86::Z), x86::Z(bias))
                    .map(|y| if task.relu { _mm512_max_ps(y.0, zero) } else { y.0 });
                let (at, n) = (dst.wrapping_add(2 * seg.f), 2 * seg.pairs);
                _mm512_mask_storeu_ps(at, mask16(n), _mm512_permutex2var_ps(e, lo, o));
                _mm512_mask_storeu_ps(
                    at.wrapping_add(16),
                    mask16(n.saturating_sub(16)),
                    _mm512_permutex2var_ps(e, hi, o),
                );
            }
        }
    }
}

/// Output channels per AVX2 block.
#[cfg(target_arch = "x86_64")]
const M_AVX2: usize = 4;

/// Every segment with AVX2: its pairs by 16 and then by 8 ([`block_avx2`]), the last
/// ones short of 8 the scalar way.
///
/// # Safety
/// AVX2 and FMA are available; [`rows`]' contract.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn gemm_avx2(layer: &ConvLayer, task: &Rows, v: &Transformed, segments: &[Segment]) {
    for seg in segments {
        let whole = seg.pairs / 8 * 8;
        for c0 in (0..layer.cout).step_by(M_AVX2) {
            let mut p = 0;
            // SAFETY: the caller's contract; whole runs of 8 pairs lie in the segment.
            unsafe {
                while p + 16 <= whole {
                    block_avx2::<2>(layer, task, v, seg.f + p, c0);
                    p += 16;
                }
                if p < whole {
                    block_avx2::<1>(layer, task, v, seg.f + p, c0);
                }
            }
        }
        // Inlined here, its multiply-adds are FMA instructions, not calls to `fmaf`.
        segment_scalar(layer, task, v, seg, whole..seg.pairs);
    }
}

/// Output channels `c0..` (up to [`M_AVX2`]) × `NV` runs of 8 flat pairs from `f`,
/// whose outputs start at `2f` in each plane: `M_AVX2·NV` accumulators.
///
/// # Safety
/// As [`gemm_avx2`], and the `8·NV` pairs from `f` lie in the task.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_avx2<const NV: usize>(layer: &ConvLayer, task: &Rows, v: &Transformed, f: usize, c0: usize) {
    use std::arch::x86_64::*;
    let (cin, m) = (layer.cin, (layer.cout - c0).min(M_AVX2));
    let (b, j0) = (c0 / MR, c0 % MR);
    // SAFETY: unmasked loads of whole runs of 8 pairs stay in the transformed rows;
    // stores in the task's output.
    unsafe {
        // Per output channel and run, the four terms' sums.
        let mut sums = [[[_mm256_setzero_ps(); TERMS]; NV]; M_AVX2];
        for q in 0..TERMS {
            let mut acc = [[_mm256_setzero_ps(); NV]; M_AVX2];
            let mut wp = layer.winograd.as_ptr().add((b * TERMS + q) * cin * 3 * MR + j0);
            for ci in 0..cin {
                let rows = v.v.as_ptr().add((ci * TERMS + q) * v.stride + f);
                for ky in 0..3 {
                    let x: [__m256; NV] = std::array::from_fn(|i| _mm256_loadu_ps(rows.add(8 * i + ky * v.row)));
                    for (j, accj) in acc.iter_mut().enumerate() {
                        let wv = _mm256_broadcast_ss(&*wp.add(j));
                        for i in 0..NV {
                            accj[i] = _mm256_fmadd_ps(x[i], wv, accj[i]);
                        }
                    }
                    wp = wp.add(MR);
                }
            }
            for (sj, accj) in sums.iter_mut().zip(&acc) {
                for (s, a) in sj.iter_mut().zip(accj) {
                    s[q] = *a;
                }
            }
        }
        let zero = _mm256_setzero_ps();
        for (j, sj) in sums.iter().enumerate().take(m) {
            let bias = _mm256_set1_ps(layer.bias[c0 + j]);
            let dst = task.out.add((c0 + j) * task.out_plane + 2 * f);
            for (i, m) in sj.iter().enumerate() {
                let [e, o] = pair_outputs(m.map(x86::Y), x86::Y(bias))
                    .map(|y| if task.relu { _mm256_max_ps(y.0, zero) } else { y.0 });
                // Interleave within 128-bit lanes, then put the lanes in order.
                let (l, h) = (_mm256_unpacklo_ps(e, o), _mm256_unpackhi_ps(e, o));
                _mm256_storeu_ps(dst.add(16 * i), _mm256_permute2f128_ps(l, h, 0x20));
                _mm256_storeu_ps(dst.add(16 * i + 8), _mm256_permute2f128_ps(l, h, 0x31));
            }
        }
    }
}
