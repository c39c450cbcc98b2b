//! Channel-major (CHW) image planes and the resampling steps of the multi-scale network:
//! 2×2 box pooling, nearest and bilinear 2× upsampling, and the firefly clamp, each
//! computed row by row in parallel.

use super::buffers::{self, zeroed};
use rayon::prelude::*;

/// Channel-major planes: `c` planes of `w × h`.
#[derive(Debug, Clone, PartialEq)]
pub struct Planes {
    /// Channels.
    pub c: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
    /// `c × h × w` values.
    pub data: Vec<f32>,
}

impl Drop for Planes {
    fn drop(&mut self) {
        buffers::recycle(std::mem::take(&mut self.data));
    }
}

impl Planes {
    /// Zeros.
    pub fn zeros(c: usize, w: usize, h: usize) -> Planes {
        Planes { c, w, h, data: zeroed(c * w * h) }
    }

    /// Wraps CHW data.
    pub fn from_vec(c: usize, w: usize, h: usize, data: Vec<f32>) -> Planes {
        assert_eq!(data.len(), c * w * h, "CHW data of {c}×{h}×{w}");
        Planes { c, w, h, data }
    }

    /// Plane `i`.
    pub fn plane(&self, i: usize) -> &[f32] {
        &self.data[i * self.w * self.h..(i + 1) * self.w * self.h]
    }

    /// Rows `rows` of every plane (`self` itself where that is all of them).
    pub fn crop_rows(self, rows: std::ops::Range<usize>) -> Planes {
        assert!(rows.start <= rows.end && rows.end <= self.h, "rows {rows:?} of planes {} tall", self.h);
        if rows == (0..self.h) {
            return self;
        }
        let w = self.w;
        let mut data = buffers::with_capacity(self.c * w * rows.len());
        for c in 0..self.c {
            data.extend_from_slice(&self.data[(c * self.h + rows.start) * w..(c * self.h + rows.end) * w]);
        }
        Planes::from_vec(self.c, w, rows.len(), data)
    }

    /// `self` then `other` (same size), channel-wise.
    pub fn concat(mut self, other: &Planes) -> Planes {
        assert_eq!((self.w, self.h), (other.w, other.h), "concatenated planes differ in size");
        self.data.extend_from_slice(&other.data);
        self.c += other.c;
        self
    }

    /// Planes of `w × h` whose rows `fill(channel, y, row)` writes, rows in parallel.
    fn by_rows(c: usize, w: usize, h: usize, fill: impl Fn(usize, usize, &mut [f32]) + Sync) -> Planes {
        let mut out = Planes::zeros(c, w, h);
        if w > 0 && h > 0 {
            out.data.par_chunks_mut(w).enumerate().for_each(|(i, row)| fill(i / h, i % h, row));
        }
        out
    }

    /// Row `y` of plane `c`.
    fn row(&self, c: usize, y: usize) -> &[f32] {
        &self.data[(c * self.h + y) * self.w..][..self.w]
    }

    /// 2×2 box average (sides halved, rounding down).
    pub fn avg_pool2(&self) -> Planes {
        Planes::by_rows(self.c, self.w / 2, self.h / 2, |c, y, dst| {
            let (r0, r1) = (self.row(c, 2 * y), self.row(c, 2 * y + 1));
            // By exact pairs, which the compiler vectorises (an odd last column is dropped).
            for ((d, a), b) in dst.iter_mut().zip(r0.chunks_exact(2)).zip(r1.chunks_exact(2)) {
                *d = (a[0] + a[1] + b[0] + b[1]) * 0.25;
            }
        })
    }

    /// Every value clamped to the largest of its 8 neighbours (edges replicated): an
    /// isolated outlier (a firefly) takes its brightest neighbour's value, while anything
    /// at least two pixels wide (an edge, a line, a highlight) keeps its extent, its peak
    /// lowered at most to its second-brightest pixel. The result is still a value of the
    /// neighbourhood, so a convex filter of it stays in the range of the original.
    pub fn clamp_to_neighbours(&self) -> Planes {
        self.clamp_to_ranked_neighbour(false)
    }

