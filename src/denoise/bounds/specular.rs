//! The specular branch's bound: how far it may move each pixel from its noisy value.

use super::CEILING_RADIUS;
use super::ceiling::{LANES, alike_differences, medians_avx2_or_not, nan_outside, window_offsets};
use crate::features::{Branch, Features, specular_of_log};
use crate::kernel::avx2_or_compiled;
use crate::kernel::planes::Planes;
use crate::model::Architecture;
use rayon::prelude::*;
use std::ops::Range;

/// A 7×7 window is noisy where the median standard error of its alike pixels' means is at
/// least this share of their mean radiance: a glossy surface at a few samples, a field of
/// specks where each sample found the light or missed it. A smooth highlight or a texture
/// at many samples is far below it. Chosen on our Cycles corpus: at 0.3 more specks fill
/// at 4 samples, but some surfaces at 64 lose detail (BENCHMARKS.md).
const NOISY_WINDOW: f32 = 0.6;

/// What bounds how far the specular branch moves each pixel of a band from its noisy value
/// ([`crate::model::Architecture::specular_bound`]): `errors` standard errors of the
/// pixel's mean, from the features (s̃ and its delta-method variance, in the exposed
/// radiance the network sees). A firefly, whose error is about its value, can go; a dark
/// pixel beside it, which no sample of that light reached, cannot take its energy; a
/// texture every sample saw keeps its detail. A value may always come down to the
/// `fine-pairs-twice` clamp of its neighbourhood, so that an outlier the file's variance
/// does not show (a speck added after rendering) goes too.
///
/// In a noisy window ([`NOISY_WINDOW`]) a pixel's own variance says little: a speck that
/// no sample of a glossy reflection reached has none, though its neighbours show the
/// surface is lit. There the standard error is at least the median of its alike
/// neighbours' (albedo and normal, 7×7), so the branch may fill the specks; one firefly
/// among dark pixels does not move that median.
pub(crate) struct NoisySpecular {
    pub(super) errors: f32,
    /// Rows of the noisy radiance (of s̃).
    pub(super) noisy: [Vec<f32>; 3],
    /// The variance of s̃, at least its noisy window's median (see above).
    pub(super) variance: Vec<f32>,
    /// The noisy radiance clamped to its neighbourhood's second-brightest, twice.
    pub(super) clamped: [Vec<f32>; 3],
}

impl NoisySpecular {
    /// The bound of `arch`, if it has one, over rows `rows` of the region `f` holds (whose
    /// rows beyond them, [`CEILING_RADIUS`] at least where the frame goes on, are the
    /// windows' and the clamp's context).
    pub(super) fn of(arch: &Architecture, f: &Features, rows: Range<usize>) -> Option<NoisySpecular> {
        let errors = arch.specular_bound? as f32;
        let (w, s) = (f.width, f.colour(Branch::Specular));
        let pixels = rows.start * w..rows.end * w;
        let mut radiance = Vec::with_capacity(3 * w * f.height);
        for p in s {
            radiance.par_extend(p.par_iter().map(|&v| specular_of_log(v)));
        }
        let noisy = Planes::from_vec(3, w, f.height, radiance);
        let clamped = noisy.clamp_to_second_neighbour().clamp_to_second_neighbour();
        let rows_of = |p: &Planes| std::array::from_fn(|c| p.plane(c)[pixels.clone()].to_vec());
        Some(NoisySpecular {
            errors,
            variance: variance_in_noisy_windows(f, &noisy, rows),
            noisy: rows_of(&noisy),
            clamped: rows_of(&clamped),
        })
    }

