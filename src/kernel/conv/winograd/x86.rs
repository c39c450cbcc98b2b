//! The AVX-512 and AVX2 paths: the registers as [`Lane`]s, the rows' transform, and the
//! sums in the direct kernel's register blocking (8 output channels × 3 segments of 16
//! tiles with AVX-512, 4 × 2 × 8 with AVX2).

use super::{Filter, Job, Lane, MR, Segment, Transformed, segment_scalar};
use crate::kernel::simd::mask16;
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

/// One padded row's transform with AVX-512, 16 tiles at a time, into `v` (term `q` at
/// `q·stride`).
///
/// # Safety
/// AVX-512F is available; `d` holds `N·tw + 2` values; `v` is valid for writes of `tw`
/// values at each of `q·stride`, `q < Q`.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn transform_avx512<F: Filter<N, Q>, const N: usize, const Q: usize>(
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
const NV: usize = 3;

/// Every segment with AVX-512: blocks of `MR` output channels × [`NV`] segments.
///
/// # Safety
/// AVX-512F is available; [`super::rows`]' contract.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn gemm_avx512<F: Filter<N, Q>, const N: usize, const Q: usize>(
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
        let mut sums = [[[Z(_mm512_setzero_ps()); Q]; NV]; M];
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
                    s[q] = Z(*a);
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (j, sj) in sums.iter().enumerate() {
            let bias = Z(_mm512_set1_ps(job.bias[b * MR + j]));
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
const M_AVX2: usize = 4;

/// Every segment with AVX2: its tiles by 16 and then by 8 ([`block_avx2`]), the last
/// ones short of 8 the scalar way.
///
/// # Safety
/// AVX2 and FMA are available; [`super::rows`]' contract.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn gemm_avx2<F: Filter<N, Q>, const N: usize, const Q: usize>(
    job: &Job,
    v: &Transformed,
    segments: &[Segment],
) {
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
        let mut sums = [[[Y(_mm256_setzero_ps()); Q]; R]; M_AVX2];
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
                    s[q] = Y(*a);
                }
            }
        }
        let zero = _mm256_setzero_ps();
        for (j, sj) in sums.iter().enumerate().take(m) {
            let bias = Y(_mm256_set1_ps(job.bias[c0 + j]));
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
