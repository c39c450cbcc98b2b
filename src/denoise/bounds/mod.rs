//! How far each branch may move a pixel from what the noisy frame shows, applied when the
//! branches are recomposed ([`super::recompose`]): the specular branch by the pixel's own
//! standard error, or its alike neighbours' where their window is noisy
//! ([`NoisySpecular`]), the diffuse branch by its similar neighbours' ([`DiffuseCeiling`]).
//! Both are computed from the features of a band's rows, so the streamed, tiled and
//! whole-frame paths bound alike. What the diffuse ceiling takes is dropped, or spread
//! over the window around where it was taken ([`Take::spread`]); then the shading detail
//! the diffuse branch smoothed away may be restored ([`Detail`]).

use crate::features::{EPSILON, Features};
use crate::model::Architecture;
use rayon::prelude::*;
use std::ops::Range;

mod ceiling;
mod detail;
mod specular;
mod spread;

pub(crate) use ceiling::{CEILING_RADIUS, DiffuseCeiling, SPARSE_RADIUS};
pub(crate) use detail::Detail;
pub(crate) use specular::NoisySpecular;
pub(crate) use spread::Take;

/// The bounds of a model over rows of a band ([`Architecture::specular_bound`],
/// [`Architecture::diffuse_bound`]), and what it does with the diffuse branch's output
/// beyond them ([`Architecture::diffuse_spread`], [`Architecture::diffuse_detail`]);
/// each `None` where the model has none.
#[derive(Default)]
pub(crate) struct Bounds {
    pub(crate) specular: Option<NoisySpecular>,
    pub(crate) diffuse: Option<DiffuseCeiling>,
    /// The radius the diffuse ceiling's take is spread over ([`Take::spread`]), where the
    /// model spreads it.
    pub(crate) spread: Option<usize>,
    /// Where it does, the noisy diffuse light of each pixel (exposed radiance, the mean of
    /// its channels): what the spread shares out by.
    noisy_light: Vec<f32>,
    /// The radius of the windows the diffuse detail is restored over ([`Detail::restore`]),
    /// where the model restores it.
    pub(crate) detail: Option<usize>,
    /// Where it does, the noisy d̃, the shading normal and the variance of d̃ of each pixel
    /// (planes 0–2, 3–5, 6).
    detail_guides: Vec<Vec<f32>>,
}

impl Bounds {
    /// The bounds of `arch` over rows `rows` of the region `f` holds, whose rows beyond
    /// them are context: [`Bounds::context`] at least where the frame goes on.
    pub(crate) fn of(arch: &Architecture, f: &Features, rows: Range<usize>) -> Bounds {
        let diffuse = DiffuseCeiling::of(arch, f, rows.clone());
        let spread = diffuse.as_ref().and(Bounds::spread_radius(arch));
        let pixels = rows.start * f.width..rows.end * f.width;
        let noisy_light = match spread {
            Some(_) => {
                let (d, a) = (&f.d_tilde, &f.albedo);
                let light = |i: usize| (0..3).map(|c| (a[c][i] + EPSILON) * d[c][i]).sum::<f32>() / 3.0;
                pixels.clone().into_par_iter().map(light).collect()
            }
            None => Vec::new(),
        };
        let detail = arch.diffuse_detail.map(usize::from);
        let detail_guides = match detail {
            Some(_) => {
                f.d_tilde.iter().chain(&f.normal).chain([&f.d_variance]).map(|p| p[pixels.clone()].to_vec()).collect()
            }
            None => Vec::new(),
        };
        Bounds { specular: NoisySpecular::of(arch, f, rows), diffuse, spread, noisy_light, detail, detail_guides }
    }

    /// The radius `arch` spreads its diffuse ceiling's take over, where it has a ceiling and
    /// spreads.
    pub(crate) fn spread_radius(arch: &Architecture) -> Option<usize> {
        arch.diffuse_bound.and(arch.diffuse_spread).map(usize::from)
    }

    /// Rows beyond a band's whose diffuse output its own reads: the spread's
    /// ([`Take::spread`]: the windows of its windows, and the 3×3 medians of their light,
    /// 2r + 1) and the detail's ([`Detail::restore`]: the windows of its windows, 2r); 0
    /// where `arch` does neither.
    pub(crate) fn diffuse_context(arch: &Architecture) -> usize {
        let spread = Bounds::spread_radius(arch).map_or(0, |r| 2 * r + 1);
        spread.max(arch.diffuse_detail.map_or(0, |r| 2 * usize::from(r)))
    }