    /// Bounds `specular` (the branch's output as exposed radiance, these rows) in place.
    pub(crate) fn apply(&self, specular: &mut [Vec<f32>; 3]) {
        const CHUNK: usize = 1 << 14;
        let [s0, s1, s2] = specular;
        let chunks = s0.par_chunks_mut(CHUNK).zip(s1.par_chunks_mut(CHUNK)).zip(s2.par_chunks_mut(CHUNK));
        chunks.enumerate().for_each(|(t, ((s0, s1), s2))| {
            let out = [s0, s1, s2];
            for k in 0..out[0].len() {
                let i = t * CHUNK + k;
                let noisy: [f32; 3] = std::array::from_fn(|c| self.noisy[c][i]);
                let reach = self.errors * self.variance[i].max(0.0).sqrt() * delta_scale(noisy);
                for (c, n) in noisy.into_iter().enumerate() {
                    let down = reach.max(n - self.clamped[c][i]);
                    // `max`/`min` rather than `clamp`, which panics on a NaN bound (hostile
                    // input).
                    let out = &mut out[c][k];
                    *out = n + (*out - n).max(-down).min(reach);
                }
            }
        });
    }
}

/// What turns the features' standard error of s̃ back into one of the radiance: the
/// features' delta method divided the variance by the mean of (1 + s)² over the channels.
fn delta_scale(noisy: [f32; 3]) -> f32 {
    1.0 + noisy.iter().map(|v| v.max(0.0)).sum::<f32>() / 3.0
}

/// The variance of s̃ over rows `rows` of the region `f` holds, each pixel's at least the
/// median of its alike neighbours' (7×7) where their window is noisy ([`NOISY_WINDOW`],
/// judged in radiance). `noisy` is the region's radiance. The window is visited one offset
/// at a time along the whole row, so that the test of which neighbours count vectorises,
/// and so is whether a window is noisy, by counting ([`median_root_reaches`]); only a noisy
/// window's median variance is found pixel by pixel.
fn variance_in_noisy_windows(f: &Features, noisy: &Planes, rows: Range<usize>) -> Vec<f32> {
    let (w, h, r) = (f.width, f.height, CEILING_RADIUS);
    let side = 2 * r + 1;
    let variance = f.variance(Branch::Specular);
    // Each pixel's delta-method scale, once, on the rows the windows read.
    let read = rows.start.saturating_sub(r) * w..(rows.end + r).min(h) * w;
    let mut scale = vec![0f32; w * h];
    scale[read.clone()]
        .par_iter_mut()
        .zip(read)
        .for_each(|(m, j)| *m = delta_scale(std::array::from_fn(|c| noisy.plane(c)[j])));
    let (albedo, normal) = (&f.albedo, &f.normal);
    let planes: [&[f32]; 8] =
        [variance, &scale, &albedo[0], &albedo[1], &albedo[2], &normal[0], &normal[1], &normal[2]];
    let (pass, ranks, medians) = (alike_pass_avx2_or_not(), ranks_avx2_or_not(), medians_avx2_or_not());
    let mut out = variance[rows.start * w..rows.end * w].to_vec();
    out.par_chunks_mut(w).zip(rows).for_each_init(WindowScratch::default, |s, (out, y)| {
        for sums in [&mut s.radiance, &mut s.count, &mut s.threshold, &mut s.nan_first, &mut s.numbers, &mut s.short] {
            sums.clear();
            sums.resize(w, 0.0);
        }
        for chosen in [&mut s.variances, &mut s.radiance_variances] {
            nan_outside((w, h), y, r, chosen);
        }
        window_offsets((w, h), y, r, 0..w, |offset, xs, there| {
            let [_, _, a0i, a1i, a2i, n0i, n1i, n2i] = planes.map(|p| &p[y * w..][xs.clone()]);
            let there = planes.map(|p| &p[there..][..xs.len()]);
            pass(
                [a0i, a1i, a2i, n0i, n1i, n2i],
                there,
                &mut s.radiance[xs.clone()],
                &mut s.count[xs.clone()],
                &mut s.variances[offset * w..][xs.clone()],
                &mut s.radiance_variances[offset * w..][xs],
            );
        });
        // The root of the lower median each window's radiance variances must reach.
        for ((t, &radiance), &n) in s.threshold.iter_mut().zip(&s.radiance).zip(&s.count) {
            *t = NOISY_WINDOW * radiance / n;
        }
        for o in 0..side * side {
            let chosen = o * w..(o + 1) * w;
            ranks(
                [&s.variances[chosen.clone()], &s.radiance_variances[chosen], &s.threshold],
                &mut s.nan_first,
                &mut s.numbers,
                &mut s.short,
            );
        }
        s.noisy.clear();
        s.noisy.extend((0..w).filter(|&x| {
            median_root_reaches([s.count[x], s.nan_first[x], s.numbers[x], s.short[x]].map(|k| k as usize))
        }));
        // The lower median, as chosen: where as many neighbours are lit as dark, the upper
        // one lifted a surface's dark texels at 64 samples.
        let mut lower = [0f32; LANES];
        for xs in s.noisy.chunks(LANES) {
            medians(&s.variances, w, xs, false, &mut lower);
            xs.iter().zip(lower).for_each(|(&x, m)| out[x] = out[x].max(m));
        }
    });
    out
}