    /// [`Planes::clamp_to_neighbours`] to the second-brightest of the 8 neighbours instead:
    /// a pair of adjacent outliers goes too, and anything at least three pixels across
    /// keeps its extent.
    pub fn clamp_to_second_neighbour(&self) -> Planes {
        self.clamp_to_ranked_neighbour(true)
    }

    fn clamp_to_ranked_neighbour(&self, second: bool) -> Planes {
        let (w, h) = (self.w, self.h);
        let interior = ranked_interior_avx2_or_not();
        Planes::by_rows(self.c, w, h, |c, y, dst| {
            let rows = [y.saturating_sub(1), y, (y + 1).min(h - 1)].map(|r| self.row(c, r));
            // The edge columns, whose neighbourhoods repeat them, one by one.
            let edge = |x: usize| {
                let cols = [x.saturating_sub(1), x, (x + 1).min(w - 1)];
                let mut ranked = Ranked::new();
                for (i, row) in rows.iter().enumerate() {
                    for (j, &cx) in cols.iter().enumerate() {
                        if (i, j) != (1, 1) {
                            ranked.add(row[cx]);
                        }
                    }
                }
                rows[1][x].min(ranked.pick(second))
            };
            if w < 3 {
                (0..w).for_each(|x| dst[x] = edge(x));
                return;
            }
            (dst[0], dst[w - 1]) = (edge(0), edge(w - 1));
            interior(rows, &mut dst[1..w - 1], second);
        })
    }

    /// Each value that stands out of its 3×3 neighbourhood (over twice its median, and by
    /// more than `k` times the median of the 3×3 standard errors) keeps only what it shows
    /// beyond `k` of its own standard errors, down to that median, or to the most a
    /// neighbour shows beyond `k` of its own (`variance`: one plane, the variance of each
    /// pixel's mean). One hit of a small light gives a pixel a standard error about its
    /// own value among neighbours that saw none, so it goes, alone or among others like
    /// it. A highlight every sample saw loses its few standard errors; a pixel as noisy as
    /// its neighbours, or one beside a neighbour as bright that every sample saw (the edge
    /// of an emitter), stays.
    pub fn clamp_insignificant(&self, variance: &[f32], k: f32) -> Planes {
        let (w, h) = (self.w, self.h);
        assert_eq!(variance.len(), w * h, "one variance per pixel");
        let err: Vec<f32> = variance.iter().map(|v| v.max(0.0).sqrt()).collect();
        let settled_interior = settled_interior_avx2_or_not();
        Planes::by_rows(self.c, w, h, |c, y, dst| {
            let ys = [y.saturating_sub(1), y, (y + 1).min(h - 1)];
            let rows = ys.map(|r| self.row(c, r));
            // Most pixels are not over twice their median: when five of the nine reach half
            // of the value, so does the median, and nothing is sorted. Judged for the
            // interior columns at once, the edges' (whose neighbourhoods repeat them) one by
            // one.
            let mut settled = vec![false; w];
            if w >= 3 {
                settled_interior(rows, &mut settled[1..w - 1]);
            }
            for (x, d) in dst.iter_mut().enumerate() {
                let cols = [x.saturating_sub(1), x, (x + 1).min(w - 1)];
                let v = rows[1][x];
                *d = v;
                let edge = x == 0 || x == w - 1;
                let half = (v - 0.01) * 0.5;
                if settled[x]
                    || edge && rows.iter().flat_map(|r| cols.map(|cx| r[cx])).filter(|&n| n >= half).count() >= 5
                {
                    continue;
                }
                let (mut n, mut e) = ([0f32; 9], [0f32; 9]);
                for (i, &ry) in ys.iter().enumerate() {
                    for (j, &cx) in cols.iter().enumerate() {
                        n[3 * i + j] = rows[i][cx];
                        e[3 * i + j] = err[ry * w + cx];
                    }
                }
                let own = e[4];
                // What a neighbour shows beyond its own noise, a pixel may show too.
                let shown = (0..9).filter(|&i| i != 4).map(|i| n[i] - k * e[i]).fold(f32::NEG_INFINITY, f32::max);
                let (_, &mut median, _) = n.select_nth_unstable_by(4, f32::total_cmp);
                let (_, &mut around, _) = e.select_nth_unstable_by(4, f32::total_cmp);
                if v - median > k * around {
                    *d = v.min(median.max(v - k * own).max(shown));
                }
            }
        })
    }

