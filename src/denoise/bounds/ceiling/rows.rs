//! The diffuse ceiling's window passes over a row of pixels on the file's variances: the
//! 7×7 window's similar neighbours ([`dense_row`]) and the 15×15 window's sums
//! ([`window_row_sums`]). Each visits the window one offset at a time along the whole row,
//! so that its inner loop vectorises, and adds up each pixel's neighbours in the window's
//! order (rows, then columns), as a pixel-by-pixel gather would.

use super::median::{LANES, Medians, medians_avx2_or_not};
use super::{CEILING_RADIUS, LIT_SHARE, alike_differences, alike_surfaces, within_errors};
use crate::kernel::avx2_or_compiled;
use std::ops::Range;

/// The planes the passes read, of a `w` × `h` region: mean d̃ (of its channels), the
/// variance of d̃, d̃ RGB, albedo RGB, normal XYZ.
pub(super) type Planes<'a> = [&'a [f32]; 11];

/// The passes' inner loops: AVX2 where the CPU has it (twice as many lanes), else as
/// compiled. Chosen once per ceiling.
#[derive(Clone, Copy)]
pub(super) struct Passes {
    similar: AddSimilar,
    dense: AddDense,
    medians: Medians,
}

impl Passes {
    pub(super) fn avx2_or_not() -> Passes {
        Passes { similar: add_similar_avx2_or_not(), dense: add_dense_avx2_or_not(), medians: medians_avx2_or_not() }
    }

    /// The loops as compiled for the crate's target, whatever the CPU has.
    #[cfg(test)]
    pub(super) fn compiled() -> Passes {
        Passes { similar: add_similar, dense: add_dense, medians: super::median::medians }
    }
}

/// Visits the window of half-side `r` around each pixel of columns `xs` of row `y` of a
/// `w` × `h` region one offset at a time, in the window's order (rows, then columns):
/// `visit(offset, xs, there)` with the offset's index in that order, the columns of `xs`
/// whose neighbour there is inside the region, and the index of the first such neighbour
/// in the region's planes (the others follow it).
pub(in crate::denoise::bounds) fn window_offsets(
    (w, h): (usize, usize),
    y: usize,
    r: usize,
    xs: Range<usize>,
    mut visit: impl FnMut(usize, Range<usize>, usize),
) {
    let side = 2 * r + 1;
    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
        for dx in -(r as isize)..=r as isize {
            let x0 = xs.start.max((-dx).max(0) as usize);
            let x1 = xs.end.min((w as isize - dx.max(0)).max(0) as usize);
            if x1 > x0 {
                let offset = (yy + r - y) * side + (dx + r as isize) as usize;
                visit(offset, x0..x1, yy * w + (x0 as isize + dx) as usize);
            }
        }
    }
}

/// Makes `chosen` (per offset of the window of half-side `r` around each pixel of row `y`
/// of a `w` × `h` region, a row of `w` values, in [`window_offsets`]' order) `w · side²`
/// long, NaN wherever the neighbour lies outside the region: the values a row pass writes
/// for the others, and [`super::median::medians`] counts no NaN. Only those are written,
/// not the whole block (each row pass once filled it with NaN, 49 values a pixel).
pub(in crate::denoise::bounds) fn nan_outside((w, h): (usize, usize), y: usize, r: usize, chosen: &mut Vec<f32>) {
    let side = 2 * r + 1;
    chosen.resize(side * side * w, f32::NAN);
    for (offset, row) in chosen.chunks_exact_mut(w).enumerate() {
        let (dy, dx) = ((offset / side) as isize - r as isize, (offset % side) as isize - r as isize);
        let yy = y as isize + dy;
        if yy < 0 || yy >= h as isize {
            row.fill(f32::NAN);
        } else {
            // Columns x with x + dx outside 0..w.
            let left = ((-dx).max(0) as usize).min(w);
            let right = w.saturating_sub(dx.max(0) as usize).max(left);
            row[..left].fill(f32::NAN);
            row[right..].fill(f32::NAN);
        }
    }
}

