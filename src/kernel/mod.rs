//! Per-pixel kernel application (ARCHITECTURE.md §Features): softmax over the predicted `k²` weights (max
//! subtracted first), then a gather over the `k×k` neighbourhood of the noisy colour,
//! the same weights for R, G and B. Weight `n = ky·k + kx` is for the neighbour at
//! `(ky − r, kx − r)`. Not im2col: this is ≈ 1.2 GFLOP per 720p frame for 21×21.

use rayon::prelude::*;

pub mod buffers;
pub mod conv;
pub mod ops;
pub mod planes;
mod simd;

pub(crate) use simd::avx2_or_compiled;

/// Logits are clamped to this magnitude (NaN → −it) so the softmax stays finite.
pub(crate) const LOGIT_LIMIT: f32 = 1e30;

fn clamp_logit(l: f32) -> f32 {
    if l.is_nan() { -LOGIT_LIMIT } else { l.clamp(-LOGIT_LIMIT, LOGIT_LIMIT) }
}

/// Applies predicted kernels.
///
/// `logits`: `k² × h × w` (CHW). `noisy`: three planes of `(h + 2r) × (w + 2r)` with
/// `r = (k − 1) / 2`, the region around the output. Returns three `h × w` planes, each a
/// convex combination of its neighbourhood.
pub fn apply(logits: &[f32], noisy: &[Vec<f32>; 3], k: usize, w: usize, h: usize) -> [Vec<f32>; 3] {
    apply_on(simd::Isa::detect(), logits, noisy, k, w, h)
}

/// [`apply`] on the given instruction set (the vector paths agree with the scalar one to a
/// few ulp: their exponential is a polynomial).
fn apply_on(isa: simd::Isa, logits: &[f32], noisy: &[Vec<f32>; 3], k: usize, w: usize, h: usize) -> [Vec<f32>; 3] {
    let r = (k - 1) / 2;
    let pw = w + 2 * r;
    let plane = w * h;
    assert_eq!(logits.len(), k * k * plane, "logits are k² × h × w");
    assert!(noisy.iter().all(|p| p.len() == pw * (h + 2 * r)), "noisy planes are (h + 2r) × (w + 2r)");
    let mut out = [buffers::zeroed(plane), buffers::zeroed(plane), buffers::zeroed(plane)];
    let [o0, o1, o2] = &mut out;
    o0.par_chunks_mut(w).zip(o1.par_chunks_mut(w)).zip(o2.par_chunks_mut(w)).enumerate().for_each(
        |(y, ((r0, r1), r2))| {
            #[cfg(target_arch = "x86_64")]
            match isa {
                // SAFETY: AVX-512F is available (detected); the slices have the sizes
                // asserted above.
                simd::Isa::Avx512 => return unsafe { simd::apply_row(logits, noisy, k, w, h, y, [r0, r1, r2]) },
                // SAFETY: AVX2 and FMA are available (detected); sizes as above.
                simd::Isa::Avx2 => return unsafe { simd::apply_row_avx2(logits, noisy, k, w, h, y, [r0, r1, r2]) },
                simd::Isa::Scalar => {}
            }
            // Row-wise passes keep every access contiguous.
            let mut max = vec![f32::NEG_INFINITY; w];
            for n in 0..k * k {
                let row = &logits[n * plane + y * w..][..w];
                for (m, &l) in max.iter_mut().zip(row) {
                    *m = m.max(clamp_logit(l));
                }
            }
            let mut sum = vec![0f32; w];
            let mut acc = [vec![0f32; w], vec![0f32; w], vec![0f32; w]];
            for ky in 0..k {
                for kx in 0..k {
                    let n = ky * k + kx;
                    let row = &logits[n * plane + y * w..][..w];
                    let src = (y + ky) * pw + kx;
                    for x in 0..w {
                        let e = (clamp_logit(row[x]) - max[x]).exp();
                        sum[x] += e;
                        for c in 0..3 {
                            acc[c][x] += e * noisy[c][src + x];
                        }
                    }
                }
            }
            for (c, out_row) in [r0, r1, r2].into_iter().enumerate() {
                for x in 0..w {
                    // sum ≥ 1: the maximum's own term is exp(0).
                    out_row[x] = acc[c][x] / sum[x];
                }
            }
        },
    );
    out
}

/// The gradient of [`apply`] in the logits, given the output's gradient `grad` (three
/// `h × w` planes): with `p` the softmax weights and `o` the output, `∂/∂l_n =
/// p_n·Σ_c grad_c·(noisy_c,n − o_c)`. Logits clamped by the forward pass get the gradient
/// of their clamped value.
pub fn apply_backward(
    logits: &[f32],
    noisy: &[Vec<f32>; 3],
    grad: [&[f32]; 3],
    k: usize,
    w: usize,
    h: usize,
) -> Vec<f32> {
    let r = (k - 1) / 2;
    let (pw, plane, k2) = (w + 2 * r, w * h, k * k);
    assert_eq!(logits.len(), k2 * plane, "logits are k² × h × w");
    let mut out = vec![0f32; k2 * plane];
    // Rows are independent; each task writes its row of every logit plane.
    let rows: Vec<Vec<f32>> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut d = vec![0f32; k2 * w];
            let mut e = vec![0f32; k2];
            for x in 0..w {
                let l = |n: usize| clamp_logit(logits[n * plane + y * w + x]);
                let max = (0..k2).map(l).fold(f32::NEG_INFINITY, f32::max);
                let mut sum = 0f32;
                for (n, en) in e.iter_mut().enumerate() {
                    *en = (l(n) - max).exp();
                    sum += *en;
                }
                let v = |c: usize, n: usize| noisy[c][(y + n / k) * pw + x + n % k];
                let o: [f32; 3] = std::array::from_fn(|c| (0..k2).map(|n| e[n] * v(c, n)).sum::<f32>() / sum);
                let g: [f32; 3] = std::array::from_fn(|c| grad[c][y * w + x]);
                for (n, &en) in e.iter().enumerate() {
                    let dot: f32 = (0..3).map(|c| g[c] * (v(c, n) - o[c])).sum();
                    d[n * w + x] = en / sum * dot;
                }
            }
            d
        })
        .collect();
    for (y, d) in rows.iter().enumerate() {
        for n in 0..k2 {
            out[n * plane + y * w..][..w].copy_from_slice(&d[n * w..][..w]);
        }
    }
    out
}