    /// The smaller of `self` and `other` (same shape), value by value.
    pub fn min(mut self, other: &Planes) -> Planes {
        assert_eq!((self.c, self.w, self.h), (other.c, other.w, other.h), "planes differ in shape");
        self.data.iter_mut().zip(&other.data).for_each(|(a, b)| *a = a.min(*b));
        self
    }

    /// [`Planes::clamp_to_neighbours`] without losing energy: what the clamp removes from a
    /// pixel is shared equally among the pixels of its 3×3 neighbourhood (itself included,
    /// those inside the frame), so every plane's sum is unchanged. A firefly becomes a
    /// faint 3×3 patch instead of vanishing, which the kernels then average.
    pub fn clamp_to_neighbours_spreading(&self) -> Planes {
        let (w, h) = (self.w, self.h);
        let clamped = self.clamp_to_neighbours();
        let span = |i: usize, n: usize| 1 + usize::from(i > 0) + usize::from(i + 1 < n);
        let share = Planes::by_rows(self.c, w, h, |c, y, dst| {
            let (v, k) = (self.row(c, y), clamped.row(c, y));
            for (x, d) in dst.iter_mut().enumerate() {
                *d = (v[x] - k[x]) / (span(x, w) * span(y, h)) as f32;
            }
        });
        Planes::by_rows(self.c, w, h, |c, y, dst| {
            let rows: Vec<&[f32]> = (y.saturating_sub(1)..(y + 2).min(h)).map(|r| share.row(c, r)).collect();
            let own = clamped.row(c, y);
            for (x, d) in dst.iter_mut().enumerate() {
                let cols = x.saturating_sub(1)..(x + 2).min(w);
                *d = own[x] + rows.iter().map(|r| r[cols.clone()].iter().sum::<f32>()).sum::<f32>();
            }
        })
    }

    /// `self − other`, plane by plane (same shapes).
    pub fn minus(&self, other: &Planes) -> Planes {
        debug_assert_eq!((self.c, self.w, self.h), (other.c, other.w, other.h));
        let data = self.data.iter().zip(&other.data).map(|(a, b)| a - b).collect();
        Planes::from_vec(self.c, self.w, self.h, data)
    }

    /// Adds `other` (same shape) in place.
    pub fn add(&mut self, other: &Planes) {
        debug_assert_eq!((self.c, self.w, self.h), (other.c, other.w, other.h));
        self.data.iter_mut().zip(&other.data).for_each(|(a, b)| *a += b);
    }

    /// Adds `coarse` (half the size, as many planes) upsampled 2× to the nearest
    /// neighbour, without building the upsampled planes.
    pub fn add_up_nearest(&mut self, coarse: &Planes) {
        assert_eq!((coarse.c, coarse.w * 2, coarse.h * 2), (self.c, self.w, self.h), "a half-size plane set");
        let h = self.h;
        self.data.par_chunks_mut(self.w).enumerate().for_each(|(i, row)| {
            let s = coarse.row(i / h, i % h / 2);
            for (pair, &c) in row.chunks_exact_mut(2).zip(s) {
                pair[0] += c;
                pair[1] += c;
            }
        });
    }

    /// 2× nearest-neighbour upsampling.
    pub fn up_nearest(&self) -> Planes {
        Planes::by_rows(self.c, self.w * 2, self.h * 2, |c, y, dst| repeat_pairs(dst, self.row(c, y / 2)))
    }

    /// 2× bilinear upsampling, pixel centres at half-integers, edges replicated: ¾ of the
    /// parent plus ¼ of its neighbour on the output's side, along each axis (first along
    /// rows, then between rows).
    pub fn up_bilinear(&self) -> Planes {
        self.up_bilinear_rows(0..2 * self.h)
    }