/// Per worker, what [`dense_row`] gathers over a row: per pixel, its 7×7 window's lit
/// pixels; the pixels whose window is not sparse; per pixel, its similar neighbours and the
/// sums of their d̃; per offset of the window, the variance of each pixel's neighbour there
/// where that neighbour is similar and its variance finite (else NaN).
#[derive(Default)]
pub(super) struct DenseScratch {
    lit: Vec<u32>,
    dense: Vec<usize>,
    count: Vec<f32>,
    sums: [Vec<f32>; 3],
    chosen: Vec<f32>,
}

/// The ceiling of each pixel of row `y` (`out`: `[c][x]`) from its 7×7 window, on the
/// file's variances: the mean d̃ of its similar neighbours (alike in albedo and normal,
/// mean d̃ within 2 errors of the pixel's; the pixel always, where it is alike itself)
/// plus `errors` × the root of their median variance (finite ones; none: no margin). The
/// pixels where under half the window saw light (sparse) go into `sparse` instead.
#[allow(clippy::too_many_arguments)]
pub(super) fn dense_row(
    passes: Passes,
    planes: &Planes,
    w: usize,
    h: usize,
    y: usize,
    errors: f32,
    out: &mut [f32],
    sparse: &mut Vec<usize>,
    s: &mut DenseScratch,
) {
    let r = CEILING_RADIUS;
    let side = 2 * r + 1;
    // Which windows are sparse, from a box count: the similarity tests then run only over
    // the runs of pixels that are not (a room lit through an opening has few).
    lit_in_window_row(planes[0], w, h, y, r, &mut s.lit);
    let rows = y.saturating_sub(r)..(y + r + 1).min(h);
    s.dense.clear();
    for x in 0..w {
        let pixels = (rows.len() * ((x + r + 1).min(w) - x.saturating_sub(r))) as f32;
        if (s.lit[x] as f32) < LIT_SHARE * pixels { sparse.push(x) } else { s.dense.push(x) }
    }
    for plane in [&mut s.count].into_iter().chain(&mut s.sums) {
        plane.clear();
        plane.resize(w, 0.0);
    }
    nan_outside((w, h), y, r, &mut s.chosen);
    let centre = side * side / 2;
    for run in column_runs(&s.dense) {
        window_offsets((w, h), y, r, run, |offset, xs, there| {
            let here = planes.map(|p| &p[y * w..][xs.clone()]);
            let there = planes.map(|p| &p[there..][..xs.len()]);
            let [mi, vi, _, _, _, a0i, a1i, a2i, n0i, n1i, n2i] = here;
            let [mj, vj, d0, d1, d2, a0j, a1j, a2j, n0j, n1j, n2j] = there;
            let [s0, s1, s2] = s.sums.each_mut().map(|p| &mut p[xs.clone()]);
            (passes.dense)(
                [mi, vi, a0i, a1i, a2i, n0i, n1i, n2i],
                [mj, vj, d0, d1, d2],
                [a0j, a1j, a2j],
                [n0j, n1j, n2j],
                offset == centre,
                &mut s.count[xs.clone()],
                s0,
                s1,
                s2,
                &mut s.chosen[offset * w..][xs],
            );
        });
    }
    let mut medians = [0f32; LANES];
    for xs in s.dense.chunks(LANES) {
        (passes.medians)(&s.chosen, w, xs, true, &mut medians);
        for (&x, m) in xs.iter().zip(medians) {
            let reach = errors * m.max(0.0).sqrt();
            for c in 0..3 {
                out[c * w + x] = s.sums[c][x] / s.count[x] + reach;
            }
        }
    }
}