/// The plain per-pixel definition, for tests.
pub fn apply_naive(logits: &[f32], noisy: &[Vec<f32>; 3], k: usize, w: usize, h: usize) -> [Vec<f32>; 3] {
    let r = (k - 1) / 2;
    let pw = w + 2 * r;
    let mut out = [vec![0f32; w * h], vec![0f32; w * h], vec![0f32; w * h]];
    for y in 0..h {
        for x in 0..w {
            let l: Vec<f64> = (0..k * k).map(|n| clamp_logit(logits[n * w * h + y * w + x]) as f64).collect();
            let m = l.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let e: Vec<f64> = l.iter().map(|v| (v - m).exp()).collect();
            let s: f64 = e.iter().sum();
            for c in 0..3 {
                let mut v = 0f64;
                for ky in 0..k {
                    for kx in 0..k {
                        v += e[ky * k + kx] * noisy[c][(y + ky) * pw + x + kx] as f64;
                    }
                }
                out[c][y * w + x] = (v / s) as f32;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn lcg(seed: u64, n: usize, scale: f32) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((s >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * scale
            })
            .collect()
    }

    #[test]
    fn every_instruction_set_matches_the_naive_definition() {
        // Widths around the 8- and 16-pixel vectors; hostile logits in the last case.
        for (k, w, h) in [(5, 7, 4), (3, 19, 3), (5, 33, 2)] {
            let mut logits = lcg(1, k * k * w * h, 8.0);
            if w == 33 {
                for (i, l) in logits.iter_mut().enumerate().step_by(7) {
                    *l = [f32::NAN, 1e30, -1e30, f32::INFINITY, 90.0, -90.0][i % 6];
                }
            }
            let noisy = [0, 1, 2].map(|c| lcg(10 + c, (w + k - 1) * (h + k - 1), 3.0));
            let slow = apply_naive(&logits, &noisy, k, w, h);
            for isa in [simd::Isa::Avx512, simd::Isa::Avx2, simd::Isa::Scalar].into_iter().filter(|i| i.available()) {
                let fast = apply_on(isa, &logits, &noisy, k, w, h);
                for c in 0..3 {
                    for i in 0..w * h {
                        let (a, b) = (fast[c][i], slow[c][i]);
                        assert!((a - b).abs() < 1e-5, "{isa:?} {k}×{k} {w}×{h} channel {c} pixel {i}: {a} vs {b}");
                    }
                }
            }
        }
    }

    #[test]
    fn a_one_hot_kernel_copies_the_neighbour() {
        let (k, w, h) = (3, 4, 3);
        let mut logits = vec![-1e3f32; 9 * w * h];
        // Weight n = 0 is the neighbour at (−1, −1).
        logits[..w * h].fill(50.0);
        let noisy = [0, 1, 2].map(|c| (0..(w + 2) * (h + 2)).map(|i| (i * 3 + c) as f32).collect::<Vec<_>>());
        let out = apply(&logits, &noisy, k, w, h);
        for y in 0..h {
            for x in 0..w {
                assert_eq!(out[1][y * w + x], noisy[1][y * (w + 2) + x]);
            }
        }
    }

    proptest! {
        #[test]
        fn output_within_neighbourhood_range(
            seed in 0u64..1000, scale in prop::sample::select(vec![1.0f32, 100.0, 1e6, 1e30])
        ) {
            let (k, w, h) = (5, 6, 5);
            let mut logits = lcg(seed, k * k * w * h, scale);
            // Hostile logits too.
            logits[3] = f32::NAN;
            logits[7] = f32::INFINITY;
            logits[11] = f32::NEG_INFINITY;
            let noisy = [0, 1, 2].map(|c| lcg(seed * 3 + c, (w + 4) * (h + 4), 10.0));
            let out = apply(&logits, &noisy, k, w, h);
            for c in 0..3 {
                for y in 0..h {
                    for x in 0..w {
                        let nb = (0..k).flat_map(|ky| (0..k).map(move |kx| (ky, kx)))
                            .map(|(ky, kx)| noisy[c][(y + ky) * (w + 4) + x + kx]);
                        let (lo, hi) = nb.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
                        let v = out[c][y * w + x];
                        let tol = 1e-5 * lo.abs().max(hi.abs());
                        prop_assert!(v.is_finite() && v >= lo - tol && v <= hi + tol, "{v} not in [{lo}, {hi}]");
                    }
                }
            }
        }
    }
}
