//! 3×3 convolutions by Winograd's minimal filtering along rows ([`Winograd`]): F(2, 3)
//! makes two neighbouring outputs of a kernel row with 4 multiplies instead of 6 (6
//! multiply-adds per input channel and output pixel rather than 9), F(4, 3) four outputs
//! with 6 instead of 12 (4.5).
//!
//! Each padded input row `d` is transformed once per tile `t` of `n` columns (its inputs
//! `d[n·t..n·t + n + 2]`, `Bᵀd`) into the filter's terms, each kernel row `g` once per
//! layer (`Gg`) (Lavin & Gray 2016). Then `m_q = Σ_(ci, ky) u_q·v_q` (one fused
//! multiply-add per term, from zero, in the order input channel, kernel row) and the
//! tile's outputs are `bias + Aᵀm`. Every path (AVX-512, AVX2, scalar) does exactly these
//! operations in one order, written once per filter for one lane's values of any path
//! (`Filter::tile`, `Filter::outputs` over `Lane`), so all give the same bits, and a
//! pixel's value depends
//! only on its tile, never on the rows or tasks around it.
//!
//! F(2, 3)'s outputs read only their own 3×3 window's inputs (`m3` never enters the first
//! of a pair, `m0` never the second), so a value depends on exactly what the direct sum
//! reads. F(4, 3)'s mix up to two more columns each side into their rounding
//! ([`Winograd::extra_columns`]), which the regions of column tiles must cover
//! (`crate::model::multiscale::column_radius`).
//!
//! The transformed rows of a task lie flat (`rows × w/n` tiles per channel and term), so
//! the three kernel rows are three offsets in one array and segments run across row ends
//! with no padding columns.

use super::{ConvLayer, MR};
use crate::kernel::simd::{Isa, mask16};

/// Which minimal filtering a 3×3 layer's rows take ([`ConvLayer::with_winograd`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Winograd {
    /// F(2, 3): tiles of two columns, four terms; a value reads its 3×3 window only.
    F2,
    /// F(4, 3): tiles of four columns, six terms, half the direct multiply-adds; a
    /// value's rounding reads two more columns each side.
    F4,
}

impl Winograd {
    /// Output columns per tile: planes this path computes are a multiple of it wide.
    pub fn tile(self) -> usize {
        match self {
            Winograd::F2 => 2,
            Winograd::F4 => 4,
        }
    }

    /// Whether a `k × k` layer of `cin` input channels takes this path. The terms are
    /// `4/2` (F(2, 3)) or `6/4` (F(4, 3)) times the input's floats, and with fewer input
    /// channels than these the traffic outweighs the multiply-adds saved (F(2, 3) on
    /// 16→16 and 27→16 at 1280×720 ran 10–15 % slower, 32→32 and up 7–40 % faster;
    /// F(4, 3) gains from 16; `fast`'s 8-channel layers go directly; BENCHMARKS.md).
    pub fn takes(self, cin: usize, k: usize) -> bool {
        let min = match self {
            Winograd::F2 => 32,
            Winograd::F4 => 16,
        };
        k == 3 && cin >= min
    }

    /// Columns each side, beyond its 3×3 window, that an output's rounding reads on a
    /// layer that takes this path (F(4, 3)'s first output sums `d0..d4`, its last
    /// `d1..d5`).
    pub fn extra_columns(self) -> usize {
        match self {
            Winograd::F2 => 0,
            Winograd::F4 => 2,
        }
    }
}

/// A layer's weights packed for one [`Winograd`] filter.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Packed {
    pub filter: Winograd,
    /// `ceil(cout / MR)` panels of `[terms][cin][3][MR]` transformed kernel rows.
    pub panels: Vec<f32>,
}

/// Packs a 3×3 `weight` `[cout][cin][3][3]` for [`rows`] with `filter`.
pub(super) fn pack(filter: Winograd, weight: &[f32], cout: usize, cin: usize) -> Packed {
    let panels = match filter {
        Winograd::F2 => pack_with::<F23, 2, 4>(weight, cout, cin),
        Winograd::F4 => pack_with::<F43, 4, 6>(weight, cout, cin),
    };
    Packed { filter, panels }
}