avx2_or_compiled!(
    /// The similarity test of [`dense_row`] at one offset: for each pixel of `here` (mean d̃,
    /// its variance, albedo RGB, normal XYZ) and its neighbour at the same place in `there`
    /// (mean d̃, its variance, d̃ RGB), `albedo` and `normal`, whether the neighbour is similar
    /// (into `count`, its d̃ into `s0`…`s2`, its variance into `chosen`, where finite; else
    /// NaN). `centre`: the neighbour is the pixel itself.
    /// Branch-free, so that it vectorises.
    type AddDense;
    fn add_dense_avx2_or_not() = add_dense(
        here: [&[f32]; 8],
        there: [&[f32]; 5],
        albedo: [&[f32]; 3],
        normal: [&[f32]; 3],
        centre: bool,
        count: &mut [f32],
        s0: &mut [f32],
        s1: &mut [f32],
        s2: &mut [f32],
        chosen: &mut [f32],
    )
);

/// See [`AddDense`]. Every row it writes is a parameter of its own, so that the compiler
/// knows they do not overlap what is read.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn add_dense(
    [mi, vi, a0i, a1i, a2i, n0i, n1i, n2i]: [&[f32]; 8],
    [mj, vj, d0, d1, d2]: [&[f32]; 5],
    [a0j, a1j, a2j]: [&[f32]; 3],
    [n0j, n1j, n2j]: [&[f32]; 3],
    centre: bool,
    count: &mut [f32],
    s0: &mut [f32],
    s1: &mut [f32],
    s2: &mut [f32],
    chosen: &mut [f32],
) {
    let n = count.len();
    let (mi, vi, a0i, a1i, a2i, n0i, n1i, n2i) =
        (&mi[..n], &vi[..n], &a0i[..n], &a1i[..n], &a2i[..n], &n0i[..n], &n1i[..n], &n2i[..n]);
    let (mj, vj, d0, d1, d2) = (&mj[..n], &vj[..n], &d0[..n], &d1[..n], &d2[..n]);
    let (a0j, a1j, a2j, n0j, n1j, n2j) = (&a0j[..n], &a1j[..n], &a2j[..n], &n0j[..n], &n1j[..n], &n2j[..n]);
    let (s0, s1, s2, chosen) = (&mut s0[..n], &mut s1[..n], &mut s2[..n], &mut chosen[..n]);
    for k in 0..n {
        let alike = alike_differences(
            [a0j[k] - a0i[k], a1j[k] - a1i[k], a2j[k] - a2i[k]],
            [n0j[k] - n0i[k], n1j[k] - n1i[k], n2j[k] - n2i[k]],
        );
        let similar = alike & (centre | within_errors(mj[k] - mi[k], vj[k] + vi[k]));
        count[k] += if similar { 1.0 } else { 0.0 };
        // Selected, not multiplied: a neighbour that is not similar adds nothing, even an
        // infinite one.
        s0[k] += if similar { d0[k] } else { 0.0 };
        s1[k] += if similar { d1[k] } else { 0.0 };
        s2[k] += if similar { d2[k] } else { 0.0 };
        let v = vj[k];
        chosen[k] = if similar & (v >= 0.0) & v.is_finite() { v } else { f32::NAN };
    }
}

/// How many sums [`window_row_sums`] keeps per pixel.
pub(super) const SUMS: usize = 6;

/// The sums of the ceiling's wide window, of half-side `r`, around each pixel of columns
/// `xs` of row `y`, from `planes` of a `w` × `h` region, into those columns of `acc` (each
/// `w` long; the other columns are left as they are): count of similar neighbours, their
/// variances and d̃ RGB, and the alike neighbours that saw light.
#[allow(clippy::too_many_arguments)]
pub(super) fn window_row_sums(
    passes: Passes,
    planes: &Planes,
    w: usize,
    h: usize,
    y: usize,
    r: usize,
    xs: Range<usize>,
    acc: &mut [Vec<f32>; SUMS],
) {
    acc.iter_mut().for_each(|a| a[xs.clone()].fill(0.0));
    window_offsets((w, h), y, r, xs, |_, xs, there| {
        let here = planes.map(|p| &p[y * w..][xs.clone()]);
        let there = planes.map(|p| &p[there..][..xs.len()]);
        window_sums(passes.similar, &here, &there, &mut acc.each_mut().map(|a| &mut a[xs.clone()]));
    });
}

