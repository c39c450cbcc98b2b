//! The detail the diffuse branch smoothed away, restored
//! ([`crate::model::Architecture::diffuse_detail`]). The network's kernels average a bumpy
//! surface's shading flat: its irradiance follows the shading normal from pixel to pixel,
//! and the kernels see that in the normals but keep too little of it (on our Cycles
//! corpus, most of `balanced`'s error on bump-mapped floors). What the noisy d̃ shows
//! beyond d̂ is that detail plus noise; over each window, the part of it that follows the
//! normals, fitted by least squares (a guided filter on the residual, guided by the
//! normal), is the detail, and the noise, which does not follow the normals, stays out.

use super::{BandPlanes, box_means};
use crate::kernel::avx2_or_compiled;
use rayon::prelude::*;

/// Added to the normals' covariance over a window before it is inverted: where the normals
/// barely vary (a flat wall), no noise is read as detail. Chosen on our own Cycles corpus,
/// simulator frames and crops (BENCHMARKS.md, "The diffuse detail restored").
const RIDGE: f32 = 0.01;

/// A pixel's detail moves it towards its noisy value, never away from it by more than this
/// many standard errors of that value (from its variance, or its window's mean variance if
/// that is more: a pixel whose few samples all saw nothing has no variance, yet is as noisy
/// as its neighbours): where the fit says more, its window straddles light the kernels got
/// wrong (the edge of a sun stripe), not detail.
const AWAY_ERRORS: f32 = 2.0;

/// What [`Detail::restore`] reads of rows of a band, each plane `[pixel]`: d̂ within its
/// ceiling (planes 0–2), the noisy d̃ (3–5), the shading normal (6–8) and the variance of
/// d̃ (9), exposed.
pub(crate) type Detail = BandPlanes<10>;

/// Output rows [`Detail::restore`] works on at a time, per this many pixels: its sums and
/// fits hold about 48 floats per pixel of a chunk (and its 4r rows of context), so a band
/// of any height holds them for a few hundred thousand pixels, not for all of its own.
const CHUNK_PIXELS: usize = 1 << 18;

impl Detail {
    /// [`restore_rows`] of every row, in chunks of about [`CHUNK_PIXELS`], each
    /// with the 2r rows above and below that its windows' windows reach: the same values,
    /// bit for bit, in a bounded working set.
    pub(crate) fn restore(&self, w: usize, r: usize) -> [Vec<f32>; 3] {
        self.restore_in_chunks(w, r, (CHUNK_PIXELS / w.max(1)).max(4 * r).max(1))
    }

    fn restore_in_chunks(&self, w: usize, r: usize, chunk: usize) -> [Vec<f32>; 3] {
        let rows = self.height(w);
        // The planes' rows `span`, borrowed.
        let view = |span: std::ops::Range<usize>| std::array::from_fn(|c| &self.0[c][span.start * w..span.end * w]);
        if rows <= chunk {
            return restore_rows(view(0..rows), w, r);
        }
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| Vec::with_capacity(w * rows));
        for a in (0..rows).step_by(chunk) {
            let b = (a + chunk).min(rows);
            let span = a.saturating_sub(2 * r)..(b + 2 * r).min(rows);
            let part = restore_rows(view(span.clone()), w, r);
            for (o, p) in out.iter_mut().zip(&part) {
                o.extend_from_slice(&p[(a - span.start) * w..(b - span.start) * w]);
            }
        }
        out
    }
}