fn pack_with<F: Filter<N, Q>, const N: usize, const Q: usize>(weight: &[f32], cout: usize, cin: usize) -> Vec<f32> {
    let blocks = cout.div_ceil(MR);
    let mut packed = vec![0f32; blocks * Q * cin * 3 * MR];
    for co in 0..cout {
        let (b, j) = (co / MR, co % MR);
        for ci in 0..cin {
            for ky in 0..3 {
                let g = &weight[((co * cin + ci) * 3 + ky) * 3..][..3];
                for (q, u) in F::kernel_row([g[0], g[1], g[2]]).into_iter().enumerate() {
                    packed[(((b * Q + q) * cin + ci) * 3 + ky) * MR + j] = u;
                }
            }
        }
    }
    packed
}

/// Whether [`rows`] computes `layer` on planes `w` wide.
pub(super) fn applies(layer: &ConvLayer, w: usize) -> bool {
    layer.winograd.as_ref().is_some_and(|p| w.is_multiple_of(p.filter.tile()))
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

/// Up to 16 consecutive flat tiles (running on across row ends): the first tile's
/// transformed values at `f` in a term's rows, its outputs at `n·f` in an output plane.
#[derive(Clone, Copy)]
struct Segment {
    f: usize,
    /// Tiles in the segment.
    tiles: usize,
}

/// `layer` ([`applies`]) on `task`'s rows; `scratch` holds the transformed input.
///
/// # Safety
/// `task.out` is valid for `rows × w` floats of each of `cout` channels `out_plane`
/// apart, written by this thread only; `task.src` holds `rows + 2` padded rows of each
/// of `cin` planes.
pub(super) unsafe fn rows(layer: &ConvLayer, task: &Rows, isa: Isa, scratch: &mut Vec<f32>) {
    let Some(packed) = &layer.winograd else { return };
    let job = Job { cin: layer.cin, cout: layer.cout, bias: &layer.bias, panels: &packed.panels, task };
    // SAFETY: the caller's contract.
    unsafe {
        match packed.filter {
            Winograd::F2 => rows_with::<F23, 2, 4>(&job, isa, scratch),
            Winograd::F4 => rows_with::<F43, 4, 6>(&job, isa, scratch),
        }
    }
}

/// A layer's packed panels on a task's rows.
struct Job<'a> {
    cin: usize,
    cout: usize,
    bias: &'a [f32],
    panels: &'a [f32],
    task: &'a Rows<'a>,
}

/// [`rows`] with filter `F` (`N` outputs and `Q` terms per tile).
///
/// # Safety
/// As [`rows`].
unsafe fn rows_with<F: Filter<N, Q>, const N: usize, const Q: usize>(job: &Job, isa: Isa, scratch: &mut Vec<f32>) {
    let task = job.task;
    let (tw, rows, w) = (task.w / N, task.rows, task.w);
    // Per channel and term: rows + 2 transformed rows, then 16 floats that masked reads
    // may touch. Every value read is written first, so a reused buffer needs no clearing.
    let stride = (rows + 2) * tw + 16;
    if scratch.len() < job.cin * Q * stride {
        scratch.resize(job.cin * Q * stride, 0.0);
    }
    for ci in 0..job.cin {
        for j in 0..rows + 2 {
            let d = &task.src[ci * task.plane + j * (w + 2)..][..w + 2];
            let v = &mut scratch[ci * Q * stride + j * tw..];
            #[cfg(target_arch = "x86_64")]
            if isa == Isa::Avx512 {
                // SAFETY: AVX-512F detected; `d` holds the w + 2 values read, and `v` the
                // Q strided rows of tw values written.
                unsafe { transform_avx512::<F, N, Q>(d, v.as_mut_ptr(), stride, tw) };
                continue;
            }
            for t in 0..tw {
                for (q, x) in F::tile(&d[N * t..][..N + 2]).into_iter().enumerate() {
                    v[q * stride + t] = x;
                }
            }
        }
    }
    let n = rows * tw;
    let segments: Vec<Segment> = (0..n).step_by(16).map(|f| Segment { f, tiles: (n - f).min(16) }).collect();
    let v = Transformed { v: scratch, stride, row: tw };
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the caller's contract; the instructions exist.
        Isa::Avx512 => return unsafe { gemm_avx512::<F, N, Q>(job, &v, &segments) },
        // SAFETY: as above.
        Isa::Avx2 => return unsafe { gemm_avx2::<F, N, Q>(job, &v, &segments) },
        Isa::Scalar => {}
    }
    for seg in &segments {
        segment_scalar::<F, N, Q>(job, &v, seg, 0..seg.tiles);
    }
}