/// How many pixels saw light (a mean d̃ other than 0; NaN counts, as in the window's
/// sums) in the window of half-side `r` around each pixel of row `y` of the `w` × `h`
/// plane `mean`, stopping at its edges: into `lit` (`w` long), from each column's count
/// over the window's rows, slid along the row.
pub(super) fn lit_in_window_row(mean: &[f32], w: usize, h: usize, y: usize, r: usize, lit: &mut Vec<u32>) {
    let mut columns = vec![0u32; w];
    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
        for (n, &m) in columns.iter_mut().zip(&mean[yy * w..(yy + 1) * w]) {
            *n += u32::from(m != 0.0);
        }
    }
    lit.clear();
    lit.resize(w, 0);
    let mut sum: u32 = columns[..r.min(w)].iter().sum();
    for x in 0..w {
        if x + r < w {
            sum += columns[x + r];
        }
        lit[x] = sum;
        if x >= r {
            sum -= columns[x - r];
        }
    }
}

/// The runs of `columns` (ascending) to visit a window over: consecutive columns and those
/// within a short gap of each other together, so that a row with a few such pixels at each
/// end is not visited from one end to the other.
pub(super) fn column_runs(columns: &[usize]) -> impl Iterator<Item = Range<usize>> + '_ {
    // Below this gap, one run costs less than two calls' set-up.
    const GAP: usize = 16;
    let ends = columns.windows(2).filter(|p| p[1] - p[0] > GAP).map(|p| (p[0] + 1, p[1]));
    let starts = columns.first().copied().into_iter().chain(ends.clone().map(|(_, start)| start));
    let stops = ends.map(|(stop, _)| stop).chain(columns.last().map(|&x| x + 1));
    starts.zip(stops).map(|(a, b)| a..b)
}

/// Adds, for each pixel of `here`, what its neighbour at the same place in `there` brings
/// to [`window_row_sums`]'s sums `acc`, with `add`. Branch-free, so that it vectorises.
fn window_sums(add: AddSimilar, here: &Planes, there: &Planes, acc: &mut [&mut [f32]; SUMS]) {
    let n = here[0].len();
    let [mi, vi, _, _, _, a0i, a1i, a2i, n0i, n1i, n2i] = here.map(|p| &p[..n]);
    let [mj, vj, d0, d1, d2, a0j, a1j, a2j, n0j, n1j, n2j] = there.map(|p| &p[..n]);
    let [count, variance, s0, s1, s2, hits] = acc.each_mut().map(|a| &mut a[..n]);
    add(
        [mi, vi, a0i, a1i, a2i, n0i, n1i, n2i],
        mj,
        vj,
        [d0, d1, d2],
        [a0j, a1j, a2j],
        [n0j, n1j, n2j],
        count,
        variance,
        [s0, s1, s2],
        hits,
    );
}

avx2_or_compiled!(
    /// The similarity test and sums of [`window_sums`].
    type AddSimilar;
    fn add_similar_avx2_or_not() = add_similar(
        here: [&[f32]; 8],
        mj: &[f32],
        vj: &[f32],
        d: [&[f32]; 3],
        a: [&[f32]; 3],
        n: [&[f32]; 3],
        count: &mut [f32],
        variance: &mut [f32],
        s: [&mut [f32]; 3],
        hits: &mut [f32],
    )
);

