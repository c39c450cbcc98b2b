//! AVX-512 versions of per-pixel kernels: the softmax kernel application and the
//! exponential it needs.

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
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(0.693_359_4), x);
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(-2.121_944_4e-4), r);
    let mut p = _mm512_set1_ps(1.987_569_1e-4);
    for c in [1.398_199_9e-3, 8.333_452e-3, 4.166_579_6e-2, 0.166_666_65, 0.5] {
        p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(c));
    }
    let y = _mm512_fmadd_ps(_mm512_mul_ps(p, r), r, _mm512_add_ps(r, _mm512_set1_ps(1.0)));
    _mm512_scalef_ps(y, n)
}

/// Row `y` of [`super::apply`], 16 pixels at a time: the same softmax (logits clamped,
/// maximum subtracted) and gather, with [`exp_nonpositive`] and fused multiply-adds.
///
/// # Safety
/// AVX-512F is available; `logits` is `k² × h × w`, each `noisy` plane `(h + k − 1) ×
/// (w + k − 1)`, each `out` row `w` long, `y < h`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
pub unsafe fn apply_row(
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
    let limit = _mm512_set1_ps(super::LOGIT_LIMIT);
    let neg_limit = _mm512_set1_ps(-super::LOGIT_LIMIT);
    // NaN → −limit: `max` returns its second operand when the first is NaN.
    let clamp = |l: __m512| _mm512_min_ps(_mm512_max_ps(l, neg_limit), limit);
    // SAFETY (all loads and stores): masked lanes are not touched; the others stay inside
    // the slices (asserted).
    unsafe {
        for x in (0..w).step_by(16) {
            let mask = if w - x >= 16 { u16::MAX } else { (1u16 << (w - x)) - 1 };
            let at = |n: usize| logits.as_ptr().add(n * plane + y * w + x);
            let mut max = _mm512_set1_ps(f32::NEG_INFINITY);
            for n in 0..k2 {
                max = _mm512_max_ps(max, clamp(_mm512_maskz_loadu_ps(mask, at(n))));
            }
            let mut sum = _mm512_setzero_ps();
            let mut acc = [_mm512_setzero_ps(); 3];
            for ky in 0..k {
                for kx in 0..k {
                    let l = clamp(_mm512_maskz_loadu_ps(mask, at(ky * k + kx)));
                    let e = exp_nonpositive(_mm512_sub_ps(l, max));
                    sum = _mm512_add_ps(sum, e);
                    let src = (y + ky) * pw + x + kx;
                    for (c, a) in acc.iter_mut().enumerate() {
                        *a = _mm512_fmadd_ps(e, _mm512_maskz_loadu_ps(mask, noisy[c].as_ptr().add(src)), *a);
                    }
                }
            }
            // sum ≥ 1: the maximum's own term is e^0.
            for (o, a) in out.iter_mut().zip(acc) {
                _mm512_mask_storeu_ps(o.as_mut_ptr().add(x), mask, _mm512_div_ps(a, sum));
            }
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;

    #[test]
    fn the_exponential_is_within_two_ulp_of_libm() {
        if !avx512() {
            return;
        }
        let xs: Vec<f32> = (0..4096).map(|i| -(i as f32) * 0.0213).chain([0.0, -1e-30, -86.9, -87.0, -1e30]).collect();
        for chunk in xs.chunks(16) {
            let mut v = [0f32; 16];
            v[..chunk.len()].copy_from_slice(chunk);
            let mut out = [0f32; 16];
            // SAFETY: AVX-512F is available (checked); 16 floats each.
            unsafe { _mm512_storeu_ps(out.as_mut_ptr(), exp_nonpositive(_mm512_loadu_ps(v.as_ptr()))) };
            for (x, e) in chunk.iter().zip(out) {
                let want = x.max(-87.0).exp();
                let ulps = (e.to_bits() as i64 - want.to_bits() as i64).abs();
                assert!(ulps <= 2, "exp({x}) = {e}, libm {want} ({ulps} ulp)");
            }
        }
    }
}