/// A task's transformed input: term `q` of channel `ci` at `(ci·Q + q)·stride`, rows
/// `row` tiles apart.
struct Transformed<'a> {
    v: &'a [f32],
    stride: usize,
    row: usize,
}

/// Tiles `ts` of `seg`, one at a time.
#[inline(always)]
fn segment_scalar<F: Filter<N, Q>, const N: usize, const Q: usize>(
    job: &Job,
    v: &Transformed,
    seg: &Segment,
    ts: std::ops::Range<usize>,
) {
    let task = job.task;
    for t in ts {
        for co in 0..job.cout {
            let y = F::outputs(terms::<Q>(job, v, co, seg.f + t), job.bias[co]);
            for (k, y) in y.into_iter().enumerate() {
                let y = if task.relu { y.max(0.0) } else { y };
                // SAFETY: inside the task's output (the caller's contract of [`rows`]).
                unsafe { *task.out.add(co * task.out_plane + N * (seg.f + t) + k) = y };
            }
        }
    }
}

/// The `Q` sums of output channel `co` at flat tile `f` (a plain loop, always inlined,
/// so the AVX2 path's tails get FMA instructions).
#[inline(always)]
fn terms<const Q: usize>(job: &Job, v: &Transformed, co: usize, f: usize) -> [f32; Q] {
    let (b, j, cin) = (co / MR, co % MR, job.cin);
    let mut m = [0f32; Q];
    for (q, acc) in m.iter_mut().enumerate() {
        let panel = &job.panels[(b * Q + q) * cin * 3 * MR..];
        for ci in 0..cin {
            for ky in 0..3 {
                let x = v.v[(ci * Q + q) * v.stride + f + ky * v.row];
                *acc = x.mul_add(panel[(ci * 3 + ky) * MR + j], *acc);
            }
        }
    }
    m
}

/// The operations every path does, on one lane's values: `f32` here, the AVX-512 and
/// AVX2 registers in `x86`, so each formula is written once for all of them.
trait Lane: Copy {
    fn add(self, b: Self) -> Self;
    fn sub(self, b: Self) -> Self;
    /// `self · c` for a power of two `c` (exact).
    fn scale(self, c: f32) -> Self;
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
    #[inline(always)]
    fn scale(self, c: f32) -> f32 {
        self * c
    }
}

/// One minimal filtering F(`N`, 3) with `Q` terms: its formulas, and how the vector paths
/// gather a tile's inputs and scatter its outputs.
trait Filter<const N: usize, const Q: usize> {
    /// `Gg`: a kernel row's `Q` terms.
    fn kernel_row(g: [f32; 3]) -> [f32; Q];

    /// `Bᵀd`: a tile's `Q` terms from its `N + 2` padded inputs.
    fn tile<T: Lane>(d: &[T]) -> [T; Q];

    /// `bias + Aᵀm`: a tile's `N` outputs from its `Q` sums (before the ReLU).
    fn outputs<T: Lane>(m: [T; Q], bias: T) -> [T; N];

    /// The terms of 16 tiles from padded input `at` on, read by `load(i)` (16 values
    /// from input `i`).
    ///
    /// # Safety
    /// AVX-512F is available.
    #[cfg(target_arch = "x86_64")]
    unsafe fn tiles_avx512(
        load: impl Fn(usize) -> std::arch::x86_64::__m512,
        at: usize,
    ) -> [std::arch::x86_64::__m512; Q];

    /// 16 tiles' outputs, one register per output of a tile, in column order.
    ///
    /// # Safety
    /// AVX-512F is available.
    #[cfg(target_arch = "x86_64")]
    unsafe fn interleave_avx512(y: [std::arch::x86_64::__m512; N]) -> [std::arch::x86_64::__m512; N];

    /// 8 tiles' outputs, one register per output of a tile, in column order.
    ///
    /// # Safety
    /// AVX2 is available.
    #[cfg(target_arch = "x86_64")]
    unsafe fn interleave_avx2(y: [std::arch::x86_64::__m256; N]) -> [std::arch::x86_64::__m256; N];
}

/// F(2, 3): `v = [d0 − d2, d1 + d2, d2 − d1, d1 − d3]`, `u = [g0, (g0 + g1 + g2)/2, (g0 −
/// g1 + g2)/2, g2]`, outputs `bias + m0 + m1 + m2` and `bias + m1 − m2 − m3`.
struct F23;