    /// Whether a band's diffuse output depends on its neighbours' ([`Bounds::diffuse_context`]).
    pub(crate) fn reads_neighbours(arch: &Architecture) -> bool {
        Bounds::diffuse_context(arch) > 0
    }

    /// Bounds the diffuse branch's output `d_hat` (exposed, these rows or the first of
    /// them) in place where the model has a ceiling; where it also spreads, what the ceiling
    /// took from each pixel, in exposed radiance ((albedo + ε) × d̂; `albedo` of those
    /// rows), beside the noisy light it is shared out by.
    pub(crate) fn bound_diffuse(&self, albedo: &[Vec<f32>; 3], d_hat: &mut [Vec<f32>; 3]) -> Option<Take> {
        let ceiling = self.diffuse.as_ref()?;
        if self.spread.is_none() {
            ceiling.apply(d_hat);
            return None;
        }
        let before = d_hat.clone();
        ceiling.apply(d_hat);
        let n = d_hat[0].len();
        Some(BandPlanes(std::array::from_fn(|c| match c {
            3 => self.noisy_light[..n].to_vec(),
            c => before[c]
                .iter()
                .zip(&d_hat[c])
                .zip(&albedo[c])
                // Only finite light moves: a NaN or infinite output (hostile input) is the
                // ceiling's and recompose's to mend, never spread over its neighbours.
                .map(|((b, d), a)| if (b - d).is_finite() { (a + EPSILON) * (b - d).max(0.0) } else { 0.0 })
                .collect(),
        })))
    }

    /// Where the model restores the diffuse detail, what [`Detail::restore`] reads of
    /// these rows (or the first of them): `d_hat` (within its ceiling), the noisy d̃, the
    /// normals and the variance of d̃.
    pub(crate) fn detail_inputs(&self, d_hat: &[Vec<f32>; 3]) -> Option<Detail> {
        self.detail?;
        let n = d_hat[0].len();
        Some(BandPlanes(std::array::from_fn(|c| match c {
            0..3 => d_hat[c].clone(),
            c => self.detail_guides[c - 3][..n].to_vec(),
        })))
    }

    /// Restores the diffuse detail of `d_hat` (exposed, these rows, within its ceiling) in
    /// place where the model does, from these rows alone: exact for rows
    /// [`Bounds::diffuse_context`] rows from any cut that is not the frame's edge.
    pub(crate) fn restore_detail(&self, w: usize, d_hat: &mut [Vec<f32>; 3]) {
        if let Some((inputs, r)) = self.detail_inputs(d_hat).zip(self.detail) {
            add_detail(d_hat, &inputs.restore(w, r));
        }
    }

    /// Rows of features beyond a band's that its bounds read, beyond those its features
    /// themselves need ([`crate::features::CONTEXT`]).
    pub(crate) fn context(arch: &Architecture) -> usize {
        let diffuse = arch.diffuse_bound.map_or(0, |_| SPARSE_RADIUS);
        diffuse.max(arch.specular_bound.map_or(0, |_| CEILING_RADIUS))
    }
}

/// `d_hat` with `detail` added, each pixel of it.
pub(crate) fn add_detail(d_hat: &mut [Vec<f32>; 3], detail: &[Vec<f32>; 3]) {
    for (d, e) in d_hat.iter_mut().zip(detail) {
        d.par_iter_mut().zip(e).for_each(|(d, e)| *d += e);
    }
}

/// Planes of rows of a band, each `[pixel]` of rows `w` wide: cut and joined by row, so
/// that a streamed band can be given its neighbours' rows.
#[derive(Clone)]
pub(crate) struct BandPlanes<const N: usize>(pub(crate) [Vec<f32>; N]);

impl<const N: usize> Default for BandPlanes<N> {
    fn default() -> Self {
        BandPlanes(std::array::from_fn(|_| Vec::new()))
    }
}

impl<const N: usize> From<[Vec<f32>; N]> for BandPlanes<N> {
    fn from(planes: [Vec<f32>; N]) -> Self {
        BandPlanes(planes)
    }
}