/// The detail of [`Detail::restore`] over rows of the planes `planes` (as [`Detail`]'s),
/// `w` wide, from windows of radius `r`: over the window around each pixel, the residual
/// (noisy d̃ − d̂, each channel held within ±d̂, so that a firefly weighs no more than the
/// light beside it) is fitted by least squares to the normals; each pixel gets the mean
/// over the windows around it of their fits' slopes, times how far its normal is from its
/// window's mean normal. Between 0 and the residual, widened by [`AWAY_ERRORS`] standard
/// errors, and within ±d̂ per channel; 0 where an input is not finite. Exact for rows whose
/// windows' windows (2r rows each side) lie within these rows or beyond the frame's edges;
/// each sum in the same order whatever the rows are, so that bands of a frame get what the
/// whole frame would, bit for bit.
fn restore_rows(planes: [&[f32]; 10], w: usize, r: usize) -> [Vec<f32>; 3] {
    let rows = planes[0].len() / w.max(1);
    let finite = |v: f32| if v.is_finite() { v } else { 0.0 };
    let d_hat = &planes[..3];
    let residual: Vec<Vec<f32>> = (0..3)
        .map(|c| {
            let (d, noisy) = (planes[c], planes[3 + c]);
            d.par_iter()
                .zip(noisy)
                .map(|(&d, &n)| if d.is_finite() { finite((n - d).clamp(-d.abs(), d.abs())) } else { 0.0 })
                .collect()
        })
        .collect();
    let normal: Vec<Vec<f32>> = planes[6..9].iter().map(|p| p.par_iter().map(|&v| finite(v)).collect()).collect();
    let count = window_counts(w, r, rows);
    let mean = |plane: &[f32]| box_means(w, r, rows, Some(&count), |y, _| Some(&plane[y * w..(y + 1) * w]));
    // The mean of the product of two planes, each row's product made where it is summed.
    let mean_product = |a: &[f32], b: &[f32]| {
        box_means(w, r, rows, Some(&count), |y, scratch| {
            let at = y * w..(y + 1) * w;
            scratch.iter_mut().zip(&a[at.clone()]).zip(&b[at]).for_each(|((s, a), b)| *s = a * b);
            None
        })
    };
    let g: Vec<Vec<f32>> = normal.iter().map(|p| mean(p)).collect();
    let e: Vec<Vec<f32>> = residual.iter().map(|p| mean(p)).collect();
    let variance: Vec<f32> = planes[9].par_iter().map(|&v| finite(v).max(0.0)).collect();
    let noise = mean(&variance);
    // Second moments over each window: normals with normals (j ≤ k), normals with the
    // residual.
    let gg: Vec<Vec<f32>> = PAIRS.iter().map(|&(j, k)| mean_product(&normal[j], &normal[k])).collect();
    let ge: Vec<Vec<f32>> = (0..9).map(|i| mean_product(&normal[i / 3], &residual[i % 3])).collect();
    // Each window's slopes, row by row: plane j * 3 + c of row y's block is the
    // residual's channel c per unit of normal component j.
    let n = w * rows;
    let (fit, ridge) = (fit_slopes_avx2_or_not(), f64::from(RIDGE));
    let mut fits = vec![0f32; 9 * n];
    fits.par_chunks_mut(9 * w).enumerate().for_each(|(y, block)| {
        let at = y * w..(y + 1) * w;
        let mut rest = block;
        let out: [&mut [f32]; 9] = std::array::from_fn(|_| {
            let (plane, tail) = std::mem::take(&mut rest).split_at_mut(w);
            rest = tail;
            plane
        });
        fit(
            std::array::from_fn(|j| &g[j][at.clone()]),
            std::array::from_fn(|c| &e[c][at.clone()]),
            std::array::from_fn(|p| &gg[p][at.clone()]),
            std::array::from_fn(|i| &ge[i][at.clone()]),
            ridge,
            out,
        );
    });
    drop((e, gg, ge));
    // The mean over the windows around each pixel of their slopes, one plane at a time.
    let slope: Vec<Vec<f32>> =
        (0..9).map(|k| box_means(w, r, rows, Some(&count), |y, _| Some(&fits[(9 * y + k) * w..][..w]))).collect();
    drop(fits);
    // The three channels side by side, in runs of a row's length: what they share (the
    // normal's distance from its window's mean, the bound's width) is read and made once,
    // and the loop over a run vectorises.
    let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0f32; n]);
    let [o0, o1, o2] = &mut out;
    let run = w.max(1);
    o0.par_chunks_mut(run).zip(o1.par_chunks_mut(run)).zip(o2.par_chunks_mut(run)).enumerate().for_each(
        |(t, ((o0, o1), o2))| {
            let at = t * run..t * run + o0.len();
            let [n0, n1, n2] = [0, 1, 2].map(|j| &normal[j][at.clone()]);
            let [g0, g1, g2] = [0, 1, 2].map(|j| &g[j][at.clone()]);
            let (variance, noise) = (&variance[at.clone()], &noise[at.clone()]);
            let slope: [&[f32]; 9] = std::array::from_fn(|k| &slope[k][at.clone()]);
            let residual: [&[f32]; 3] = std::array::from_fn(|c| &residual[c][at.clone()]);
            let d_hat: [&[f32]; 3] = std::array::from_fn(|c| &d_hat[c][at.clone()]);
            let mut out = [o0, o1, o2];
            for x in 0..n0.len() {
                let to = [n0[x] - g0[x], n1[x] - g1[x], n2[x] - g2[x]];
                let away = AWAY_ERRORS * finite(variance[x].max(noise[x]).sqrt());
                for (ch, out) in out.iter_mut().enumerate() {
                    let v: f32 = (0..3).map(|j| slope[j * 3 + ch][x] * to[j]).sum();
                    let (e, bound) = (residual[ch][x], d_hat[ch][x].abs());
                    out[x] = if v.is_finite() && bound.is_finite() {
                        v.clamp(e.min(0.0) - away, e.max(0.0) + away).clamp(-bound, bound)
                    } else {
                        0.0
                    };
                }
            }
        },
    );
    out
}

