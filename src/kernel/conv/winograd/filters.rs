//! The two minimal filterings, F(2, 3) and F(4, 3): each one's formulas (written once
//! for every path's lanes) and how the AVX-512 and AVX2 paths gather its inputs and
//! scatter its outputs.

#[cfg(target_arch = "x86_64")]
use super::x86::Z;
use super::{Filter, Lane};

/// F(2, 3): `v = [d0 − d2, d1 + d2, d2 − d1, d1 − d3]`, `u = [g0, (g0 + g1 + g2)/2, (g0 −
/// g1 + g2)/2, g2]`, outputs `bias + m0 + m1 + m2` and `bias + m1 − m2 − m3`.
pub(super) struct F23;

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
            Self::tile(&[d0, d1, d2, d3].map(Z)).map(|x| x.0)
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
pub(super) struct F43;

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
            Self::tile(&[d0, d1, d2, d3, d4, d5].map(Z)).map(|x| x.0)
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
