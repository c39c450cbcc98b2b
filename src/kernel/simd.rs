//! AVX-512 and AVX2 versions of per-pixel kernels: the softmax kernel application and
//! the exponential it needs.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// Whether the AVX-512 paths run (`KPCN_NO_AVX512` set turns them off, for comparing);
/// decided once per process, since hot loops ask.
pub fn avx512() -> bool {
    static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ON.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            std::env::var_os("KPCN_NO_AVX512").is_none() && std::arch::is_x86_feature_detected!("avx512f")
        }
        #[cfg(not(target_arch = "x86_64"))]
        false
    })
}

/// The mask of an AVX-512 load or store of the first `left` of 16 lanes (all 16 when
/// `left ≥ 16`).
pub fn mask16(left: usize) -> u16 {
    if left >= 16 { u16::MAX } else { (1u16 << left) - 1 }
}

/// The vector instruction set of a kernel, picked at run time.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Isa {
    /// AVX-512F.
    Avx512,
    /// AVX2 with FMA.
    Avx2,
    /// Plain Rust.
    Scalar,
}

impl Isa {
    /// The best this CPU has ([`avx512`] decides for AVX-512).
    pub fn detect() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            if avx512() {
                return Isa::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                return Isa::Avx2;
            }
        }
        Isa::Scalar
    }

    /// Whether this CPU can run `self`.
    #[cfg(test)]
    pub fn available(self) -> bool {
        match self {
            Isa::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma"),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }
}

/// Defines the function pointer type `$ty` of `$plain` (a function written for the compiler
/// to vectorise, `#[inline(always)]`, whose arguments are listed with their types), and
/// `fn $pick() -> $ty`, which picks `$plain` compiled once more with AVX2 and FMA enabled
/// where the CPU has them (twice the lanes of the baseline's SSE2), else `$plain` as
/// compiled.
macro_rules! avx2_or_compiled {
    ($(#[$tmeta:meta])* $vis:vis type $ty:ident; $pvis:vis fn $pick:ident() = $plain:ident($($arg:ident: $argty:ty),* $(,)?)) => {
        $(#[$tmeta])*
        $vis type $ty = fn($($argty),*);

        $pvis fn $pick() -> $ty {
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                /// `$plain` compiled for AVX2 and FMA.
                ///
                /// # Safety
                /// AVX2 and FMA are available.
                #[target_feature(enable = "avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn avx2($($arg: $argty),*) {
                    $plain($($arg),*)
                }
                return |$($arg: $argty),*| {
                    // SAFETY: AVX2 and FMA are available (detected).
                    unsafe { avx2($($arg),*) }
                };
            }
            $plain
        }
    };
}
pub(crate) use avx2_or_compiled;

/// Cephes' single-precision `e^r` polynomial on `|r| ≤ ln 2 / 2`, highest power first, and
/// `ln 2` split in two for the range reduction; shared by every instruction set.
const EXP_POLY: [f32; 6] = [1.987_569_1e-4, 1.398_199_9e-3, 8.333_452e-3, 4.166_579_6e-2, 0.166_666_65, 0.5];
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;

/// `e^x` for `x ≤ 0` (Cephes' single-precision polynomial after a range reduction by
/// `ln 2`, within 2 ulp); below −87 it returns `e^−87`, still a normal float.
///
/// # Safety
/// AVX-512F is available.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
pub unsafe fn exp_nonpositive(x: __m512) -> __m512 {
    let x = _mm512_max_ps(x, _mm512_set1_ps(-87.0));
    let n = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(_mm512_mul_ps(
        x,
        _mm512_set1_ps(std::f32::consts::LOG2_E),
    ));
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(LN2_HI), x);
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(LN2_LO), r);
    let mut p = _mm512_set1_ps(EXP_POLY[0]);
    for c in &EXP_POLY[1..] {
        p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(*c));
    }
    let y = _mm512_fmadd_ps(_mm512_mul_ps(p, r), r, _mm512_add_ps(r, _mm512_set1_ps(1.0)));
    _mm512_scalef_ps(y, n)
}

