//! The diffuse ceiling ([`DiffuseCeiling`]): the most the diffuse branch may brighten each
//! pixel, from the noisy light of its similar neighbours.

mod median;
mod rows;
pub(super) use median::{LANES, medians_avx2_or_not};

use super::Bounds;
use crate::features::Features;
use crate::model::{Architecture, Variances};
use rayon::prelude::*;
use rows::{DenseScratch, Passes, Planes, SUMS, column_runs, dense_row, lit_in_window_row, window_row_sums};
pub(super) use rows::{nan_outside, window_offsets};
use std::ops::Range;

/// Half the side of the window a pixel's similar neighbours are sought in (7×7).
pub(crate) const CEILING_RADIUS: usize = 3;
/// Similar neighbours' albedos differ by at most this in every channel,
const SIMILAR_ALBEDO: f32 = 0.1;
/// their normals are at most this far apart,
const SIMILAR_NORMAL: f32 = 0.6;
/// and their noisy values (d̃, mean of the channels) differ by at most this many
/// standard errors of the difference.
const SIMILAR_ERRORS: f32 = 2.0;
/// A ceiling from the 7×7 window only where at least this share of its pixels saw light:
/// where fewer did, the light is sparse (a room lit through a slit, at a few samples) and
/// the window's samples say too little of how bright it is.
const LIT_SHARE: f32 = 0.5;
/// A pixel whose 7×7 window is sparse gets its ceiling from a window this wide each side
/// instead (15×15),
pub(crate) const SPARSE_RADIUS: usize = 7;
/// where at least this many of its neighbours alike in albedo and normal saw light (the
/// mean of 8 hits is known to about a third); else none.
const SPARSE_HITS: f32 = 8.0;
/// On per-pixel variances, the wide window's margin is this share of the 7×7 window's
/// (7/15): its similar mean is over about (15/7)² as many pixels, so its standard error is
/// about 7/15 as large.
const SPARSE_ERRORS: f32 = (2 * CEILING_RADIUS + 1) as f32 / (2 * SPARSE_RADIUS + 1) as f32;

/// The most the diffuse branch may make each pixel of a band
/// ([`crate::model::Architecture::diffuse_bound`]): the mean noisy value (d̃, per channel)
/// of its similar neighbours in a 7×7 window, plus `errors` standard errors of a pixel's
/// mean there (the root of their median variance). Similar: albedo and normal alike, and
/// a noisy value within 2 standard errors of the pixel's; the pixel is always its own.
/// The median, not the mean: a few single-sample hits among them (each with an error about
/// its value, so similar to dark and lit pixels alike) would widen a mean's margin enough
/// to let the light of a sun patch beside the pixel through. Where fewer than half the
/// 7×7 window's pixels saw light, the same is sought in the 15×15 window with
/// [`SPARSE_ERRORS`] times the root of their mean variance the margin, if [`SPARSE_HITS`]
/// of the pixel's neighbours alike in albedo and normal there saw light; else there is
/// none. (There most similar pixels are dark, so a median margin is nearly none: it took
/// the light of sparse sun stripes, BENCHMARKS.md.)
///
/// A model fed spatial variance estimates ([`Variances::Spatial`]: files without
/// variances, as Blender writes them) reads one variance for the whole window instead:
/// the median over the neighbours alike in albedo and normal ([`spatial_ceiling_row`]). A
/// 3×3 estimate beside an edge holds the bright side's light, so per pixel it would lift
/// the ceiling exactly where the kernels bleed. Where its 7×7 window is sparse, all its
/// alike neighbours in the 15×15 one count.
///
/// Kernels that reach across an edge carry light from the bright side into the dark one,
/// a band of pixels a few times brighter than the surface they sit on: the dark side's
/// own samples say it is not so, and the bright side is not similar, so the ceiling
/// stops it. Where a surface is uniformly noisy (few samples, most of them dark) the
/// variances are large and the ceiling lets the kernels fill it. Only brightening is
/// bounded: dimming a pixel moves energy out of it, which a relative error forgives far
/// more than energy put into a dark pixel.
pub(crate) struct DiffuseCeiling {
    /// Per row: the ceiling of each channel, `[c][x]`.
    pub(super) ceiling: Vec<f32>,
    pub(super) width: usize,
}