/// The similarity test and sums of [`window_sums`]. Every row it writes is a parameter of
/// its own: the compiler knows only those not to overlap what is read, and vectorises the
/// loop (slices inside arrays leave it scalar, four times slower).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn add_similar(
    [mi, vi, a0i, a1i, a2i, n0i, n1i, n2i]: [&[f32]; 8],
    mj: &[f32],
    vj: &[f32],
    [d0, d1, d2]: [&[f32]; 3],
    [a0j, a1j, a2j]: [&[f32]; 3],
    [n0j, n1j, n2j]: [&[f32]; 3],
    count: &mut [f32],
    variance: &mut [f32],
    [s0, s1, s2]: [&mut [f32]; 3],
    hits: &mut [f32],
) {
    for k in 0..count.len() {
        let albedo = (a0j[k] - a0i[k]).abs().max((a1j[k] - a1i[k]).abs()).max((a2j[k] - a2i[k]).abs());
        let (e0, e1, e2) = (n0j[k] - n0i[k], n1j[k] - n1i[k], n2j[k] - n2i[k]);
        let e = mj[k] - mi[k];
        let alike = alike_surfaces(albedo, e0 * e0 + e1 * e1 + e2 * e2);
        hits[k] += if alike & (mj[k] != 0.0) { 1.0 } else { 0.0 };
        let similar = alike & within_errors(e, vj[k] + vi[k]);
        let s = if similar { 1.0 } else { 0.0 };
        count[k] += s;
        variance[k] += s * vj[k];
        s0[k] += s * d0[k];
        s1[k] += s * d1[k];
        s2[k] += s * d2[k];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rows_lit_counts_are_its_windows_counted_one_by_one() {
        // Zeros, NaNs (lit, as the window's sums count them) and values; windows cut by
        // every edge, and a window wider than the plane.
        let (w, h) = (13, 9);
        let mean: Vec<f32> = (0..w * h)
            .map(|i| match (i * 7 + i / w) % 5 {
                0 | 1 => 0.0,
                2 => f32::NAN,
                3 => -0.0,
                _ => 0.5,
            })
            .collect();
        let (mean, mut lit) = (&mean, Vec::new());
        for r in [1, 3, 7, 20] {
            for y in 0..h {
                lit_in_window_row(mean, w, h, y, r, &mut lit);
                for (x, &got) in lit.iter().enumerate() {
                    let rows = y.saturating_sub(r)..(y + r + 1).min(h);
                    let columns = x.saturating_sub(r)..(x + r + 1).min(w);
                    let want = rows.flat_map(|yy| columns.clone().map(move |xx| mean[yy * w + xx]));
                    assert_eq!(got, want.filter(|&m| m != 0.0).count() as u32, "r {r} ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn columns_are_visited_in_runs_split_at_long_gaps() {
        let runs = |columns: &[usize]| column_runs(columns).collect::<Vec<_>>();
        assert_eq!(runs(&[]), Vec::<Range<usize>>::new());
        assert_eq!(runs(&[5]), vec![5..6]);
        // Gaps of up to 16 columns stay in one run; a longer one splits it.
        assert_eq!(runs(&[0, 1, 17, 40, 41, 300]), [0..18, 40..42, 300..301]);
    }

    #[test]
    fn exactly_the_neighbours_outside_the_region_are_nan_whatever_was_there() {
        // Regions narrower and shorter than a window, and wider; every row. What was there
        // before (a previous row's values) must not show through anywhere the passes do
        // not write, and nowhere they do write may be NaN already.
        for (w, h, r) in [(1, 1, 3), (2, 5, 3), (13, 9, 3), (40, 3, 1), (9, 12, 7)] {
            let side = 2 * r + 1;
            let mut chosen = vec![7.0; side * side * w + 5];
            for y in 0..h {
                chosen.iter_mut().for_each(|v| *v = 7.0);
                nan_outside((w, h), y, r, &mut chosen);
                assert_eq!(chosen.len(), side * side * w);
                let mut visited = vec![false; chosen.len()];
                window_offsets((w, h), y, r, 0..w, |offset, xs, _| {
                    visited[offset * w..][xs].iter_mut().for_each(|v| *v = true);
                });
                for (i, (&v, &inside)) in chosen.iter().zip(&visited).enumerate() {
                    assert_eq!(v.is_nan(), !inside, "{w}×{h}, r {r}, row {y}, offset {}, column {}", i / w, i % w);
                }
            }
        }
    }
}