/// Per worker, what [`variance_in_noisy_windows`] gathers over a row: per pixel, the sum
/// of its counted neighbours' radiance, their count, the threshold of its window, and the
/// counts of their radiance variances that [`ranks`] keeps; per offset of the
/// window, the variance of s̃ of each pixel's neighbour there and the radiance's, where
/// that neighbour is alike and its variance finite (else NaN).
#[derive(Default)]
struct WindowScratch {
    radiance: Vec<f32>,
    count: Vec<f32>,
    threshold: Vec<f32>,
    nan_first: Vec<f32>,
    numbers: Vec<f32>,
    short: Vec<f32>,
    variances: Vec<f32>,
    radiance_variances: Vec<f32>,
    /// The pixels whose window is noisy.
    noisy: Vec<usize>,
}

/// Whether the root of the lower median of a pixel's counted radiance variances reaches its
/// threshold, from `[counted, nan_first, numbers, short]` as [`ranks`] counts them: in
/// the median's order (`f32::total_cmp`: NaNs with the sign bit, then numbers
/// ascending, then the other NaNs) the numbers whose root falls short come first among
/// the numbers (the root is monotone), so the median's place among the counts says it,
/// without ordering the window. False where none counts.
fn median_root_reaches([counted, nan_first, numbers, short]: [usize; 4]) -> bool {
    let lower = counted.saturating_sub(1) / 2;
    counted > 0 && nan_first + short <= lower && lower < nan_first + numbers
}

avx2_or_compiled!(
    /// [`ranks`], chosen once per bound.
    type Ranks;
    fn ranks_avx2_or_not() = ranks(
        window: [&[f32]; 3],
        nan_first: &mut [f32],
        numbers: &mut [f32],
        short: &mut [f32],
    )
);

/// Counts, for one offset of the window and each pixel of a row, where its neighbour
/// there (`window`: its variance, counted where not NaN, its radiance's variance, and the
/// pixel's threshold) falls among the window's radiance variances in the median's
/// order: a NaN with the sign bit (first, into `nan_first`), a number (`numbers`), and a
/// number whose root falls short of the threshold (`short`). Branch-free, so that it
/// vectorises.
#[inline(always)]
fn ranks(
    [variances, radiance_variances, threshold]: [&[f32]; 3],
    nan_first: &mut [f32],
    numbers: &mut [f32],
    short: &mut [f32],
) {
    let n = variances.len();
    let (radiance_variances, threshold) = (&radiance_variances[..n], &threshold[..n]);
    let (nan_first, numbers, short) = (&mut nan_first[..n], &mut numbers[..n], &mut short[..n]);
    for k in 0..n {
        let (counts, v) = (!variances[k].is_nan(), radiance_variances[k]);
        let number = counts & !v.is_nan();
        nan_first[k] += if counts & v.is_nan() & v.is_sign_negative() { 1.0 } else { 0.0 };
        numbers[k] += if number { 1.0 } else { 0.0 };
        // False against a NaN threshold too: no root reaches it.
        let reaches = v.sqrt() >= threshold[k];
        short[k] += if number & !reaches { 1.0 } else { 0.0 };
    }
}

avx2_or_compiled!(
    /// The test of [`variance_in_noisy_windows`] at one offset: for each pixel of `here`
    /// (albedo RGB, normal XYZ) and its neighbour at the same place in `there` (variance of
    /// s̃, delta-method scale, albedo RGB, normal XYZ), whether the neighbour counts (alike,
    /// its variance finite): then its radiance is added to `radiance` and 1 to `count`, its
    /// variance goes into `variances` and its radiance's into `radiance_variances`; else NaN
    /// goes into both.
    type AlikePass;
    fn alike_pass_avx2_or_not() = add_alike(
        here: [&[f32]; 6],
        there: [&[f32]; 8],
        radiance: &mut [f32],
        count: &mut [f32],
        variances: &mut [f32],
        radiance_variances: &mut [f32],
    )
);