impl DiffuseCeiling {
    /// The ceiling of `arch`, if it has one, over rows `rows` of the region `f` holds
    /// (whose rows beyond them, [`Bounds::context`] at least where the frame goes on, are
    /// the window's context; the window stops at the region's edges).
    pub(super) fn of(arch: &Architecture, f: &Features, rows: Range<usize>) -> Option<DiffuseCeiling> {
        let errors = arch.diffuse_bound? as f32;
        let (w, h) = (f.width, f.height);
        let reach = Bounds::context(arch);
        let (d, var, albedo, normal) = (&f.d_tilde, &f.d_variance, &f.albedo, &f.normal);
        // The mean of d̃'s channels, on the rows the windows read only: a tiled band's
        // region holds the network's whole reach beyond them.
        let read = rows.start.saturating_sub(reach) * w..((rows.end + reach).min(h)) * w;
        let mut mean = vec![0f32; w * h];
        mean[read.clone()].par_iter_mut().zip(read).for_each(|(m, i)| *m = (d[0][i] + d[1][i] + d[2][i]) / 3.0);
        let mut ceiling = vec![0f32; 3 * w * rows.len()];
        let window = Window { width: w, height: h, errors, mean: &mean, f };
        if arch.variances == Variances::Spatial {
            ceiling.par_chunks_mut(3 * w).zip(rows).for_each(|(out, y)| spatial_ceiling_row(&window, y, out));
            return Some(DiffuseCeiling { ceiling, width: w });
        }
        let passes = Passes::avx2_or_not();
        let planes: Planes =
            [&mean, var, &d[0], &d[1], &d[2], &albedo[0], &albedo[1], &albedo[2], &normal[0], &normal[1], &normal[2]];
        ceiling.par_chunks_mut(3 * w).zip(rows).for_each_init(
            || (Vec::new(), DenseScratch::default(), [(); SUMS].map(|_| vec![0f32; w]), Vec::new()),
            |(sparse, scratch, sums, lit), (out, y)| {
                sparse.clear();
                dense_row(passes, &planes, w, h, y, errors, out, sparse, scratch);
                // A sparse pixel whose 15×15 window holds fewer than SPARSE_HITS lit pixels
                // has fewer alike ones that saw light, so no ceiling: known from a box count,
                // without the window's similarity tests (most of a frame's dark background).
                if !sparse.is_empty() {
                    lit_in_window_row(&mean, w, h, y, SPARSE_RADIUS, lit);
                    sparse.retain(|&x| {
                        let measured = lit[x] as f32 >= SPARSE_HITS;
                        if !measured {
                            (0..3).for_each(|c| out[c * w + x] = f32::INFINITY);
                        }
                        measured
                    });
                }
                // Where the 7×7 window is sparse, the 15×15 one, summed over the runs of
                // such pixels.
                for run in column_runs(sparse) {
                    window_row_sums(passes, &planes, w, h, y, SPARSE_RADIUS, run, sums);
                }
                let [count, variance, s0, s1, s2, hits] = &*sums;
                for &x in &*sparse {
                    if hits[x] < SPARSE_HITS {
                        (0..3).for_each(|c| out[c * w + x] = f32::INFINITY);
                    } else {
                        // The pixel is its own neighbour, so `count` ≥ 1 (finite features).
                        let count = count[x].max(1.0);
                        let reach = errors * SPARSE_ERRORS * (variance[x] / count).max(0.0).sqrt();
                        [&s0, &s1, &s2]
                            .into_iter()
                            .enumerate()
                            .for_each(|(c, s)| out[c * w + x] = s[x] / count + reach);
                    }
                }
            },
        );
        Some(DiffuseCeiling { ceiling, width: w })
    }

    /// Bounds `d_hat` (the branch's output d̂, exposed, these rows or the first of them)
    /// in place.
    pub(crate) fn apply(&self, d_hat: &mut [Vec<f32>; 3]) {
        let w = self.width;
        for (c, plane) in d_hat.iter_mut().enumerate() {
            for (i, v) in plane.iter_mut().enumerate() {
                // `min` keeps the ceiling where the output is NaN (hostile input).
                *v = v.min(self.ceiling[(i / w) * 3 * w + c * w + i % w]);
            }
        }
    }
}

/// What the ceiling's per-pixel gathers on spatial variances read
/// ([`spatial_ceiling_row`]): the region's features, the mean of d̃'s channels
/// (on the rows the windows read) and the ceiling's errors.
struct Window<'a> {
    width: usize,
    height: usize,
    errors: f32,
    mean: &'a [f32],
    f: &'a Features,
}