    /// Rows `rows` of [`Planes::up_bilinear`], computed alone.
    pub fn up_bilinear_rows(&self, rows: std::ops::Range<usize>) -> Planes {
        let h = self.h;
        assert!(rows.start <= rows.end && rows.end <= 2 * h, "rows {rows:?} of {} upsampled", 2 * h);
        Planes::by_rows(self.c, 2 * self.w, rows.len(), |c, j, dst| {
            let y2 = rows.start + j;
            let y = y2 / 2;
            let other = if y2.is_multiple_of(2) { y.saturating_sub(1) } else { (y + 1).min(h - 1) };
            up_bilinear_row(dst, self.row(c, y), self.row(c, other));
        })
    }
}

/// Row `dst` (twice as wide) of [`Planes::up_bilinear`] between parent rows `near` (¾)
/// and `far` (¼), each widened first (¾ of each parent plus ¼ of its left or right one):
/// the same products and sums in the same order, pixel by pixel, without building the
/// widened rows; the interior in one loop the compiler vectorises, the two edge pixels
/// (replicated neighbours) apart.
fn up_bilinear_row(dst: &mut [f32], near: &[f32], far: &[f32]) {
    let w = near.len();
    let wide = |s: &[f32], x: usize, side: usize| s[x] * 0.75 + s[side] * 0.25;
    let pair = |x: usize| {
        let (before, after) = (x.saturating_sub(1), (x + 1).min(w - 1));
        [
            wide(near, x, before) * 0.75 + wide(far, x, before) * 0.25,
            wide(near, x, after) * 0.75 + wide(far, x, after) * 0.25,
        ]
    };
    for x in [0, w - 1] {
        dst[2 * x..2 * x + 2].copy_from_slice(&pair(x));
    }
    if w > 2 {
        let m = w - 2;
        let (nb, nc, na) = (&near[..m], &near[1..][..m], &near[2..][..m]);
        let (fb, fc, fa) = (&far[..m], &far[1..][..m], &far[2..][..m]);
        for (i, d) in dst[2..][..2 * m].chunks_exact_mut(2).enumerate() {
            let (n, f) = (nc[i] * 0.75, fc[i] * 0.75);
            d[0] = (n + nb[i] * 0.25) * 0.75 + (f + fb[i] * 0.25) * 0.25;
            d[1] = (n + na[i] * 0.25) * 0.75 + (f + fa[i] * 0.25) * 0.25;
        }
    }
}

/// Blend logits are clamped to this magnitude before the sigmoid, so `exp` and its
/// gradient stay finite.
pub const BLEND_LIMIT: f32 = 30.0;

/// The blend weight `α = 1 / (1 + e^{−l})` of logit `l` clamped to ±[`BLEND_LIMIT`].
pub fn blend_weight(l: f32) -> f32 {
    1.0 / (1.0 + (-l.clamp(-BLEND_LIMIT, BLEND_LIMIT)).exp())
}

/// The multi-scale network's gain, in place: every plane of `x` times `2σ(g)`, with
/// `σ(g)` [`blend_weight`] of `logits` (one plane of the same size). A logit of 0 is a
/// gain of exactly 1.
pub fn gain(x: &mut Planes, logits: &[f32]) {
    let n = x.w * x.h;
    assert_eq!(logits.len(), n, "gain logits differ in size from their planes");
    let g: Vec<f32> = logits.par_iter().map(|&l| 2.0 * blend_weight(l)).collect();
    x.data.par_chunks_mut(n.max(1)).for_each(|plane| plane.iter_mut().zip(&g).for_each(|(v, g)| *v *= g));
}

/// The coarse-to-fine blend of the multi-scale network, in place: every plane of `fine`
/// becomes `(1 − α)·fine + α·up`, with `α` from [`blend_weight`] of `logits` (one plane
/// of the same size) and `up` the coarser result upsampled ([`Planes::up_bilinear`]).
pub fn blend(fine: &mut Planes, up: &Planes, logits: &[f32]) {
    blend_with(fine, up, logits, |d, u, a| d * (1.0 - a) + u * a);
}