impl<const N: usize> BandPlanes<N> {
    /// Rows `rows` of it (`w` wide).
    pub(crate) fn rows(&self, rows: Range<usize>, w: usize) -> Self {
        let cut = rows.start * w..rows.end * w;
        BandPlanes(std::array::from_fn(|c| self.0[c][cut.clone()].to_vec()))
    }

    /// `self` with `below`'s rows after its own.
    pub(crate) fn then(mut self, below: &Self) -> Self {
        self.0.iter_mut().zip(&below.0).for_each(|(p, b)| p.extend_from_slice(b));
        self
    }

    /// Its rows, `w` wide.
    pub(crate) fn height(&self, w: usize) -> usize {
        self.0[0].len() / w.max(1)
    }
}

/// The largest magnitude [`box_sums`] sums a row of with a running sum.
const RUNNING_SUM_LIMIT: f32 = 1e4;

/// The sums of `plane` (rows `rows` of a `w`-wide frame) over the (2r + 1)² window around
/// each pixel of those rows, cut at the frame's edges and at `rows`: along each row, then
/// down each column, each in the same order whatever `rows` is.
pub(super) fn box_sums(plane: &[f32], w: usize, r: usize, rows: usize) -> Vec<f32> {
    box_means(w, r, rows, None, |y, _| Some(&plane[y * w..(y + 1) * w]))
}