/// The ceiling of row `y` (`out`: `[c][x]`) where the variances are spatial estimates:
/// per pixel, the median variance `m` of the 7×7 window's neighbours alike in albedo and
/// normal; of those, the ones whose mean d̃ is within 2 standard errors of the pixel's
/// (√(2m)) are similar, and the ceiling is their mean d̃ plus `errors` × √m. Where under
/// half the 7×7 window saw light, the 15×15 window's alike neighbours give it instead
/// ([`Window::wide_ceiling`]). Pixel by pixel: the median variance decides which
/// neighbours are similar, so the window cannot be visited one offset at a time along the
/// row, as on the file's variances ([`rows::dense_row`]).
fn spatial_ceiling_row(win: &Window, y: usize, out: &mut [f32]) {
    let w = win.width;
    let (mut alike, mut variances) = (Vec::new(), Vec::new());
    for x in 0..w {
        let (pixels, lit) = win.gather(x, y, CEILING_RADIUS, &mut alike, &mut variances);
        let ceiling = if lit < LIT_SHARE * pixels {
            win.wide_ceiling(x, y, &mut alike, &mut variances)
        } else {
            win.dense_ceiling(y * w + x, &alike, &mut variances)
        };
        for (c, v) in ceiling.into_iter().enumerate() {
            out[c * w + x] = v;
        }
    }
}

impl Window<'_> {
    /// The pixels of the window of half-side `r` around (`x`, `y`) alike the pixel there in
    /// albedo and normal (into `alike`), their finite variances (into `variances`), and the
    /// window's pixel and lit-pixel counts.
    fn gather(&self, x: usize, y: usize, r: usize, alike: &mut Vec<usize>, variances: &mut Vec<f32>) -> (f32, f32) {
        let (w, var) = (self.width, &self.f.d_variance);
        let i = y * w + x;
        let (mut pixels, mut lit) = (0f32, 0f32);
        alike.clear();
        variances.clear();
        for yy in y.saturating_sub(r)..(y + r + 1).min(self.height) {
            let row = yy * w + x.saturating_sub(r)..yy * w + (x + r + 1).min(w);
            for (j, &v) in row.clone().zip(&var[row]) {
                pixels += 1.0;
                lit += if self.mean[j] != 0.0 { 1.0 } else { 0.0 };
                if alike_pixels(self.f, i, j) {
                    alike.push(j);
                    if v >= 0.0 && v.is_finite() {
                        variances.push(v);
                    }
                }
            }
        }
        (pixels, lit)
    }

    /// The ceiling of pixel `i` from the similar ones among `alike` (see
    /// [`spatial_ceiling_row`]); none where no variance is finite.
    fn dense_ceiling(&self, i: usize, alike: &[usize], variances: &mut [f32]) -> [f32; 3] {
        let m = median(variances);
        if m.is_nan() {
            return [f32::INFINITY; 3];
        }
        let (mut count, mut sum) = (0f32, [0f32; 3]);
        for &j in alike {
            let e = self.mean[j] - self.mean[i];
            if j == i || within_errors(e, 2.0 * m) {
                count += 1.0;
                (0..3).for_each(|c| sum[c] += self.f.d_tilde[c][j]);
            }
        }
        sum.map(|s| s / count.max(1.0) + self.errors * m.sqrt())
    }

    /// The ceiling of a pixel (`x`, `y`) whose 7×7 window is sparse: from all its alike
    /// neighbours in the 15×15 window, their mean d̃ plus `errors` × the root of their
    /// median variance; none where fewer than [`SPARSE_HITS`] of them saw light.
    fn wide_ceiling(&self, x: usize, y: usize, alike: &mut Vec<usize>, variances: &mut Vec<f32>) -> [f32; 3] {
        self.gather(x, y, SPARSE_RADIUS, alike, variances);
        let hits = alike.iter().filter(|&&j| self.mean[j] != 0.0).count() as f32;
        let m = median(variances);
        if hits < SPARSE_HITS || m.is_nan() {
            return [f32::INFINITY; 3];
        }
        let mut sum = [0f32; 3];
        for &j in &*alike {
            (0..3).for_each(|c| sum[c] += self.f.d_tilde[c][j]);
        }
        sum.map(|s| s / alike.len() as f32 + self.errors * m.sqrt())
    }
}