/// The detail-keeping blend of the multi-scale network, in place: every plane of `fine`
/// becomes `fine + α·up`, with `α` from [`blend_weight`] of `logits` and `up` the coarser
/// result less the fine one's 2×2 average, upsampled ([`Planes::up_bilinear`]).
pub fn add_blended(fine: &mut Planes, up: &Planes, logits: &[f32]) {
    blend_with(fine, up, logits, |d, u, a| d + u * a);
}

/// Every value `d` of `fine` becomes `f(d, u, α)`, `u` the same value of `up`.
fn blend_with(fine: &mut Planes, up: &Planes, logits: &[f32], f: impl Fn(f32, f32, f32) -> f32 + Sync) {
    let n = fine.w * fine.h;
    assert_eq!((up.c, up.w, up.h, logits.len()), (fine.c, fine.w, fine.h, n), "blend operands differ in size");
    let alpha: Vec<f32> = logits.par_iter().map(|&l| blend_weight(l)).collect();
    fine.data.par_chunks_mut(n).zip(up.data.par_chunks(n)).for_each(|(dst, src)| {
        for ((d, &u), &a) in dst.iter_mut().zip(src).zip(&alpha) {
            *d = f(*d, u, a);
        }
    });
}

impl Planes {
    /// The adjoint of [`Planes::up_bilinear`]: given the gradient of the upsampled planes
    /// (`self`, even sides), the gradient of the planes they came from.
    pub fn up_bilinear_adjoint(&self) -> Planes {
        let (w, h) = (self.w / 2, self.h / 2);
        let mut out = Planes::zeros(self.c, w, h);
        out.data.par_chunks_mut(w * h).enumerate().for_each(|(c, dst)| {
            // Between rows: output rows 2y and 2y + 1 came from widened rows y and y ∓ 1.
            let mut wide = vec![0f32; 2 * w * h];
            for y in 0..h {
                let (even, odd) = (self.row(c, 2 * y), self.row(c, 2 * y + 1));
                let (above, below) = (y.saturating_sub(1), (y + 1).min(h - 1));
                for x in 0..2 * w {
                    wide[y * 2 * w + x] += 0.75 * (even[x] + odd[x]);
                    wide[above * 2 * w + x] += 0.25 * even[x];
                    wide[below * 2 * w + x] += 0.25 * odd[x];
                }
            }
            // Along rows: columns 2x and 2x + 1 came from x and x ∓ 1.
            for y in 0..h {
                let (src, row) = (&wide[y * 2 * w..][..2 * w], &mut dst[y * w..][..w]);
                for x in 0..w {
                    row[x] += 0.75 * (src[2 * x] + src[2 * x + 1]);
                    row[x.saturating_sub(1)] += 0.25 * src[2 * x];
                    row[(x + 1).min(w - 1)] += 0.25 * src[2 * x + 1];
                }
            }
        });
        out
    }
}

/// The brightest and second-brightest of the values added (NaN ignored), −∞ until there
/// are as many.
#[derive(Clone, Copy)]
struct Ranked {
    most: f32,
    next: f32,
}

impl Ranked {
    #[inline(always)]
    fn new() -> Ranked {
        Ranked { most: f32::NEG_INFINITY, next: f32::NEG_INFINITY }
    }

    /// Selects rather than branches, so that a loop of it vectorises.
    #[inline(always)]
    fn add(&mut self, v: f32) {
        let above = v > self.most;
        self.next = if above { self.most } else { self.next.max(v) };
        self.most = if above { v } else { self.most };
    }

    #[inline(always)]
    fn pick(self, second: bool) -> f32 {
        if second { self.next } else { self.most }
    }
}

super::avx2_or_compiled!(
    /// Clamps the interior of a row (`dst`: columns 1 to w − 2 of rows `rows`, the row and
    /// those above and below it) to its neighbours' brightest, or second-brightest.
    type RankedInterior;
    fn ranked_interior_avx2_or_not() = ranked_interior(
        rows: [&[f32]; 3],
        dst: &mut [f32],
        second: bool,
    )
);