/// See [`AlikePass`]. Every row it writes is a parameter of its own, so that the compiler
/// knows they do not overlap what is read.
#[inline(always)]
fn add_alike(
    [a0i, a1i, a2i, n0i, n1i, n2i]: [&[f32]; 6],
    [v, m, a0j, a1j, a2j, n0j, n1j, n2j]: [&[f32]; 8],
    radiance: &mut [f32],
    count: &mut [f32],
    variances: &mut [f32],
    radiance_variances: &mut [f32],
) {
    // Each slice cut to the same length, one by one: the compiler then drops the bounds
    // checks and vectorises (slices cut through an array's `map` leave it scalar).
    let n = radiance.len();
    let (a0i, a1i, a2i, n0i, n1i, n2i) = (&a0i[..n], &a1i[..n], &a2i[..n], &n0i[..n], &n1i[..n], &n2i[..n]);
    let (v, m, a0j, a1j, a2j, n0j, n1j, n2j) =
        (&v[..n], &m[..n], &a0j[..n], &a1j[..n], &a2j[..n], &n0j[..n], &n1j[..n], &n2j[..n]);
    let (count, variances, radiance_variances) = (&mut count[..n], &mut variances[..n], &mut radiance_variances[..n]);
    for k in 0..n {
        let alike = alike_differences(
            [a0j[k] - a0i[k], a1j[k] - a1i[k], a2j[k] - a2i[k]],
            [n0j[k] - n0i[k], n1j[k] - n1i[k], n2j[k] - n2i[k]],
        );
        let counts = (v[k] >= 0.0) & v[k].is_finite() & alike;
        // Selected, not multiplied: a neighbour that does not count adds nothing.
        radiance[k] += if counts { m[k] - 1.0 } else { 0.0 };
        count[k] += if counts { 1.0 } else { 0.0 };
        variances[k] = if counts { v[k] } else { f32::NAN };
        radiance_variances[k] = if counts { v[k] * m[k] * m[k] } else { f32::NAN };
    }
}