/// Whether two noisy values `e` apart, the variances of their means summing to `variance`,
/// may show the same light: within [`SIMILAR_ERRORS`] standard errors of their difference.
#[inline(always)]
fn within_errors(e: f32, variance: f32) -> bool {
    e * e <= SIMILAR_ERRORS * SIMILAR_ERRORS * variance
}

/// Whether two pixels are alike in albedo and normal, from the largest difference of their
/// albedos' channels and the squared distance of their normals. Branch-free, so that the
/// row passes ([`rows`]) vectorise.
#[inline(always)]
fn alike_surfaces(albedo: f32, normal2: f32) -> bool {
    (albedo <= SIMILAR_ALBEDO) & (normal2 <= SIMILAR_NORMAL * SIMILAR_NORMAL)
}

/// Whether pixels `i` and `j` of `f` are alike in albedo and normal.
fn alike_pixels(f: &Features, i: usize, j: usize) -> bool {
    let (albedo, normal) = (&f.albedo, &f.normal);
    alike_differences(
        std::array::from_fn(|c| albedo[c][j] - albedo[c][i]),
        std::array::from_fn(|c| normal[c][j] - normal[c][i]),
    )
}

/// Whether two pixels whose albedos' channels differ by `albedo` and whose normals'
/// components differ by `normal` are alike ([`alike_surfaces`]; a NaN difference of a
/// channel counts as none). Branch-free, so that the row passes vectorise.
#[inline(always)]
pub(super) fn alike_differences(albedo: [f32; 3], normal: [f32; 3]) -> bool {
    let largest = 0f32.max(albedo[0].abs()).max(albedo[1].abs()).max(albedo[2].abs());
    alike_surfaces(largest, normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2])
}