/// See [`RankedInterior`]. The eight neighbours in the order the edges visit them (row by
/// row), so that a tie of −0 and +0 ranks alike.
#[inline(always)]
fn ranked_interior(rows: [&[f32]; 3], dst: &mut [f32], second: bool) {
    let n = dst.len();
    let nine = neighbourhood(rows, n);
    for k in 0..n {
        let mut ranked = Ranked::new();
        for (i, neighbour) in nine.iter().enumerate() {
            if i != 4 {
                ranked.add(neighbour[k]);
            }
        }
        dst[k] = nine[4][k].min(ranked.pick(second));
    }
}

/// The 3×3 neighbourhood of columns 1 to `n` of `rows` (the row and those above and below
/// it), row by row: for each of its nine places, the values there of every column in turn.
#[inline(always)]
fn neighbourhood([up, row, down]: [&[f32]; 3], n: usize) -> [&[f32]; 9] {
    [
        &up[..n],
        &up[1..n + 1],
        &up[2..n + 2],
        &row[..n],
        &row[1..n + 1],
        &row[2..n + 2],
        &down[..n],
        &down[1..n + 1],
        &down[2..n + 2],
    ]
}

super::avx2_or_compiled!(
    /// Judges the interior of a row (`settled`: columns 1 to w − 2 of rows `rows`, the row and
    /// those above and below it) for [`Planes::clamp_insignificant`]: whether five of each
    /// value's nine reach half of it (less 0.01), so that it is not over twice its median.
    type SettledInterior;
    fn settled_interior_avx2_or_not() = settled_interior(
        rows: [&[f32]; 3],
        settled: &mut [bool],
    )
);

/// See [`SettledInterior`].
#[inline(always)]
fn settled_interior(rows: [&[f32]; 3], settled: &mut [bool]) {
    let n = settled.len();
    let nine = neighbourhood(rows, n);
    for k in 0..n {
        let half = (nine[4][k] - 0.01) * 0.5;
        let reach: u32 = nine.iter().map(|v| u32::from(v[k] >= half)).sum();
        settled[k] = reach >= 5;
    }
}