/// [`exp_nonpositive`] with AVX2 and FMA: the same polynomial, and `2^n` built in the
/// exponent bits (`n ≥ −126` after the clamp, so the result stays normal).
///
/// # Safety
/// AVX2 and FMA are available.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub unsafe fn exp_nonpositive_avx2(x: __m256) -> __m256 {
    let x = _mm256_max_ps(x, _mm256_set1_ps(-87.0));
    let n = _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(_mm256_mul_ps(
        x,
        _mm256_set1_ps(std::f32::consts::LOG2_E),
    ));
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_HI), x);
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_LO), r);
    let mut p = _mm256_set1_ps(EXP_POLY[0]);
    for c in &EXP_POLY[1..] {
        p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(*c));
    }
    let y = _mm256_fmadd_ps(_mm256_mul_ps(p, r), r, _mm256_add_ps(r, _mm256_set1_ps(1.0)));
    let pow2 =
        _mm256_castsi256_ps(_mm256_slli_epi32::<23>(_mm256_add_epi32(_mm256_cvtps_epi32(n), _mm256_set1_epi32(127))));
    _mm256_mul_ps(y, pow2)
}

/// Defines a row of [`super::apply`] on one instruction set, `$lanes` pixels at a time:
/// the same softmax (logits clamped, maximum subtracted) and gather, with the set's
/// polynomial exponential and fused multiply-adds. What differs is passed in: the mask of
/// the `left` pixels still to go, masked loads and stores, and the arithmetic.
macro_rules! apply_row {
    (
        $(#[$attr:meta])* $name:ident, $lanes:literal, $exp:ident,
        mask |$left:ident| $mask:expr,
        load |$ptr:ident, $m:ident| $load:expr,
        store |$dst:ident, $sm:ident, $v:ident| $store:expr,
        $set1:ident, $setzero:ident, $min:ident, $max:ident, $add:ident, $sub:ident, $fmadd:ident, $div:ident $(,)?
    ) => {
        $(#[$attr])*
        #[allow(clippy::too_many_arguments)]
        pub unsafe fn $name(
            logits: &[f32],
            noisy: &[Vec<f32>; 3],
            k: usize,
            w: usize,
            h: usize,
            y: usize,
            mut out: [&mut [f32]; 3],
        ) {
            let (plane, pw, k2) = (w * h, w + k - 1, k * k);
            assert!(logits.len() >= k2 * plane && noisy.iter().all(|p| p.len() >= pw * (h + k - 1)) && y < h);
            assert!(out.iter().all(|o| o.len() >= w));
            let limit = $set1(super::LOGIT_LIMIT);
            let neg_limit = $set1(-super::LOGIT_LIMIT);
            // NaN → −limit: `max` returns its second operand when the first is NaN.
            let clamp = |l| $min($max(l, neg_limit), limit);
            // SAFETY: (all loads and stores) masked lanes are not touched; the others stay
            // inside the slices (asserted).
            unsafe {
                for x in (0..w).step_by($lanes) {
                    let $left = w - x;
                    let $m = $mask;
                    let at = |n: usize| logits.as_ptr().add(n * plane + y * w + x);
                    let mut max = $set1(f32::NEG_INFINITY);
                    for n in 0..k2 {
                        let $ptr = at(n);
                        max = $max(max, clamp($load));
                    }
                    let mut sum = $setzero();
                    let mut acc = [$setzero(); 3];
                    for ky in 0..k {
                        for kx in 0..k {
                            let $ptr = at(ky * k + kx);
                            let e = $exp($sub(clamp($load), max));
                            sum = $add(sum, e);
                            let src = (y + ky) * pw + x + kx;
                            for (c, a) in acc.iter_mut().enumerate() {
                                let $ptr = noisy[c].as_ptr().add(src);
                                *a = $fmadd(e, $load, *a);
                            }
                        }
                    }
                    // sum ≥ 1: the maximum's own term is e^0.
                    for (o, a) in out.iter_mut().zip(acc) {
                        let ($dst, $sm, $v) = (o.as_mut_ptr().add(x), $m, $div(a, sum));
                        $store;
                    }
                }
            }
        }
    };
}

#[cfg(target_arch = "x86_64")]
apply_row! {
    /// Row `y` of [`super::apply`] with AVX-512, 16 pixels at a time.
    ///
    /// # Safety
    /// AVX-512F is available; `logits` is `k² × h × w`, each `noisy` plane `(h + k − 1) ×
    /// (w + k − 1)`, each `out` row `w` long, `y < h`.
    #[target_feature(enable = "avx512f")]
    apply_row, 16, exp_nonpositive,
    mask |left| mask16(left),
    load |ptr, mask| _mm512_maskz_loadu_ps(mask, ptr),
    store |dst, mask, v| _mm512_mask_storeu_ps(dst, mask, v),
    _mm512_set1_ps, _mm512_setzero_ps, _mm512_min_ps, _mm512_max_ps, _mm512_add_ps, _mm512_sub_ps,
    _mm512_fmadd_ps, _mm512_div_ps,
}

#[cfg(target_arch = "x86_64")]
apply_row! {
    /// Row `y` of [`super::apply`] with AVX2, 8 pixels at a time.
    ///
    /// # Safety
    /// AVX2 and FMA are available; sizes as [`apply_row()`].
    #[target_feature(enable = "avx2,fma")]
    apply_row_avx2, 8, exp_nonpositive_avx2,
    mask |left| _mm256_cmpgt_epi32(_mm256_set1_epi32(left.min(8) as i32), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7)),
    load |ptr, mask| _mm256_maskload_ps(ptr, mask),
    store |dst, mask, v| _mm256_maskstore_ps(dst, mask, v),
    _mm256_set1_ps, _mm256_setzero_ps, _mm256_min_ps, _mm256_max_ps, _mm256_add_ps, _mm256_sub_ps,
    _mm256_fmadd_ps, _mm256_div_ps,
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;

    /// Checks an exponential on 16 inputs at a time against libm, within 2 ulp.
    fn within_two_ulp(exp: impl Fn(&[f32; 16]) -> [f32; 16]) {
        let xs: Vec<f32> = (0..4096).map(|i| -(i as f32) * 0.0213).chain([0.0, -1e-30, -86.9, -87.0, -1e30]).collect();
        for chunk in xs.chunks(16) {
            let mut v = [0f32; 16];
            v[..chunk.len()].copy_from_slice(chunk);
            for (x, e) in chunk.iter().zip(exp(&v)) {
                let want = x.max(-87.0).exp();
                let ulps = (e.to_bits() as i64 - want.to_bits() as i64).abs();
                assert!(ulps <= 2, "exp({x}) = {e}, libm {want} ({ulps} ulp)");
            }
        }
    }

    #[test]
    fn the_exponentials_are_within_two_ulp_of_libm() {
        if Isa::Avx512.available() {
            within_two_ulp(|v| {
                let mut out = [0f32; 16];
                // SAFETY: AVX-512F is available (checked); 16 floats each.
                unsafe { _mm512_storeu_ps(out.as_mut_ptr(), exp_nonpositive(_mm512_loadu_ps(v.as_ptr()))) };
                out
            });
        }
        if Isa::Avx2.available() {
            within_two_ulp(|v| {
                let mut out = [0f32; 16];
                for i in [0, 8] {
                    // SAFETY: AVX2 and FMA are available (checked); 8 floats each.
                    unsafe {
                        _mm256_storeu_ps(out[i..].as_mut_ptr(), exp_nonpositive_avx2(_mm256_loadu_ps(v[i..].as_ptr())))
                    };
                }
                out
            });
        }
    }
}