/// The lower median of `v` (reordered); NaN when empty: what the row pass's medians
/// ([`super::ceiling::medians_avx2_or_not`]) must equal, pixel by pixel.
#[cfg(test)]
fn lower_median(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return f32::NAN;
    }
    *v.select_nth_unstable_by((v.len() - 1) / 2, f32::total_cmp).1
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::denoise::bounds::tests::{hash, hostile};

    /// A bound of 2 errors over pixels of noisy radiance `noisy`, standard error `error`
    /// and clamped value `clamped` (one value for all three channels).
    pub(crate) fn bound(noisy: &[f32], error: &[f32], clamped: &[f32]) -> NoisySpecular {
        let n = noisy.len();
        let m = |i: usize| 1.0 + noisy[i];
        NoisySpecular {
            errors: 2.0,
            noisy: std::array::from_fn(|_| noisy.to_vec()),
            variance: (0..n).map(|i| (error[i] / m(i)).powi(2)).collect(),
            clamped: std::array::from_fn(|_| clamped.to_vec()),
        }
    }

    /// [`variance_in_noisy_windows`] pixel by pixel: a gather of each window, as the row
    /// pass must equal bit for bit.
    fn variance_pixel_by_pixel(f: &Features, noisy: &Planes, rows: Range<usize>) -> Vec<f32> {
        let (w, h, r) = (f.width, f.height, CEILING_RADIUS);
        let variance = f.variance(Branch::Specular);
        let scale: Vec<f32> = (0..w * h).map(|j| delta_scale(std::array::from_fn(|c| noisy.plane(c)[j]))).collect();
        let alike = |i: usize, j: usize| {
            let (a, n) = (&f.albedo, &f.normal);
            alike_differences(std::array::from_fn(|c| a[c][j] - a[c][i]), std::array::from_fn(|c| n[c][j] - n[c][i]))
        };
        let mut out = variance[rows.start * w..rows.end * w].to_vec();
        for (out, y) in out.chunks_mut(w).zip(rows) {
            for (x, out) in out.iter_mut().enumerate() {
                let i = y * w + x;
                let (mut variances, mut radiance_variances, mut radiance) = (Vec::new(), Vec::new(), 0f32);
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for j in yy * w + x.saturating_sub(r)..yy * w + (x + r + 1).min(w) {
                        let (v, m) = (variance[j], scale[j]);
                        if v >= 0.0 && v.is_finite() && alike(i, j) {
                            variances.push(v);
                            radiance_variances.push(v * m * m);
                            radiance += m - 1.0;
                        }
                    }
                }
                let n = variances.len() as f32;
                if lower_median(&mut radiance_variances).sqrt() >= NOISY_WINDOW * radiance / n {
                    *out = out.max(lower_median(&mut variances));
                }
            }
        }
        out
    }

    #[test]
    fn the_row_pass_gives_the_pixel_by_pixel_variance_bit_for_bit() {
        // Two surfaces, a glossy field of specks and smooth highlights, and hostile values
        // scattered over every plane.
        let (w, h) = (21, 13);
        let hostile = |i: usize, k: usize, v: f32| hostile(i, k, v, 37);
        let mut f = Features::new(&crate::features::tests::inputs(w, h, |_| 0.0));
        // Hostile radiance only in the last rows: one infinite value makes its windows'
        // mean infinite, and none of them noisy.
        let s = |i: usize, c: usize| match (hash(i, 7) < 0.6, i / w > 10) {
            (true, true) => hostile(i, c, 3.0 * hash(i, c)),
            (true, false) => 3.0 * hash(i, c),
            (false, _) => 0.0,
        };
        f.s_tilde = std::array::from_fn(|c| (0..w * h).map(|i| s(i, c).ln_1p()).collect());
        f.s_variance = (0..w * h).map(|i| hostile(i, 3, if i % w < 10 { 0.3 } else { 0.001 } * hash(i, 4))).collect();
        f.albedo = std::array::from_fn(|c| {
            (0..w * h).map(|i| hostile(i, c + 11, if i / w < 6 { 0.5 } else { 0.8 + 0.01 * c as f32 })).collect()
        });
        f.normal =
            std::array::from_fn(|c| (0..w * h).map(|i| hostile(i, c + 5, (i % w) as f32 * 0.05 * c as f32)).collect());
        let radiance: Vec<f32> = f.s_tilde.iter().flat_map(|p| p.iter().map(|&v| specular_of_log(v))).collect();
        let noisy = Planes::from_vec(3, w, h, radiance);
        for rows in [0..h, 3..9] {
            let want = variance_pixel_by_pixel(&f, &noisy, rows.clone());
            let got = variance_in_noisy_windows(&f, &noisy, rows.clone());
            assert_eq!(
                got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                want.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            );
            // Some windows are noisy: their pixels' variances were raised.
            let own = &f.s_variance[rows.start * w..rows.end * w];
            assert!(want.iter().zip(own).any(|(a, b)| a > b), "{rows:?}");
        }
    }

    #[test]
    fn counting_says_what_the_lower_median_says() {
        // Windows of 1 to 49 values drawn from numbers, zeros of both signs, infinities and
        // NaNs of both signs (at run time on x86, 0 × ∞ is a NaN with the sign bit: a
        // neighbour without variance beside an infinite radiance), against thresholds
        // below, at and above them.
        let pool = [0.0, -0.0, 0.25, 1.0, 4.0, 9.0, f32::INFINITY, f32::NAN, -f32::NAN, 0.0 * f32::INFINITY, 1e-30];
        let thresholds = [0.0, -0.0, 0.5, 1.0, 2.0, 3.0, 1e-15, f32::INFINITY, f32::NAN];
        for n in 1..=49usize {
            for seed in 0..40usize {
                let v: Vec<f32> = (0..n).map(|k| pool[(k * 7 + seed * 13 + k * k * seed) % pool.len()]).collect();
                for &t in &thresholds {
                    let mut counts = [n, 0, 0, 0];
                    for &value in &v {
                        let mut found = [0f32; 3];
                        let [first, numbers, short] = found.each_mut().map(std::slice::from_mut);
                        ranks([&[1.0], &[value], &[t]], first, numbers, short);
                        (0..3).for_each(|k| counts[k + 1] += found[k] as usize);
                    }
                    let want = lower_median(&mut v.clone()).sqrt() >= t;
                    assert_eq!(median_root_reaches(counts), want, "{v:?} against {t}");
                }
            }
        }
        assert!(!median_root_reaches([0, 0, 0, 0]), "no neighbour counts");
    }

    #[test]
    fn the_specular_branch_moves_a_pixel_at_most_two_of_its_errors_but_outliers_go() {
        // 0: a dark pixel that no sample of a light reached takes no light from its
        //    neighbour (error 0.01: up to 0.02 more);
        // 1: a firefly whose error is its size goes;
        // 2: a speck the variance does not show still goes down to its clamped value;
        // 3: a texture pixel every sample saw keeps its detail (moved 0.1 of its 0.5 asked);
        // 4: a move within the bound is kept as it is.
        let b = bound(&[0.05, 80.0, 500.0, 1.0, 1.0], &[0.01, 80.0, 0.1, 0.05, 0.5], &[0.05, 0.3, 0.2, 1.0, 1.0]);
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![2.0, 0.5, 0.2, 0.5, 1.6]);
        b.apply(&mut out);
        let want = [0.07, 0.5, 0.2, 0.9, 1.6];
        for (o, w) in out[0].iter().zip(want) {
            assert!((o - w).abs() < 1e-3 * w.max(1.0), "{:?} against {want:?}", out[0]);
        }
        assert_eq!(out[0], out[2]);
    }

    /// The bound (2 errors) over a 12×12 frame of one surface whose pixel `i` shows
    /// specular radiance `s(i)` with standard error `error(i)`, all rows.
    fn bound_of_frame(s: impl Fn(usize) -> f32, error: impl Fn(usize) -> f32) -> NoisySpecular {
        let mut f = Features::new(&crate::features::tests::inputs(12, 12, |_| 0.0));
        f.s_tilde = std::array::from_fn(|_| (0..144).map(|i| s(i).ln_1p()).collect());
        f.s_variance = (0..144).map(|i| (error(i) / (1.0 + s(i))).powi(2)).collect();
        let arch = Architecture { specular_bound: Some(2), ..Architecture::ladder(crate::model::Quality::Fast) };
        NoisySpecular::of(&arch, &f, 0..12).unwrap()
    }

    #[test]
    fn specks_of_a_noisy_glossy_surface_may_fill_and_dark_beside_a_lone_firefly_may_not() {
        // A glossy surface at 4 samples: two pixels in three caught the reflection (2 ± 1),
        // the others none (0 ± 0). A speck takes its neighbours' standard error of s̃,
        // ln(1 + 2 ± 1) ≈ ± 1/3, so it may rise to 2 × 1/3 (asked 1).
        let lit = |i: usize| !i.is_multiple_of(3);
        let specks = bound_of_frame(|i| if lit(i) { 2.0 } else { 0.0 }, |i| if lit(i) { 1.0 } else { 0.0 });
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![1.0; 144]);
        specks.apply(&mut out);
        let speck = 5 * 12 + 6;
        assert!((out[0][speck] - 2.0 / 3.0).abs() < 1e-4, "a speck stays at {}", out[0][speck]);
        // One firefly (50 ± 50) among dark pixels that each sample saw (0.05 ± 0.01): its
        // neighbours keep their own bound.
        let firefly =
            bound_of_frame(|i| if i == speck { 50.0 } else { 0.05 }, |i| if i == speck { 50.0 } else { 0.01 });
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![5.0; 144]);
        firefly.apply(&mut out);
        assert!((out[0][speck + 1] - 0.07).abs() < 1e-4, "the firefly's neighbour took {}", out[0][speck + 1]);
        assert!((out[0][speck] - 5.0).abs() < 1e-4, "the firefly stays at {}", out[0][speck]);
    }
}