/// Row `dst` of a 2× nearest-neighbour upsampling: each value of `src` twice, as far as
/// `dst` goes (an odd length ends on one copy). By exact pairs, which the compiler
/// vectorises; a U-Net decoder's input rows are half of them this.
pub fn repeat_pairs(dst: &mut [f32], src: &[f32]) {
    let mut pairs = dst.chunks_exact_mut(2);
    let mut src = src.iter();
    for (pair, &v) in (&mut pairs).zip(&mut src) {
        pair[0] = v;
        pair[1] = v;
    }
    if let ([last], Some(&v)) = (pairs.into_remainder(), src.next()) {
        *last = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_as_noisy_as_its_neighbours_is_never_clamped_for_significance() {
        // A lit region at 16 spp: values 1 ± 0.3 with standard errors of 0.3 everywhere.
        // However far a pixel sits above its median, its neighbours are as noisy, so it
        // stays: the clamp only takes rare bright samples, never the upper half of noise.
        let (w, h) = (9, 7);
        let mut rng = crate::rng::SplitMix64(5);
        let p = Planes::from_vec(1, w, h, (0..w * h).map(|_| 1.0 + 0.6 * (rng.uniform_f32() - 0.5)).collect());
        let variance = vec![0.09; w * h];
        assert_eq!(p.clamp_insignificant(&variance, 3.0), p);
        // One sample of a light of 100 among them stands out: it goes to the median.
        let mut q = p.clone();
        q.data[3 * w + 4] = 1.0 + 100.0 / 16.0;
        let mut variance = variance;
        variance[3 * w + 4] = (100.0f32 / 16.0).powi(2);
        let out = q.clamp_insignificant(&variance, 3.0);
        assert!(out.data[3 * w + 4] < 1.3, "{}", out.data[3 * w + 4]);
        assert!((0..w * h).filter(|&i| i != 3 * w + 4).all(|i| out.data[i] == q.data[i]), "nothing else moves");
    }

    #[test]
    fn clamping_to_neighbours_removes_isolated_outliers_only() {
        let mut x = vec![0.5f32; 6 * 5];
        x[2 * 6 + 1] = 40.0; // a firefly
        x[6 + 4] = 9.0; // a two-pixel highlight
        x[2 * 6 + 4] = 8.0;
        x[4 * 6 + 5] = 0.0; // a dark pixel in a corner
        let spread = Planes::from_vec(1, 6, 5, x.clone()).clamp_to_neighbours_spreading();
        let (sum_in, sum_out): (f64, f64) = (
            x.iter().map(|&v| v as f64).sum(),
            spread.row(0, 0).iter().chain((1..5).flat_map(|r| spread.row(0, r).iter())).map(|&v| v as f64).sum(),
        );
        assert!((sum_in - sum_out).abs() < 1e-4 * sum_in.abs().max(1.0), "energy kept: {sum_in} vs {sum_out}");
        let p = Planes::from_vec(1, 6, 5, x.clone()).clamp_to_neighbours();
        let mut want = x;
        want[2 * 6 + 1] = 0.5;
        want[6 + 4] = 8.0;
        assert_eq!(p.data, want);
    }

    #[test]
    fn the_vectorised_rank_clamp_gives_the_branching_ones_bits() {
        // The clamp as first written: a branch per neighbour.
        let branching = |p: &Planes, second: bool| {
            let (w, h) = (p.w, p.h);
            let mut out = p.data.clone();
            for y in 0..h {
                let rows = [y.saturating_sub(1), y, (y + 1).min(h - 1)].map(|r| p.row(0, r));
                for x in 0..w {
                    let cols = [x.saturating_sub(1), x, (x + 1).min(w - 1)];
                    let (mut most, mut next) = (f32::NEG_INFINITY, f32::NEG_INFINITY);
                    for (i, row) in rows.iter().enumerate() {
                        for (j, &cx) in cols.iter().enumerate() {
                            let v = row[cx];
                            if (i, j) == (1, 1) {
                            } else if v > most {
                                (next, most) = (most, v);
                            } else {
                                next = next.max(v);
                            }
                        }
                    }
                    out[y * w + x] = rows[1][x].min(if second { next } else { most });
                }
            }
            out
        };
        let value = |i: usize| match (i * 7919) % 23 {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => f32::NEG_INFINITY,
            3 => -0.0,
            4 => 0.0,
            k => (k as f32 - 12.0) * ((i * 104_729) % 97) as f32,
        };
        for (w, h) in [(1, 1), (2, 3), (3, 2), (17, 5), (40, 9)] {
            let p = Planes::from_vec(1, w, h, (0..w * h).map(value).collect());
            for (second, got) in [(false, p.clamp_to_neighbours()), (true, p.clamp_to_second_neighbour())] {
                let bits = |v: &[f32]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got.data), bits(&branching(&p, second)), "{w}×{h}, second: {second}");
            }
        }
    }

    #[test]
    fn the_significance_clamps_vectorised_test_judges_as_each_pixels_own() {
        let value = |i: usize| match (i * 7919) % 19 {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => -1.0,
            k => ((i * 104_729) % 97) as f32 * 0.01 * k as f32,
        };
        let rows: [Vec<f32>; 3] = std::array::from_fn(|r| (0..40).map(|x| value(r * 40 + x)).collect());
        let rows = rows.each_ref().map(|r| &r[..]);
        for pass in [settled_interior, settled_interior_avx2_or_not()] {
            let mut settled = vec![false; 38];
            pass(rows, &mut settled);
            for (x, &settled) in (1..39).zip(&settled) {
                let half = (rows[1][x] - 0.01) * 0.5;
                let reach = rows.iter().flat_map(|r| &r[x - 1..x + 2]).filter(|&&n| n >= half).count();
                assert_eq!(settled, reach >= 5, "column {x}");
            }
            assert!(settled.iter().any(|&s| s) && settled.iter().any(|&s| !s));
        }
    }

    #[test]
    fn resampling_matches_its_definition() {
        let p = Planes::from_vec(1, 4, 2, vec![0., 1., 2., 3., 4., 5., 6., 7.]);
        assert_eq!(p.avg_pool2().data, [2.5, 4.5]);
        let up = p.up_nearest();
        assert_eq!(&up.data[..8], &[0., 0., 1., 1., 2., 2., 3., 3.]);
        let row = Planes::from_vec(1, 2, 1, vec![0., 4.]).up_bilinear();
        assert_eq!(row.data, [0., 1., 3., 4., 0., 1., 3., 4.]);
    }

    #[test]
    fn the_bilinear_adjoint_is_the_transpose() {
        // <up(x), g> = <x, upᵀ(g)> for random x and g.
        let (c, w, h) = (2, 5, 3);
        let x = Planes::from_vec(c, w, h, crate::rng::SplitMix64(1).centred(c * w * h));
        let g = Planes::from_vec(c, 2 * w, 2 * h, crate::rng::SplitMix64(2).centred(c * 4 * w * h));
        let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(a, b)| (a * b) as f64).sum::<f64>();
        let (lhs, rhs) = (dot(&x.up_bilinear().data, &g.data), dot(&x.data, &g.up_bilinear_adjoint().data));
        assert!((lhs - rhs).abs() < 1e-5 * lhs.abs().max(1.0), "{lhs} vs {rhs}");
    }

    #[test]
    fn repeated_pairs_are_each_value_twice() {
        let src: Vec<f32> = (0..5).map(|i| i as f32 + 0.5).collect();
        // Even and odd lengths, the last one a single copy.
        for n in 0..=10 {
            let mut dst = vec![f32::NAN; n];
            repeat_pairs(&mut dst, &src);
            assert_eq!(dst, (0..n).map(|x| src[x / 2]).collect::<Vec<_>>(), "{n} long");
        }
    }

    #[test]
    fn bilinear_rows_are_the_widened_rows_blended_bit_for_bit() {
        // Upsampling as first written: each parent row widened into a buffer, then the
        // near and far widened rows blended.
        let widened_first = |p: &Planes| {
            let (w, h) = (p.w, p.h);
            let wide = |c: usize, y: usize| -> Vec<f32> {
                let s = p.row(c, y);
                (0..2 * w)
                    .map(|x2| {
                        let x = x2 / 2;
                        let side = if x2.is_multiple_of(2) { s[x.saturating_sub(1)] } else { s[(x + 1).min(w - 1)] };
                        s[x] * 0.75 + side * 0.25
                    })
                    .collect()
            };
            let mut out = Vec::new();
            for c in 0..p.c {
                for y2 in 0..2 * h {
                    let y = y2 / 2;
                    let other = if y2.is_multiple_of(2) { y.saturating_sub(1) } else { (y + 1).min(h - 1) };
                    out.extend(wide(c, y).iter().zip(wide(c, other)).map(|(n, f)| n * 0.75 + f * 0.25));
                }
            }
            out
        };
        let bits = |v: &[f32]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for (w, h) in [(1, 1), (2, 1), (3, 2), (4, 3), (7, 5), (33, 4)] {
            let mut values = crate::rng::SplitMix64((w * 31 + h) as u64).centred(2 * w * h);
            // Magnitudes far apart and hostile values, so any change of order shows.
            values.iter_mut().enumerate().for_each(|(i, v)| *v *= [1.0, 1e7, 3e-6, 1.0][i % 4]);
            if w * h > 4 {
                values[3] = f32::INFINITY;
                values[5] = f32::NAN;
            }
            let p = Planes::from_vec(2, w, h, values);
            let whole = p.up_bilinear();
            assert_eq!(bits(&whole.data), bits(&widened_first(&p)), "{w}×{h}");
            for rows in [0..2 * h, 1..2 * h, h..2 * h - 1, 0..0] {
                let part = p.up_bilinear_rows(rows.clone());
                let want: Vec<f32> = (0..2)
                    .flat_map(|c| whole.data[(c * 2 * h + rows.start) * 2 * w..][..rows.len() * 2 * w].to_vec())
                    .collect();
                assert_eq!(bits(&part.data), bits(&want), "{w}×{h}, rows {rows:?}");
            }
        }
    }
}
