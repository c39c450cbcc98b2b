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
//! pixel's value depends only on its tile, never on the rows or tasks around it.
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

mod filters;
#[cfg(target_arch = "x86_64")]
mod x86;

use super::{ConvLayer, MR};
use crate::kernel::simd::Isa;
use filters::{F23, F43};

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

    /// Whether a `k × k` layer of `cin` input channels takes this path: a 3×3 one of 32
    /// input channels or more for F(2, 3), 16 or more for F(4, 3). The terms are `4/2`
    /// (F(2, 3)) or `6/4` (F(4, 3)) times the input's floats, and with fewer channels the
    /// traffic outweighs the multiply-adds saved (F(2, 3) on 16→16 and 27→16 at 1280×720
    /// ran 10–15 % slower, 32→32 and up 7–40 % faster; F(4, 3) gains from 16; `fast`'s
    /// 8-channel layers go directly; BENCHMARKS.md).
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

/// [`pack`] for filter `F` (`N` outputs and `Q` terms per tile).
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
                unsafe { x86::transform_avx512::<F, N, Q>(d, v.as_mut_ptr(), stride, tw) };
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
        Isa::Avx512 => return unsafe { x86::gemm_avx512::<F, N, Q>(job, &v, &segments) },
        // SAFETY: as above.
        Isa::Avx2 => return unsafe { x86::gemm_avx2::<F, N, Q>(job, &v, &segments) },
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