/// How many pixels of rows `rows`, `w` wide, the window of radius `r` around each holds,
/// cut at their edges: what [`box_means`] of ones would give (exact integers either way).
fn window_counts(w: usize, r: usize, rows: usize) -> Vec<f32> {
    let span = |i: usize, n: usize| ((i + r + 1).min(n) - i.saturating_sub(r)) as f32;
    (0..w * rows).into_par_iter().map(|i| span(i / w, rows) * span(i % w, w)).collect()
}

/// The normal components' pairs (j ≤ k) whose products a window's covariance needs.
const PAIRS: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];

avx2_or_compiled!(
    /// [`fit_slopes`], chosen once per restore.
    type FitSlopes;
    fn fit_slopes_avx2_or_not() = fit_slopes(
        g: [&[f32]; 3],
        e: [&[f32]; 3],
        gg: [&[f32]; 6],
        ge: [&[f32]; 9],
        ridge: f64,
        out: [&mut [f32]; 9],
    )
);

/// Each pixel's window's slopes from its window's means (`g` of the normal's components,
/// `e` of the residual's channels, `gg` of the normals' products in [`PAIRS`]' order,
/// `ge` of normal j times residual c at j · 3 + c): the normals' covariance, `ridge`
/// added to its diagonal, inverted by its cofactors (zero where its determinant is not
/// finite and positive), times the covariance of normals and residual; slope j · 3 + c
/// into `out`. In f64, one pixel after another along the slices, in an order the
/// compiler vectorises.
#[inline(always)]
fn fit_slopes(g: [&[f32]; 3], e: [&[f32]; 3], gg: [&[f32]; 6], ge: [&[f32]; 9], ridge: f64, out: [&mut [f32]; 9]) {
    for i in 0..out[0].len() {
        let g: [f64; 3] = g.map(|p| f64::from(p[i]));
        let mut c = [[0f64; 3]; 3];
        for (p, &(j, k)) in PAIRS.iter().enumerate() {
            let v = f64::from(gg[p][i]) - g[j] * g[k] + if j == k { ridge } else { 0.0 };
            (c[j][k], c[k][j]) = (v, v);
        }
        let cof = |r: usize, q: usize| {
            let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
            let (q0, q1) = ((q + 1) % 3, (q + 2) % 3);
            c[r0][q0] * c[r1][q1] - c[r0][q1] * c[r1][q0]
        };
        let det = (c[0][0] * cof(0, 0) + c[0][1] * cof(0, 1)) + c[0][2] * cof(0, 2);
        let invertible = det.is_finite() && det > 0.0;
        let inverse: [[f64; 3]; 3] =
            std::array::from_fn(|r| std::array::from_fn(|q| if invertible { cof(q, r) / det } else { 0.0 }));
        for ch in 0..3 {
            let e = f64::from(e[ch][i]);
            let b: [f64; 3] = std::array::from_fn(|j| f64::from(ge[j * 3 + ch][i]) - g[j] * e);
            for j in 0..3 {
                out[j * 3 + ch][i] = ((inverse[j][0] * b[0] + inverse[j][1] * b[1]) + inverse[j][2] * b[2]) as f32;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bumpy floor: normals that wander from pixel to pixel, shading that follows them
    /// (light from +x), d̂ smoothed flat, and the noisy d̃ (the shading plus noise of
    /// `noise` standard deviation).
    fn floor(w: usize, h: usize, noise: f32, seed: u64) -> (Detail, Vec<f32>) {
        let mut rng = crate::rng::SplitMix64(seed);
        let mut planes: [Vec<f32>; 10] = std::array::from_fn(|_| vec![0f32; w * h]);
        let mut truth = vec![0f32; w * h];
        for i in 0..w * h {
            let (nx, ny) = (rng.uniform_f32() - 0.5, rng.uniform_f32() - 0.5);
            let nz = (1.0 - nx * nx - ny * ny).sqrt();
            truth[i] = 1.0 + nx;
            for c in 0..3 {
                planes[c][i] = 1.0;
                planes[3 + c][i] = truth[i] + noise * 2.0 * (rng.uniform_f32() - 0.5) * 3f32.sqrt();
            }
            (planes[6][i], planes[7][i], planes[8][i], planes[9][i]) = (nx, ny, nz, noise * noise);
        }
        (BandPlanes(planes), truth)
    }

    fn squared_error(a: &[f32], b: &[f32]) -> f64 {
        a.iter().zip(b).map(|(a, b)| f64::from(a - b).powi(2)).sum()
    }

    /// The inverse of a symmetric 3×3 matrix by its cofactors; zeros where its
    /// determinant is not finite and positive.
    fn invert(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
        let cof = |r: usize, c: usize| {
            let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
            let (c0, c1) = ((c + 1) % 3, (c + 2) % 3);
            m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0]
        };
        let det = (0..3).map(|c| m[0][c] * cof(0, c)).sum::<f64>();
        if !(det.is_finite() && det > 0.0) {
            return [[0.0; 3]; 3];
        }
        std::array::from_fn(|r| std::array::from_fn(|c| cof(c, r) / det))
    }

    /// One pixel's slopes from its window's means, in the order [`fit_slopes`] documents:
    /// what the vectorised loop must give, bit for bit.
    fn fit_pixel(g: [f32; 3], e: [f32; 3], gg: [f32; 6], ge: [f32; 9]) -> [f32; 9] {
        let mut c = [[0f64; 3]; 3];
        for (p, &(j, k)) in PAIRS.iter().enumerate() {
            let v = f64::from(gg[p]) - f64::from(g[j]) * f64::from(g[k]) + if j == k { f64::from(RIDGE) } else { 0.0 };
            (c[j][k], c[k][j]) = (v, v);
        }
        let inverse = invert(&c);
        let mut out = [0f32; 9];
        for ch in 0..3 {
            let b: [f64; 3] = std::array::from_fn(|j| f64::from(ge[j * 3 + ch]) - f64::from(g[j]) * f64::from(e[ch]));
            for j in 0..3 {
                out[j * 3 + ch] = (0..3).map(|k| inverse[j][k] * b[k]).sum::<f64>() as f32;
            }
        }
        out
    }

    #[test]
    fn slopes_are_each_pixels_fit_bit_for_bit() {
        // Moments of real windows, of flat ones (only the ridge keeps them invertible), of
        // impossible ones (a negative variance: no inverse) and of non-finite ones.
        let n = 203;
        let mut rng = crate::rng::SplitMix64(21);
        let mut planes: [Vec<f32>; 21] = std::array::from_fn(|_| Vec::with_capacity(n));
        for i in 0..n {
            let g: [f32; 3] = std::array::from_fn(|_| rng.uniform_f32() - 0.5);
            let e: [f32; 3] = std::array::from_fn(|_| rng.uniform_f32() * 2.0);
            let spread = match i % 4 {
                0 => 0.0,
                1 => -0.5,
                _ => rng.uniform_f32() * 0.2,
            };
            let gg: [f32; 6] = PAIRS.map(|(j, k)| g[j] * g[k] + if j == k { spread } else { spread * 0.3 });
            let ge: [f32; 9] = std::array::from_fn(|q| g[q / 3] * e[q % 3] + rng.uniform_f32() * 0.01);
            let mut all: Vec<f32> = g.into_iter().chain(e).chain(gg).chain(ge).collect();
            if i % 17 == 5 {
                all[i % 21] = [f32::NAN, f32::INFINITY][i % 2];
            }
            planes.iter_mut().zip(all).for_each(|(p, v)| p.push(v));
        }
        for fit in [fit_slopes_avx2_or_not(), fit_slopes as FitSlopes] {
            let mut out: [Vec<f32>; 9] = std::array::from_fn(|_| vec![0f32; n]);
            let [o0, o1, o2, o3, o4, o5, o6, o7, o8] = &mut out;
            let p = |k: usize| planes[k].as_slice();
            fit(
                std::array::from_fn(p),
                std::array::from_fn(|c| p(3 + c)),
                std::array::from_fn(|q| p(6 + q)),
                std::array::from_fn(|q| p(12 + q)),
                f64::from(RIDGE),
                [o0, o1, o2, o3, o4, o5, o6, o7, o8].map(|o| o.as_mut_slice()),
            );
            for i in 0..n {
                let at = |k: usize| planes[k][i];
                let want = fit_pixel(
                    std::array::from_fn(at),
                    std::array::from_fn(|c| at(3 + c)),
                    std::array::from_fn(|q| at(6 + q)),
                    std::array::from_fn(|q| at(12 + q)),
                );
                for (k, w) in want.iter().enumerate() {
                    assert_eq!(out[k][i].to_bits(), w.to_bits(), "pixel {i}, slope {k}");
                }
            }
        }
    }

    #[test]
    fn window_counts_are_the_box_sums_of_ones() {
        for (w, rows, r) in [(1, 1, 7), (5, 3, 1), (23, 17, 7), (40, 9, 20)] {
            let ones = super::super::box_sums(&vec![1f32; w * rows], w, r, rows);
            assert_eq!(window_counts(w, r, rows), ones, "{w}×{rows}, r {r}");
        }
    }

    #[test]
    fn shading_that_follows_the_normals_comes_back_and_noise_stays_out() {
        let (w, h) = (40, 30);
        let (floor, truth) = floor(w, h, 0.1, 1);
        let detail = floor.restore(w, 7);
        for (c, detail) in detail.iter().enumerate() {
            let restored: Vec<f32> = floor.0[c].iter().zip(detail).map(|(d, e)| d + e).collect();
            let (before, after) = (squared_error(&floor.0[c], &truth), squared_error(&restored, &truth));
            assert!(after < before / 10.0, "channel {c}: {before} → {after}");
            // Never nearer the noisy input than to the truth: its noise stays out.
            assert!(after < squared_error(&floor.0[3 + c], &truth) / 5.0);
        }
        // A pixel whose noisy value equals d̂ moves towards its fit at most two standard
        // errors of its window's noise (0.1 here).
        let at = (0..w * h).max_by(|&a, &b| detail[0][a].abs().total_cmp(&detail[0][b].abs())).unwrap();
        let mut exact = floor.clone();
        for c in 0..3 {
            exact.0[3 + c][at] = exact.0[c][at];
        }
        let moved = exact.restore(w, 7)[0][at];
        assert!(detail[0][at].abs() > 0.3 && moved.abs() <= 0.2 + 1e-3, "{} → {moved}", detail[0][at]);
        // Noise alone, on a flat wall (every normal alike), restores nothing.
        let mut wall = floor.clone();
        for (p, v) in wall.0[6..9].iter_mut().zip([0.0, 0.0, 1.0]) {
            p.fill(v);
        }
        assert!(wall.restore(w, 7).iter().flatten().all(|&v| v == 0.0));
    }

    #[test]
    fn a_band_gets_what_the_whole_frame_does_bit_for_bit() {
        let (w, h, r) = (23, 50, 3usize);
        let (whole, _) = floor(w, h, 0.3, 2);
        let all = whole.restore(w, r);
        for band in [0..9usize, 9..30, 30..50, 20..21] {
            let rows = band.start.saturating_sub(2 * r)..(band.end + 2 * r).min(h);
            let out = whole.rows(rows.clone(), w).restore(w, r);
            for c in 0..3 {
                let (a, b) = (band.start - rows.start, band.end - rows.start);
                assert_eq!(out[c][a * w..b * w], all[c][band.start * w..band.end * w], "{band:?}");
            }
        }
        let (top, bottom) = (whole.rows(0..20, w), whole.rows(20..50, w));
        assert_eq!(top.then(&bottom).restore(w, r), all);
        // In chunks of rows, shorter and longer than the windows' reach: the same bits.
        for chunk in [1, 7, 12, 49] {
            assert_eq!(whole.restore_in_chunks(w, r, chunk), all, "chunks of {chunk} rows");
        }
    }

    #[test]
    fn hostile_values_restore_finite_detail_within_d_hat() {
        let (w, h) = (12, 9);
        let (mut f, _) = floor(w, h, 0.5, 3);
        let hostile = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 3e38, -3e38, 1e-30];
        for (i, &v) in hostile.iter().enumerate() {
            f.0[i % 10][i * 13 % (w * h)] = v;
            f.0[3 + i % 3][i * 7 % (w * h)] = v;
        }
        let detail = f.restore(w, 2);
        for (c, detail) in detail.iter().enumerate() {
            for (i, &v) in detail.iter().enumerate() {
                let d = f.0[c][i];
                assert!(v.is_finite() && (v.abs() <= d.abs() || !d.is_finite() && v == 0.0), "({c}, {i}): {v} on {d}");
            }
        }
    }
}