/// The upper median of `v` (reordered); NaN when empty.
fn median(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return f32::NAN;
    }
    let half = v.len() / 2;
    *v.select_nth_unstable_by(half, f32::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::denoise::bounds::tests::{hash, hostile};

    impl Window<'_> {
        /// The ceiling of pixel (`x`, `y`) from its 7×7 window, on the file's variances: the
        /// mean d̃ of its similar neighbours (alike in albedo and normal, mean d̃ within 2
        /// errors of the pixel's, as [`within_errors`] judges them; the pixel always) plus
        /// `errors` × the root of their median variance (finite ones; none: no margin).
        /// `None` where under half the window saw light (sparse). `alike` and `variances` are
        /// scratch. Pixel by pixel: what [`rows::dense_row`] must equal bit for bit.
        fn dense_file_ceiling(
            &self,
            x: usize,
            y: usize,
            alike: &mut Vec<usize>,
            variances: &mut Vec<f32>,
        ) -> Option<[f32; 3]> {
            let (i, var) = (y * self.width + x, &self.f.d_variance);
            let (pixels, lit) = self.gather(x, y, CEILING_RADIUS, alike, variances);
            if lit < LIT_SHARE * pixels {
                return None;
            }
            variances.clear();
            let (mut count, mut sum) = (0f32, [0f32; 3]);
            for &j in &*alike {
                let v = var[j];
                if j == i || within_errors(self.mean[j] - self.mean[i], v + var[i]) {
                    count += 1.0;
                    (0..3).for_each(|c| sum[c] += self.f.d_tilde[c][j]);
                    if v >= 0.0 && v.is_finite() {
                        variances.push(v);
                    }
                }
            }
            let reach = self.errors * median(variances).max(0.0).sqrt();
            Some(sum.map(|s| s / count + reach))
        }
    }

    #[test]
    fn the_row_pass_gives_the_pixel_by_pixel_ceiling_bit_for_bit() {
        // Two surfaces (albedo 0.5 and 0.8, normals bent by column), sparse light on the
        // left and dense on the right, and hostile values scattered over every plane.
        let (w, h) = (23, 11);
        let hostile = |i: usize, k: usize, v: f32| hostile(i, k, v, 41);
        let mut f = Features::new(&crate::features::tests::inputs(w, h, |_| 0.0));
        let lit = |i: usize| i % w > 8 || hash(i, 9) < 0.3;
        f.d_tilde = std::array::from_fn(|c| {
            (0..w * h).map(|i| if lit(i) { hostile(i, c, 0.2 + hash(i, c)) } else { 0.0 }).collect()
        });
        f.d_variance = (0..w * h).map(|i| hostile(i, 3, 0.05 * hash(i, 4))).collect();
        f.albedo = std::array::from_fn(|c| {
            (0..w * h).map(|i| hostile(i, c + 11, if i / w < 5 { 0.5 } else { 0.8 + 0.01 * c as f32 })).collect()
        });
        f.normal =
            std::array::from_fn(|c| (0..w * h).map(|i| hostile(i, c + 5, (i % w) as f32 * 0.05 * c as f32)).collect());
        let mean: Vec<f32> = (0..w * h).map(|i| (f.d_tilde[0][i] + f.d_tilde[1][i] + f.d_tilde[2][i]) / 3.0).collect();
        let window = Window { width: w, height: h, errors: 2.0, mean: &mean, f: &f };
        let planes: Planes = [
            &mean,
            &f.d_variance,
            &f.d_tilde[0],
            &f.d_tilde[1],
            &f.d_tilde[2],
            &f.albedo[0],
            &f.albedo[1],
            &f.albedo[2],
            &f.normal[0],
            &f.normal[1],
            &f.normal[2],
        ];
        let (mut alike, mut variances) = (Vec::new(), Vec::new());
        let mut dense = 0;
        for passes in [Passes::avx2_or_not(), Passes::compiled()] {
            // One scratch for every row, as a worker keeps it: what a row leaves in it must
            // not reach the next.
            let mut scratch = DenseScratch::default();
            for y in 0..h {
                let (mut out, mut sparse) = (vec![-1.0; 3 * w], Vec::new());
                dense_row(passes, &planes, w, h, y, 2.0, &mut out, &mut sparse, &mut scratch);
                for x in 0..w {
                    let got = [0, 1, 2].map(|c| out[c * w + x].to_bits());
                    match window.dense_file_ceiling(x, y, &mut alike, &mut variances) {
                        Some(want) => {
                            dense += 1;
                            assert_eq!(got, want.map(f32::to_bits), "({x}, {y})");
                        }
                        None => assert!(sparse.contains(&x), "({x}, {y})"),
                    }
                }
            }
        }
        // Both kinds of window occur.
        assert!(dense > w * h / 2 && dense < 2 * w * h, "{dense}");
    }

    /// The ceiling (2 errors) over rows `frame` of a 12-wide frame of one surface (albedo
    /// 0.5), whose pixel `i` (counted from the frame's top) shows d̃ `d(i)` with variance
    /// `v(i)`; rows `rows` of those.
    fn ceiling(
        frame: Range<usize>,
        d: impl Fn(usize) -> f32,
        v: impl Fn(usize) -> f32,
        rows: Range<usize>,
    ) -> DiffuseCeiling {
        ceiling_fed(Variances::File, frame, d, v, rows)
    }

    /// [`ceiling`] of a model fed `variances`.
    fn ceiling_fed(
        variances: Variances,
        frame: Range<usize>,
        d: impl Fn(usize) -> f32,
        v: impl Fn(usize) -> f32,
        rows: Range<usize>,
    ) -> DiffuseCeiling {
        let pixels = frame.start * 12..frame.end * 12;
        let mut f = Features::new(&crate::features::tests::inputs(12, frame.len(), |_| 0.0));
        f.d_tilde = std::array::from_fn(|_| pixels.clone().map(&d).collect());
        f.d_variance = pixels.map(v).collect();
        let arch =
            Architecture { diffuse_bound: Some(2), variances, ..Architecture::ladder(crate::model::Quality::Fast) };
        DiffuseCeiling::of(&arch, &f, rows).unwrap()
    }

    #[test]
    fn on_spatial_variances_an_edges_estimate_does_not_lift_the_ceiling() {
        // Columns 0–3 lit (5), 4–11 dark (0.07); the 3×3 estimates of columns 3 and 4 hold
        // both sides (variance 6), the rest are small. The kernels carry 1.8 into column 4.
        let lit = |i: usize| i % 12 < 4;
        let d = |i: usize| if lit(i) { 5.0 } else { 0.07 };
        let v = |i: usize| match i % 12 {
            3 | 4 => 6.0,
            0..=2 => 0.01,
            _ => 1e-4,
        };
        let edge = 3 * 12 + 4;
        // The window's median variance (0.01: of its 49 variances, 14 are the edge's) holds
        // the light back: the dark neighbours' 0.07 + 2 × 0.1.
        let mut median: [Vec<f32>; 3] = std::array::from_fn(|_| vec![1.8; 84]);
        ceiling_fed(Variances::Spatial, 0..7, d, v, 0..7).apply(&mut median);
        assert!((median[1][edge] - 0.27).abs() < 1e-5, "{}", median[1][edge]);
        // The lit side keeps what it is given.
        assert_eq!(median[2][3 * 12 + 1], 1.8);
        // Hostile features: no panic, and what was finite stays finite.
        let hostile = |i: usize| [f32::NAN, f32::INFINITY, -1.0, 3e38][i % 4];
        let c = ceiling_fed(Variances::Spatial, 0..7, hostile, hostile, 0..7);
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.5; 84]);
        c.apply(&mut out);
        assert!(out.iter().flatten().all(|v| v.is_finite()));
    }

    #[test]
    fn the_diffuse_branch_brightens_no_pixel_past_its_similar_neighbours() {
        // Columns 0–3 lit (5 ± 0.1), 4–11 dark (0.07 ± 0.01): the kernels carry 1.8 across
        // the edge into column 4; the ceiling is the dark side's 0.07 + 2 × 0.01.
        let lit = |i: usize| i % 12 < 4;
        let c = ceiling(0..7, |i| if lit(i) { 5.0 } else { 0.07 }, |i| if lit(i) { 0.01 } else { 1e-4 }, 0..7);
        let mut d_hat: [Vec<f32>; 3] = std::array::from_fn(|_| vec![1.8; 84]);
        d_hat[0][3 * 12 + 3] = 4.0;
        c.apply(&mut d_hat);
        assert!((d_hat[1][3 * 12 + 4] - 0.09).abs() < 1e-5, "{}", d_hat[1][3 * 12 + 4]);
        assert!((d_hat[1][3 * 12 + 11] - 0.09).abs() < 1e-5, "{}", d_hat[1][3 * 12 + 11]);
        // The lit side keeps what it is given, dimmed or not.
        assert_eq!((d_hat[1][3 * 12 + 3], d_hat[0][3 * 12 + 3]), (1.8, 4.0));
    }

    #[test]
    fn a_few_single_sample_hits_in_a_lit_window_do_not_widen_its_margin() {
        // A lit surface (1.0, variance 0.01) where one pixel in eight got a bright
        // single-sample hit too (30, variance 900: an error about its value, so similar to
        // the rest). The kernels carry 10 into every pixel. The margin is 2 × the root of
        // the similar neighbours' median variance (0.1), not of their mean (≈ 10.4), which
        // would let 10 through.
        let hit = |i: usize| i % 8 == 3;
        let c = ceiling(0..7, |i| if hit(i) { 30.0 } else { 1.0 }, |i| if hit(i) { 900.0 } else { 0.01 }, 0..7);
        let mut d_hat: [Vec<f32>; 3] = std::array::from_fn(|_| vec![10.0; 84]);
        c.apply(&mut d_hat);
        // Pixel (6, 3): its 7×7 window is columns 3–9 of all 7 rows, every pixel similar.
        let window: Vec<usize> = (0..7).flat_map(|y| (3..10).map(move |x| y * 12 + x)).collect();
        let mean = window.iter().map(|&i| if hit(i) { 30.0 } else { 1.0 }).sum::<f32>() / 49.0;
        let centre = 3 * 12 + 6;
        assert!((d_hat[0][centre] - (mean + 0.2)).abs() < 1e-4, "{} against {}", d_hat[0][centre], mean + 0.2);
    }

    #[test]
    fn a_noisy_surface_is_filled_and_light_too_sparse_to_measure_is_not_bounded() {
        // Two pixels in three got one bright sample (0.4, variance 0.05): a dark one among
        // them may be filled to its neighbours' mean and beyond.
        let hit = |i: usize| i % 3 != 2;
        let c = ceiling(0..7, |i| if hit(i) { 0.4 } else { 0.0 }, |i| if hit(i) { 0.05 } else { 0.0 }, 2..5);
        let mut d_hat: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.5; 36]);
        c.apply(&mut d_hat);
        assert!(d_hat.iter().flatten().all(|&v| v == 0.5), "{d_hat:?}");
        // One pixel in 12 lit, 7 in the frame: too few to say how bright the rest is.
        let hit = |i: usize| i.is_multiple_of(12);
        let c = ceiling(0..7, |i| if hit(i) { 0.4 } else { 0.0 }, |i| if hit(i) { 0.05 } else { 0.0 }, 0..7);
        assert!(c.ceiling.iter().all(|v| v.is_infinite()));
    }

    #[test]
    fn sparse_light_is_bounded_by_a_wider_window_where_it_holds_enough_hits() {
        // One pixel in `every` got a sample (0.4; its variance, or its 3×3 estimate, 0.05;
        // the rest 0).
        for variances in [Variances::File, Variances::Spatial] {
            let sparse = |every: usize| {
                let hit = move |i: usize| i.is_multiple_of(every);
                ceiling_fed(
                    variances,
                    0..20,
                    move |i| if hit(i) { 0.4 } else { 0.0 },
                    move |i| if hit(i) { 0.05 } else { 0.0 },
                    0..20,
                )
            };
            // One in four: under half of a 7×7 window saw light, so the 15×15 window's 8+
            // hits give the ceiling, where the kernels of a sunlit patch nearby carry 1.8:
            // their mean 0.1, plus 2 × 7/15 × the root of the mean variance of the similar
            // ones (the hits are within 2 errors of the dark pixels: all of them, 0.0125),
            // or 2 × the root of the median variance of the alike ones (0) on spatial
            // estimates.
            let mut d_hat: [Vec<f32>; 3] = std::array::from_fn(|_| vec![1.8; 240]);
            sparse(4).apply(&mut d_hat);
            let middle = 10 * 12 + 6;
            let want = if variances == Variances::File { 0.1 + 2.0 * 7.0 / 15.0 * 0.0125f32.sqrt() } else { 0.1 };
            assert!((d_hat[0][middle] - want).abs() < 0.02, "{variances:?}: {}", d_hat[0][middle]);
            // One pixel in 48 (every fourth row's first pixel): at most 4 hits in a 15×15
            // window, too few: no ceiling.
            let c = sparse(48);
            assert!(c.ceiling.iter().all(|v| v.is_infinite()), "{variances:?}");
        }
    }

    #[test]
    fn a_thin_sunlit_stripe_keeps_its_light_and_the_dark_beside_it_gets_none() {
        // A stripe of sunlight across row 10 (2.0, well sampled: variance 0.01) on a dim
        // surface where one pixel in four got a sample (0.4, variance 0.05): every 7×7
        // window is sparse. The kernels keep the stripe's 2.0 and carry 1.0 beside it.
        let stripe = |i: usize| i / 12 == 10;
        // (value, variance) of pixel i.
        let pixel = move |i: usize| match (stripe(i), i.is_multiple_of(4)) {
            (true, _) => (2.0, 0.01),
            (false, true) => (0.4, 0.05),
            (false, false) => (0.0, 0.0),
        };
        let c = ceiling(0..20, |i| pixel(i).0, |i| pixel(i).1, 0..20);
        let mut d_hat: [Vec<f32>; 3] =
            std::array::from_fn(|_| (0..240).map(|i| if stripe(i) { 2.0 } else { 1.0 }).collect());
        c.apply(&mut d_hat);
        // The stripe's similar neighbours are the stripe: its ceiling is 2.0 + 2 × 7/15 × 0.1.
        assert_eq!(d_hat[0][10 * 12 + 6], 2.0);
        // Beside it, the stripe is not similar (2.0 is 20 errors away): the dim surface's
        // 0.1 + 2 × 7/15 × √0.0125.
        let beside = 12 * 12 + 6;
        assert!((d_hat[0][beside] - 0.204).abs() < 0.01, "{}", d_hat[0][beside]);
    }

    #[test]
    fn a_band_read_with_its_context_rows_has_the_whole_frames_ceiling() {
        let d = |i: usize| ((i * 7919) % 13) as f32 * 0.1;
        let v = |i: usize| ((i * 104_729) % 5) as f32 * 0.01;
        // Sparse on the left (one pixel in four lit), dense on the right.
        let d = |i: usize| if i % 12 < 6 && !i.is_multiple_of(4) { 0.0 } else { d(i) };
        for variances in [Variances::File, Variances::Spatial] {
            let radius = SPARSE_RADIUS;
            let whole = ceiling_fed(variances, 0..24, d, v, 0..24);
            for band in [0..4usize, 9..12, 20..24] {
                let context = band.start.saturating_sub(radius)..(band.end + radius).min(24);
                let inner = band.start - context.start..band.end - context.start;
                let c = ceiling_fed(variances, context, d, v, inner);
                assert_eq!(c.ceiling[..], whole.ceiling[band.start * 36..band.end * 36], "{variances:?} {band:?}");
            }
        }
    }
}