impl Filter<2, 4> for F23 {
    fn kernel_row([g0, g1, g2]: [f32; 3]) -> [f32; 4] {
        [g0, (g0 + g1 + g2) * 0.5, (g0 - g1 + g2) * 0.5, g2]
    }

    #[inline(always)]
    fn tile<T: Lane>(d: &[T]) -> [T; 4] {
        let (d0, d1, d2, d3) = (d[0], d[1], d[2], d[3]);
        [d0.sub(d2), d1.add(d2), d2.sub(d1), d1.sub(d3)]
    }

    #[inline(always)]
    fn outputs<T: Lane>([m0, m1, m2, m3]: [T; 4], bias: T) -> [T; 2] {
        [bias.add(m0).add(m1).add(m2), bias.add(m1).sub(m2).sub(m3)]
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn tiles_avx512(
        load: impl Fn(usize) -> std::arch::x86_64::__m512,
        at: usize,
    ) -> [std::arch::x86_64::__m512; 4] {
        use std::arch::x86_64::*;
        // SAFETY: the caller's contract.
        unsafe {
            let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
            let odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
            let (a, b) = (load(at), load(at + 16));
            let (c, e) = (load(at + 2), load(at + 18));
            let (d0, d1) = (_mm512_permutex2var_ps(a, even, b), _mm512_permutex2var_ps(a, odd, b));
            let (d2, d3) = (_mm512_permutex2var_ps(c, even, e), _mm512_permutex2var_ps(c, odd, e));
            Self::tile(&[d0, d1, d2, d3].map(x86::Z)).map(|x| x.0)
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn interleave_avx512([e, o]: [std::arch::x86_64::__m512; 2]) -> [std::arch::x86_64::__m512; 2] {
        use std::arch::x86_64::*;
        // SAFETY: the caller's contract.
        unsafe {
            let lo = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
            let hi = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
            [_mm512_permutex2var_ps(e, lo, o), _mm512_permutex2var_ps(e, hi, o)]
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn interleave_avx2([e, o]: [std::arch::x86_64::__m256; 2]) -> [std::arch::x86_64::__m256; 2] {
        use std::arch::x86_64::*;
        // SAFETY: the caller's contract.
        unsafe {
            // Interleave within 128-bit lanes, then put the lanes in order.
            let (l, h) = (_mm256_unpacklo_ps(e, o), _mm256_unpackhi_ps(e, o));
            [_mm256_permute2f128_ps(l, h, 0x20), _mm256_permute2f128_ps(l, h, 0x31)]
        }
    }
}

/// F(4, 3) with the points 0, ±1, ±2 and ∞ (Lavin & Gray 2016): `Bᵀd`, `Gg` and `Aᵀm`
/// as written in [`F43::tile`], [`F43::kernel_row`] and [`F43::outputs`].
struct F43;

impl Filter<4, 6> for F43 {
    fn kernel_row(g: [f32; 3]) -> [f32; 6] {
        let [g0, g1, g2] = g.map(f64::from);
        [
            g0 / 4.0,
            -(g0 + g1 + g2) / 6.0,
            -(g0 - g1 + g2) / 6.0,
            (g0 + 2.0 * g1 + 4.0 * g2) / 24.0,
            (g0 - 2.0 * g1 + 4.0 * g2) / 24.0,
            g2,
        ]
        .map(|u| u as f32)
    }

    #[inline(always)]
    fn tile<T: Lane>(d: &[T]) -> [T; 6] {
        let (d0, d1, d2, d3, d4, d5) = (d[0], d[1], d[2], d[3], d[4], d[5]);
        let r = d4.sub(d2);
        let p = d4.sub(d2.scale(4.0));
        let q = d3.sub(d1.scale(4.0));
        let s = d3.sub(d1).scale(2.0);
        [d0.sub(d2).scale(4.0).add(r), p.add(q), p.sub(q), r.add(s), r.sub(s), d1.sub(d3).scale(4.0).add(d5.sub(d3))]
    }

    #[inline(always)]
    fn outputs<T: Lane>([m0, m1, m2, m3, m4, m5]: [T; 6], bias: T) -> [T; 4] {
        let (a1, s1) = (m1.add(m2), m1.sub(m2));
        let (a2, s2) = (m3.add(m4), m3.sub(m4));
        [
            bias.add(m0).add(a1).add(a2),
            bias.add(s1).add(s2.scale(2.0)),
            bias.add(a1).add(a2.scale(4.0)),
            bias.add(s1).add(s2.scale(8.0)).add(m5),
        ]
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn tiles_avx512(
        load: impl Fn(usize) -> std::arch::x86_64::__m512,
        at: usize,
    ) -> [std::arch::x86_64::__m512; 6] {
        use std::arch::x86_64::*;
        // SAFETY: the caller's contract.
        unsafe {
            // Columns 0 and 1 of each tile, from 32 values; then 2 and 3.
            let cols01 = _mm512_setr_epi32(0, 4, 8, 12, 16, 20, 24, 28, 1, 5, 9, 13, 17, 21, 25, 29);
            let cols23 = _mm512_setr_epi32(2, 6, 10, 14, 18, 22, 26, 30, 3, 7, 11, 15, 19, 23, 27, 31);
            // The first halves of two registers, then the second halves.
            let firsts = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23);
            let seconds = _mm512_setr_epi32(8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31);
            let (a, b, c, e) = (load(at), load(at + 16), load(at + 32), load(at + 48));
            let (ab01, ab23) = (_mm512_permutex2var_ps(a, cols01, b), _mm512_permutex2var_ps(a, cols23, b));
            let (ce01, ce23) = (_mm512_permutex2var_ps(c, cols01, e), _mm512_permutex2var_ps(c, cols23, e));
            let d0 = _mm512_permutex2var_ps(ab01, firsts, ce01);
            let d1 = _mm512_permutex2var_ps(ab01, seconds, ce01);
            let d2 = _mm512_permutex2var_ps(ab23, firsts, ce23);
            let d3 = _mm512_permutex2var_ps(ab23, seconds, ce23);
            // Columns 4 and 5 are the next tile's 0 and 1: shifted one lane, the 16th
            // tile's from the values after these 64.
            let next = |col: __m512, first: usize| {
                let after = _mm512_castps_si512(load(at + 64 + first));
                _mm512_castsi512_ps(_mm512_alignr_epi32(after, _mm512_castps_si512(col), 1))
            };
            let (d4, d5) = (next(d0, 0), next(d1, 1));
            Self::tile(&[d0, d1, d2, d3, d4, d5].map(x86::Z)).map(|x| x.0)
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn interleave_avx512(y: [std::arch::x86_64::__m512; 4]) -> [std::arch::x86_64::__m512; 4] {
        use std::arch::x86_64::*;
        // SAFETY: the caller's contract.
        unsafe {
            // Two outputs pairwise, then the pairs.
            let pairs_lo = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
            let pairs_hi = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
            let quads_lo = _mm512_setr_epi32(0, 1, 16, 17, 2, 3, 18, 19, 4, 5, 20, 21, 6, 7, 22, 23);
            let quads_hi = _mm512_setr_epi32(8, 9, 24, 25, 10, 11, 26, 27, 12, 13, 28, 29, 14, 15, 30, 31);
            let (p01, q01) =
                (_mm512_permutex2var_ps(y[0], pairs_lo, y[1]), _mm512_permutex2var_ps(y[0], pairs_hi, y[1]));
            let (p23, q23) =
                (_mm512_permutex2var_ps(y[2], pairs_lo, y[3]), _mm512_permutex2var_ps(y[2], pairs_hi, y[3]));
            [
                _mm512_permutex2var_ps(p01, quads_lo, p23),
                _mm512_permutex2var_ps(p01, quads_hi, p23),
                _mm512_permutex2var_ps(q01, quads_lo, q23),
                _mm512_permutex2var_ps(q01, quads_hi, q23),
            ]
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn interleave_avx2(y: [std::arch::x86_64::__m256; 4]) -> [std::arch::x86_64::__m256; 4] {
        use std::arch::x86_64::*;
        // SAFETY: the caller's contract.
        unsafe {
            // A 4 × 8 transpose: outputs pairwise, then the pairs (tiles t and t + 4 in
            // one register's halves), then the halves in order.
            let (t0, t1) = (_mm256_unpacklo_ps(y[0], y[1]), _mm256_unpackhi_ps(y[0], y[1]));
            let (t2, t3) = (_mm256_unpacklo_ps(y[2], y[3]), _mm256_unpackhi_ps(y[2], y[3]));
            let (u0, u1) = (_mm256_shuffle_ps::<0x44>(t0, t2), _mm256_shuffle_ps::<0xEE>(t0, t2));
            let (u2, u3) = (_mm256_shuffle_ps::<0x44>(t1, t3), _mm256_shuffle_ps::<0xEE>(t1, t3));
            [
                _mm256_permute2f128_ps::<0x20>(u0, u1),
                _mm256_permute2f128_ps::<0x20>(u2, u3),
                _mm256_permute2f128_ps::<0x31>(u0, u1),
                _mm256_permute2f128_ps::<0x31>(u2, u3),
            ]
        }
    }
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
        #[inline(always)]
        fn scale(self, c: f32) -> Z {
            // SAFETY: as above.
            Z(unsafe { _mm512_mul_ps(self.0, _mm512_set1_ps(c)) })
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
        #[inline(always)]
        fn scale(self, c: f32) -> Y {
            // SAFETY: as above.
            Y(unsafe { _mm256_mul_ps(self.0, _mm256_set1_ps(c)) })
        }
    }
}

/// One padded row's transform with AVX-512, 16 tiles at a time, into `v` (term `q` at
/// `q·stride`).
///
/// # Safety
/// AVX-512F is available; `d` holds `N·tw + 2` values; `v` is valid for writes of `tw`
/// values at each of `q·stride`, `q < Q`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn transform_avx512<F: Filter<N, Q>, const N: usize, const Q: usize>(
    d: &[f32],
    v: *mut f32,
    stride: usize,
    tw: usize,
) {
    use std::arch::x86_64::*;
    let len = d.len();
    // SAFETY: loads are masked to `d`, stores to the tw values of each term.
    unsafe {
        let load = |at: usize| _mm512_maskz_loadu_ps(mask16(len.saturating_sub(at)), d.as_ptr().add(at.min(len)));
        for t in (0..tw).step_by(16) {
            let m = mask16(tw - t);
            for (q, x) in F::tiles_avx512(load, N * t).into_iter().enumerate() {
                _mm512_mask_storeu_ps(v.add(q * stride + t), m, x);
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
unsafe fn gemm_avx512<F: Filter<N, Q>, const N: usize, const Q: usize>(
    job: &Job,
    v: &Transformed,
    segments: &[Segment],
) {
    for group in segments.chunks(NV) {
        // A short last group repeats its first segment with no tiles.
        let group: [Segment; NV] =
            std::array::from_fn(|i| group.get(i).copied().unwrap_or(Segment { tiles: 0, ..group[0] }));
        for b in 0..job.cout.div_ceil(MR) {
            let m = (job.cout - b * MR).min(MR);
            // SAFETY: the caller's contract.
            unsafe { with_const!(m, M => block_avx512::<F, N, Q, M>(job, v, &group, b), [8 7 6 5 4 3 2] else 1) };
        }
    }
}

/// `M` output channels of panel `b` at `group`'s tiles.
///
/// # Safety
/// As [`gemm_avx512`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn block_avx512<F: Filter<N, Q>, const N: usize, const Q: usize, const M: usize>(
    job: &Job,
    v: &Transformed,
    group: &[Segment; NV],
    b: usize,
) {
    use std::arch::x86_64::*;
    let (cin, task) = (job.cin, job.task);
    // SAFETY: masked loads stay in the transformed rows (each term's rows end with 16
    // spare floats), masked stores in the task's output; pointers to masked-off lanes
    // are only formed (`wrapping_add`), never read.
    unsafe {
        // Per output channel and segment, the terms' sums.
        let mut sums = [[[x86::Z(_mm512_setzero_ps()); Q]; NV]; M];
        for q in 0..Q {
            let mut acc = [[_mm512_setzero_ps(); NV]; M];
            let mut wp = job.panels.as_ptr().add((b * Q + q) * cin * 3 * MR);
            for ci in 0..cin {
                let rows = v.v.as_ptr().wrapping_add((ci * Q + q) * v.stride);
                for ky in 0..3 {
                    let mut x = [_mm512_setzero_ps(); NV];
                    for (i, xi) in x.iter_mut().enumerate() {
                        let at = rows.wrapping_add(group[i].f + ky * v.row);
                        *xi = _mm512_maskz_loadu_ps(mask16(group[i].tiles), at);
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
                    s[q] = x86::Z(*a);
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (j, sj) in sums.iter().enumerate() {
            let bias = x86::Z(_mm512_set1_ps(job.bias[b * MR + j]));
            let dst = task.out.wrapping_add((b * MR + j) * task.out_plane);
            for (m, seg) in sj.iter().zip(group) {
                let y = F::outputs(*m, bias).map(|y| if task.relu { _mm512_max_ps(y.0, zero) } else { y.0 });
                let (at, n) = (dst.wrapping_add(N * seg.f), N * seg.tiles);
                for (k, o) in F::interleave_avx512(y).into_iter().enumerate() {
                    _mm512_mask_storeu_ps(at.wrapping_add(16 * k), mask16(n.saturating_sub(16 * k)), o);
                }
            }
        }
    }
}

/// Output channels per AVX2 block.
#[cfg(target_arch = "x86_64")]
const M_AVX2: usize = 4;

/// Every segment with AVX2: its tiles by 16 and then by 8 ([`block_avx2`]), the last
/// ones short of 8 the scalar way.
///
/// # Safety
/// AVX2 and FMA are available; [`rows`]' contract.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn gemm_avx2<F: Filter<N, Q>, const N: usize, const Q: usize>(job: &Job, v: &Transformed, segments: &[Segment]) {
    for seg in segments {
        let whole = seg.tiles / 8 * 8;
        for c0 in (0..job.cout).step_by(M_AVX2) {
            let mut t = 0;
            // SAFETY: the caller's contract; whole runs of 8 tiles lie in the segment.
            unsafe {
                while t + 16 <= whole {
                    block_avx2::<F, N, Q, 2>(job, v, seg.f + t, c0);
                    t += 16;
                }
                if t < whole {
                    block_avx2::<F, N, Q, 1>(job, v, seg.f + t, c0);
                }
            }
        }
        // Inlined here, its multiply-adds are FMA instructions, not calls to `fmaf`.
        segment_scalar::<F, N, Q>(job, v, seg, whole..seg.tiles);
    }
}

/// Output channels `c0..` (up to [`M_AVX2`]) × `R` runs of 8 flat tiles from `f`, whose
/// outputs start at `N·f` in each plane: `M_AVX2·R` accumulators.
///
/// # Safety
/// As [`gemm_avx2`], and the `8·R` tiles from `f` lie in the task.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_avx2<F: Filter<N, Q>, const N: usize, const Q: usize, const R: usize>(
    job: &Job,
    v: &Transformed,
    f: usize,
    c0: usize,
) {
    use std::arch::x86_64::*;
    let (cin, task, m) = (job.cin, job.task, (job.cout - c0).min(M_AVX2));
    let (b, j0) = (c0 / MR, c0 % MR);
    // SAFETY: unmasked loads of whole runs of 8 tiles stay in the transformed rows;
    // stores in the task's output.
    unsafe {
        // Per output channel and run, the terms' sums.
        let mut sums = [[[x86::Y(_mm256_setzero_ps()); Q]; R]; M_AVX2];
        for q in 0..Q {
            let mut acc = [[_mm256_setzero_ps(); R]; M_AVX2];
            let mut wp = job.panels.as_ptr().add((b * Q + q) * cin * 3 * MR + j0);
            for ci in 0..cin {
                let rows = v.v.as_ptr().add((ci * Q + q) * v.stride + f);
                for ky in 0..3 {
                    let x: [__m256; R] = std::array::from_fn(|i| _mm256_loadu_ps(rows.add(8 * i + ky * v.row)));
                    for (j, accj) in acc.iter_mut().enumerate() {
                        let wv = _mm256_broadcast_ss(&*wp.add(j));
                        for i in 0..R {
                            accj[i] = _mm256_fmadd_ps(x[i], wv, accj[i]);
                        }
                    }
                    wp = wp.add(MR);
                }
            }
            for (sj, accj) in sums.iter_mut().zip(&acc) {
                for (s, a) in sj.iter_mut().zip(accj) {
                    s[q] = x86::Y(*a);
                }
            }
        }
        let zero = _mm256_setzero_ps();
        for (j, sj) in sums.iter().enumerate().take(m) {
            let bias = x86::Y(_mm256_set1_ps(job.bias[c0 + j]));
            let dst = task.out.add((c0 + j) * task.out_plane + N * f);
            for (i, m) in sj.iter().enumerate() {
                let y = F::outputs(*m, bias).map(|y| if task.relu { _mm256_max_ps(y.0, zero) } else { y.0 });
                for (k, o) in F::interleave_avx2(y).into_iter().enumerate() {
                    _mm256_storeu_ps(dst.add(8 * N * i + 8 * k), o);
                }
            }
        }
    }
}