/// [`box_sums`] of the plane whose row `y` `row(y, scratch)` gives (or, where it gives
/// none, writes into `scratch`, a worker's row `w` long), each divided by `count`'s pixel
/// where given: the same sums in the same order, without that plane or the sums held twice.
pub(super) fn box_means<'a>(
    w: usize,
    r: usize,
    rows: usize,
    count: Option<&[f32]>,
    row: impl Fn(usize, &mut [f32]) -> Option<&'a [f32]> + Sync,
) -> Vec<f32> {
    if w == 0 {
        return Vec::new();
    }
    let mut across = vec![0f32; w * rows];
    across.par_chunks_mut(w * ROWS_AT_ONCE).enumerate().for_each_init(
        || vec![0f32; w * ROWS_AT_ONCE],
        |scratch, (g, out)| {
            let n = out.len() / w;
            let mut given: [Option<&'a [f32]>; ROWS_AT_ONCE] = [None; ROWS_AT_ONCE];
            for (k, s) in scratch.chunks_mut(w).take(n).enumerate() {
                given[k] = row(g * ROWS_AT_ONCE + k, s);
            }
            // Rows past the plane's last (a short last group) are empty.
            let src: [&[f32]; ROWS_AT_ONCE] =
                std::array::from_fn(|k| given[k].unwrap_or(if k < n { &scratch[k * w..(k + 1) * w] } else { &[] }));
            // A running sum along each row, in f64, where its values are moderate: what
            // leaves the window is then taken off to far below f32's rounding, and a huge
            // or non-finite value (hostile input) cannot spoil the rest of the row, which
            // is summed window by window. Rows are whole, so either way runs alike whatever
            // `rows` is.
            let moderate = |row: &[f32]| row.iter().all(|v| v.abs() <= RUNNING_SUM_LIMIT);
            if n == ROWS_AT_ONCE && src.iter().all(|row| moderate(row)) {
                return running_sums(src, out, r);
            }
            for (row, out) in src.iter().zip(out.chunks_mut(w)) {
                if moderate(row) {
                    running_sums([row], out, r);
                } else {
                    for (x, o) in out.iter_mut().enumerate() {
                        *o = row[x.saturating_sub(r)..(x + r + 1).min(w)].iter().sum();
                    }
                }
            }
        },
    );
    let mut out = vec![0f32; w * rows];
    out.par_chunks_mut(w).enumerate().for_each(|(k, o)| {
        let window = k.saturating_sub(r)..(k + r + 1).min(rows);
        let count = count.map(|c| &c[k * w..(k + 1) * w]);
        // A block of columns at a time, its sums held in registers down the window:
        // each still starts at 0 and adds the rows in order, then divides.
        let mut x0 = 0;
        while x0 < w {
            let n = COLUMNS_AT_ONCE.min(w - x0);
            let mut sums = [0f32; COLUMNS_AT_ONCE];
            for j in window.clone() {
                let a = &across[j * w + x0..][..n];
                // A whole block with a constant bound, which the compiler unrolls into
                // registers; the plane's last, narrower block as it comes.
                if n == COLUMNS_AT_ONCE {
                    (0..COLUMNS_AT_ONCE).for_each(|i| sums[i] += a[i]);
                } else {
                    sums.iter_mut().zip(a).for_each(|(s, a)| *s += a);
                }
            }
            let o = &mut o[x0..x0 + n];
            match count {
                Some(count) => o.iter_mut().zip(&sums).zip(&count[x0..]).for_each(|((o, s), c)| *o = s / c),
                None => o.copy_from_slice(&sums[..n]),
            }
            x0 += n;
        }
    });
    out
}

/// Rows [`box_means`]'s row pass sums side by side: their running sums are independent
/// chains of additions, which a core then overlaps instead of waiting on each.
const ROWS_AT_ONCE: usize = 8;

/// Columns [`box_means`]'s column pass sums at a time, in registers.
const COLUMNS_AT_ONCE: usize = 64;

/// The sums of each of `rows` (moderate values, each `w` long) over the window of radius
/// `r` around each pixel, into `out`'s rows: a running sum in f64 per row, `N` rows a
/// step, each row's in the one order.
#[inline(always)]
fn running_sums<const N: usize>(rows: [&[f32]; N], out: &mut [f32], r: usize) {
    let w = out.len() / N;
    let rows: [&[f32]; N] = rows.map(|row| &row[..w]);
    let mut sum: [f64; N] = rows.map(|row| row[..r.min(w)].iter().map(|&v| f64::from(v)).sum());
    for x in 0..w {
        for k in 0..N {
            if x + r < w {
                sum[k] += f64::from(rows[k][x + r]);
            }
            if x > r {
                sum[k] -= f64::from(rows[k][x - r - 1]);
            }
            out[k * w + x] = sum[k] as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::recompose;
    use super::*;
    use crate::model::{Specular, Variances};

    /// A value in [0, 1) drawn from pixel `i` and plane `k`.
    pub(in crate::denoise::bounds) fn hash(i: usize, k: usize) -> f32 {
        ((i * 7919 + k * 104_729) % 1009) as f32 / 1009.0
    }

    /// [`box_means`] a row and a pixel at a time: each row's running sum (or, where a value
    /// is not moderate, each window's sum), then each column's window of rows added in
    /// order from 0 and divided. What the blocked passes must give, bit for bit.
    fn box_means_pixel_by_pixel(plane: &[f32], w: usize, r: usize, rows: usize, count: Option<&[f32]>) -> Vec<f32> {
        let mut across = vec![0f32; w * rows];
        for (row, out) in plane.chunks(w).zip(across.chunks_mut(w)) {
            if !row.iter().all(|v| v.abs() <= RUNNING_SUM_LIMIT) {
                for (x, o) in out.iter_mut().enumerate() {
                    *o = row[x.saturating_sub(r)..(x + r + 1).min(w)].iter().sum();
                }
                continue;
            }
            let mut sum: f64 = row[..r.min(w)].iter().map(|&v| f64::from(v)).sum();
            for (x, o) in out.iter_mut().enumerate() {
                if x + r < w {
                    sum += f64::from(row[x + r]);
                }
                if x > r {
                    sum -= f64::from(row[x - r - 1]);
                }
                *o = sum as f32;
            }
        }
        (0..w * rows)
            .map(|i| {
                let (k, x) = (i / w, i % w);
                let mut o = 0f32;
                for j in k.saturating_sub(r)..(k + r + 1).min(rows) {
                    o += across[j * w + x];
                }
                count.map_or(o, |c| o / c[i])
            })
            .collect()
    }

    #[test]
    fn box_means_are_the_pixel_by_pixel_sums_bit_for_bit() {
        // Widths around the column block (64), heights around the row group (8), radii
        // wider than the plane, and rows of huge or non-finite values among moderate ones.
        for (w, rows, r) in [(1, 1, 0), (5, 3, 7), (63, 9, 2), (64, 8, 3), (130, 17, 7), (70, 24, 1)] {
            for spoiled in [false, true] {
                let plane: Vec<f32> = (0..w * rows)
                    .map(|i| match (spoiled, (i / w) % 5, i % 13) {
                        (true, 2, 3) => hostile(i, 0, 3e4, 3),
                        _ => hash(i, 1) * 10.0 - 3.0,
                    })
                    .collect();
                let count: Vec<f32> = (0..w * rows).map(|i| 1.0 + (i % 7) as f32).collect();
                for count in [None, Some(&count[..])] {
                    let got = box_means(w, r, rows, count, |y, _| Some(&plane[y * w..(y + 1) * w]));
                    let want = box_means_pixel_by_pixel(&plane, w, r, rows, count);
                    assert!(
                        got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()),
                        "{w}×{rows}, r {r}, spoiled {spoiled}, counted {}",
                        count.is_some()
                    );
                    // Rows written into the scratch rather than given, alike.
                    let written = box_means(w, r, rows, count, |y, scratch| {
                        scratch.copy_from_slice(&plane[y * w..(y + 1) * w]);
                        None
                    });
                    assert!(written.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()));
                }
            }
        }
    }

    /// `v` at pixel `i` of plane `k`, but NaN, +∞ or −`v` at one pixel in `every` each.
    pub(in crate::denoise::bounds) fn hostile(i: usize, k: usize, v: f32, every: usize) -> f32 {
        match (i * 31 + k * 17) % every {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => -v,
            _ => v,
        }
    }

    #[test]
    fn a_streamed_band_is_read_with_the_context_rows_its_ceiling_needs() {
        let ladder = Architecture::ladder(crate::model::Quality::Fast);
        let context = crate::features::CONTEXT;
        for (diffuse_bound, specular_bound, variances, context) in [
            (None, None, Variances::File, context),
            (None, Some(2), Variances::File, context + CEILING_RADIUS),
            (Some(2), Some(2), Variances::File, context + SPARSE_RADIUS),
            (None, None, Variances::Spatial, context),
            (Some(2), None, Variances::Spatial, context + SPARSE_RADIUS),
        ] {
            let arch = Architecture { diffuse_bound, specular_bound, variances, ..ladder };
            let d = super::super::Denoiser::new(crate::model::Model::xavier(arch, 1).unwrap(), Default::default());
            let d = d.unwrap();
            assert!(d.streams(640));
            assert_eq!(d.halo(640), context, "{diffuse_bound:?} {specular_bound:?} {variances:?}");
        }
    }

    #[test]
    fn a_bound_on_hostile_values_never_panics_and_stays_finite() {
        let mut b = specular::tests::bound(
            &[1.0, 0.0, 3e38, 1.0],
            &[f32::NAN, f32::INFINITY, 3e38, 1.0],
            &[1.0, 0.0, 3e38, 1.0],
        );
        b.variance[0] = f32::NAN;
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![f32::NAN, 5.0, 1.0, 1.0]);
        b.apply(&mut out);
        let ceiling = DiffuseCeiling { ceiling: [f32::NAN, 1.0, f32::INFINITY, 0.5].repeat(3), width: 4 };
        let bounds = Bounds {
            specular: Some(b),
            diffuse: Some(ceiling),
            spread: Some(1),
            noisy_light: vec![f32::NAN, 1.0, f32::INFINITY, 3e38],
            detail: Some(1),
            detail_guides: [vec![f32::NAN, 0.2, -3e38, f32::INFINITY], vec![0.0, 1.0, f32::NAN, 0.5]]
                .into_iter()
                .cycle()
                .take(7)
                .collect(),
        };
        let albedo = std::array::from_fn(|_| vec![0.5; 4]);
        let mut d_hat = std::array::from_fn(|_| vec![f32::NAN, 0.1, f32::INFINITY, 3e38]);
        // The spread shares out what the ceiling takes: the finite excess only.
        let glow = bounds.bound_diffuse(&albedo, &mut d_hat).map(|t| t.spread(4, 1));
        bounds.restore_detail(4, &mut d_hat);
        let s_hat = std::array::from_fn(|_| vec![f32::NAN, 90.0, -1.0, 1.0]);
        let d = recompose(&albedo, d_hat, &s_hat, (4, 1), Specular::Log, 1.0, &bounds, glow.as_ref());
        assert!(d.color.iter().flatten().all(|v| v.is_finite()), "{:?}", d.color);
    }
}
