//! Preprocessing (ARCHITECTURE.md §Features): from the renderer's buffers to the 27-channel network input of
//! each branch.
//!
//! Per branch, in this order: `[c̃ 3][Gx of (c̃ 3, normal 3, albedo 3, depth 1)][Gy of the
//! same 10][σ̃²_c 1][σ²_normal 1, σ²_albedo 1, σ²_depth 1]`, where c̃ is the demodulated
//! diffuse `d̃ = diffuse / (albedo + ε)` or the log specular `s̃ = ln(1 + max(specular, 0))`.

use crate::io::layout::KpcnInputs;
use rayon::prelude::*;
use std::borrow::Cow;
use std::ops::Range;

mod exposure;
mod repairs;

pub use exposure::{EXPOSURE_BLOCK, EXPOSURE_KEY, ExposureMeter, FrameStats, FrameStatsMeter, auto_exposure};
pub use repairs::{Repairs, repairs};

/// Context (pixels, each side) a pixel's network input depends on beyond the pixel: one
/// for the backward-difference gradients, one for the 3×3 variance estimates.
pub const CONTEXT: usize = 2;

/// The paper's ε, used in albedo demodulation and recomposition.
pub const EPSILON: f32 = 0.00316;
/// Channels of one branch's input.
pub const INPUT_CHANNELS: usize = 27;
/// The input layout's name, recorded in model files.
pub const INPUT_LAYOUT: &str = "kpcn27-v1";
/// Magnitude every input sample is clamped to after NaN/Inf removal. Far above physical
/// render values, low enough that products and squares of inputs stay finite in f32.
pub const MAX_MAGNITUDE: f32 = 1e15;

/// Which network branch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "tools", derive(clap::ValueEnum))]
pub enum Branch {
    /// Demodulated diffuse.
    Diffuse,
    /// Log specular.
    Specular,
}

/// A frame's preprocessed buffers (whole frame, sanitised), from which branch inputs of any
/// region are extracted. Gradients are computed on demand from whole-frame values, so a
/// tile's input equals the same region of the untiled input exactly.
#[derive(Debug, Clone, PartialEq)]
pub struct Features {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// d̃ = diffuse / (albedo + ε).
    pub d_tilde: [Vec<f32>; 3],
    /// s̃ = ln(1 + max(specular, 0)).
    pub s_tilde: [Vec<f32>; 3],
    /// Shading normal.
    pub normal: [Vec<f32>; 3],
    /// Albedo, clamped ≥ 0 (also used for recomposition).
    pub albedo: [Vec<f32>; 3],
    /// Depth / the frame's largest finite depth.
    pub depth: Vec<f32>,
    /// Variance of d̃.
    pub d_variance: Vec<f32>,
    /// Variance of s̃ (delta method).
    pub s_variance: Vec<f32>,
    /// Variance of the normal.
    pub normal_variance: Vec<f32>,
    /// Variance of the albedo.
    pub albedo_variance: Vec<f32>,
    /// Variance of the normalised depth.
    pub depth_variance: Vec<f32>,
    /// The factor the radiance inputs (and their variances, squared) were multiplied by:
    /// 1 for raw inputs; the output is divided by it.
    pub exposure: f32,
}

/// Reflects an index into `0..n` (mirror without repeating the edge; folds again for
/// indices further out than `n`, so tiny frames work).
pub fn reflect(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let period = 2 * (n as isize - 1);
    let m = i.rem_euclid(period);
    (if m < n as isize { m } else { period - m }) as usize
}

/// NaN and ±Inf become 0 (never float max: it poisons squares); then a magnitude clamp.
pub fn sanitize(v: f32) -> f32 {
    if v.is_finite() { v.clamp(-MAX_MAGNITUDE, MAX_MAGNITUDE) } else { 0.0 }
}

/// A variance: sanitised and never negative.
fn clean_variance_of(v: f32) -> f32 {
    sanitize(v).max(0.0)
}

/// An input plane that [`Features::for_frame`] transforms elementwise: in place when the
/// inputs are owned, into a new plane when borrowed.
enum Plane<'a> {
    Owned(Vec<f32>),
    Borrowed(&'a [f32]),
}

impl Plane<'_> {
    fn map(self, f: impl Fn(f32) -> f32 + Sync + Send) -> Vec<f32> {
        match self {
            Plane::Owned(mut v) => {
                v.par_iter_mut().for_each(|x| *x = f(*x));
                v
            }
            Plane::Borrowed(p) => p.par_iter().map(|&x| f(x)).collect(),
        }
    }
}

/// The inputs [`Features`] are made of (the colour and its variance are not).
struct Planes<'a> {
    diffuse: [Plane<'a>; 3],
    specular: [Plane<'a>; 3],
    albedo: [Plane<'a>; 3],
    normal: [Plane<'a>; 3],
    depth: Plane<'a>,
    diffuse_variance: Plane<'a>,
    specular_variance: Plane<'a>,
    albedo_variance: Plane<'a>,
    normal_variance: Plane<'a>,
    depth_variance: Plane<'a>,
}

impl<'a> Planes<'a> {
    fn of(k: Cow<'a, KpcnInputs>) -> Planes<'a> {
        match k {
            Cow::Owned(k) => {
                let three = |p: [Vec<f32>; 3]| p.map(Plane::Owned);
                Planes {
                    diffuse: three(k.diffuse),
                    specular: three(k.specular),
                    albedo: three(k.albedo),
                    normal: three(k.normal),
                    depth: Plane::Owned(k.depth),
                    diffuse_variance: Plane::Owned(k.diffuse_variance),
                    specular_variance: Plane::Owned(k.specular_variance),
                    albedo_variance: Plane::Owned(k.albedo_variance),
                    normal_variance: Plane::Owned(k.normal_variance),
                    depth_variance: Plane::Owned(k.depth_variance),
                }
            }
            Cow::Borrowed(k) => {
                let three = |p: &'a [Vec<f32>; 3]| p.each_ref().map(|v| Plane::Borrowed(v));
                Planes {
                    diffuse: three(&k.diffuse),
                    specular: three(&k.specular),
                    albedo: three(&k.albedo),
                    normal: three(&k.normal),
                    depth: Plane::Borrowed(&k.depth),
                    diffuse_variance: Plane::Borrowed(&k.diffuse_variance),
                    specular_variance: Plane::Borrowed(&k.specular_variance),
                    albedo_variance: Plane::Borrowed(&k.albedo_variance),
                    normal_variance: Plane::Borrowed(&k.normal_variance),
                    depth_variance: Plane::Borrowed(&k.depth_variance),
                }
            }
        }
    }
}

/// Backward differences `I[x] − I[x−1]` (0 in the first column) and `I[y] − I[y−1]`.
pub fn gradients(p: &[f32], w: usize, h: usize) -> (Vec<f32>, Vec<f32>) {
    let gx = (0..w * h).map(|i| grad_at(p, w, i % w, i / w, true)).collect();
    let gy = (0..w * h).map(|i| grad_at(p, w, i % w, i / w, false)).collect();
    (gx, gy)
}

fn grad_at(p: &[f32], w: usize, x: usize, y: usize, along_x: bool) -> f32 {
    let i = y * w + x;
    let g = match (along_x, x, y) {
        (true, 0, _) | (false, _, 0) => 0.0,
        (true, ..) => p[i] - p[i - 1],
        (false, ..) => p[i] - p[i - w],
    };
    sanitize(g)
}

/// [`grad_at`] of frame columns `span` of row `y` of `p` (`w` wide), into `out`: a
/// slice at a time, so that it vectorises.
fn gradient_row(p: &[f32], w: usize, y: usize, along_x: bool, span: Range<usize>, out: &mut Vec<f32>) {
    out.clear();
    if span.is_empty() {
        return;
    }
    let row = &p[y * w..][..w];
    let (from, to) = match (along_x, y) {
        (true, _) => (&row[span.start.max(1)..span.end], &row[span.start.max(1) - 1..span.end - 1]),
        (false, 0) => return out.resize(span.len(), 0.0),
        (false, _) => (&row[span.clone()], &p[(y - 1) * w..][span.clone()]),
    };
    if along_x && span.start == 0 {
        out.push(0.0);
    }
    out.extend(from.iter().zip(to).map(|(a, b)| sanitize(a - b)));
}

/// A region's columns reflected into the frame, as runs of consecutive frame columns
/// (up or down): a region past the frame's sides is three runs, which copy a slice at a
/// time instead of a column at a time.
struct Columns {
    /// `(first region column, first frame column, length, ascending)`.
    runs: Vec<(usize, usize, usize, bool)>,
    /// The frame columns the region reads.
    span: Range<usize>,
}

impl Columns {
    /// The runs of `xs`, the frame column of each region column.
    fn new(xs: impl Iterator<Item = usize>) -> Columns {
        let mut runs: Vec<(usize, usize, usize, bool)> = Vec::new();
        let (mut lo, mut hi, mut at) = (usize::MAX, 0, 0);
        for x in xs {
            (lo, hi) = (lo.min(x), hi.max(x + 1));
            match runs.last_mut() {
                Some((_, first, len, up)) if *len == 1 && first.abs_diff(x) == 1 => (*len, *up) = (2, x > *first),
                Some((_, first, len, true)) if *first + *len == x => *len += 1,
                Some((_, first, len, false)) if first.checked_sub(*len) == Some(x) => *len += 1,
                _ => runs.push((at, x, 1, true)),
            }
            at += 1;
        }
        Columns { runs, span: lo.min(hi)..hi }
    }

    /// The frame columns read.
    fn span(&self) -> Range<usize> {
        self.span.clone()
    }

    /// `row` from `src`, a frame row's columns from `from` on.
    fn gather(&self, row: &mut [f32], src: &[f32], from: usize) {
        for &(at, x, len, up) in &self.runs {
            let out = &mut row[at..at + len];
            if up {
                out.copy_from_slice(&src[x - from..][..len]);
            } else {
                out.iter_mut().zip(src[x + 1 - len - from..=x - from].iter().rev()).for_each(|(o, &v)| *o = v);
            }
        }
    }
}

/// The largest finite depth (0 when none is positive): depth is divided by it.
pub fn max_depth(depth: &[f32]) -> f32 {
    depth.iter().fold(0f32, |m, &d| m.max(sanitize(d)))
}

/// Demodulated diffuse `diffuse / (albedo + ε)` of one pixel.
pub fn demodulated(diffuse: f32, albedo: f32) -> f32 {
    diffuse / (albedo + EPSILON)
}

/// Log specular `ln(1 + max(s, 0))`.
pub fn log_specular(s: &[f32]) -> Vec<f32> {
    s.par_iter().map(|&v| log_specular_of(v)).collect()
}

/// One pixel of [`log_specular`]; [`specular_of_log`] undoes it for `s ≥ 0`.
pub fn log_specular_of(s: f32) -> f32 {
    s.max(0.0).ln_1p()
}

/// The specular radiance `exp(s̃) − 1` of a log-specular value.
pub fn specular_of_log(s_tilde: f32) -> f32 {
    s_tilde.exp_m1()
}

impl Features {
    /// Planes a frame's features hold.
    pub const PLANES: usize = 18;

    /// Bytes of the features of a `width`×`height` frame.
    pub fn bytes(width: usize, height: usize) -> usize {
        Self::PLANES * 4 * width * height
    }

    /// Preprocesses one frame, as rendered.
    pub fn new(k: &KpcnInputs) -> Features {
        Self::for_frame(Cow::Borrowed(k), FrameStats { max_depth: max_depth(&k.depth), exposure: 1.0 })
    }

    /// Preprocesses a frame, or a band of rows of one, with the whole frame's statistics,
    /// so that a band gets the same features as the whole frame: depth divided by its
    /// largest, the diffuse and specular radiance multiplied by its exposure and their
    /// variances by the exposure's square.
    pub fn for_frame(k: Cow<'_, KpcnInputs>, FrameStats { max_depth, exposure }: FrameStats) -> Features {
        let (w, h) = (k.width, k.height);
        let n = w * h;
        // Owned inputs become the features in place (a streamed 4K band's inputs are
        // hundreds of MB); every step is elementwise, so both ways give the same bits.
        let p = Planes::of(k);
        // Reflectance lies in [0, 1] (ARCHITECTURE.md §Layout); clamping also keeps albedo + ε away from 0,
        // and a hostile 1e30 from scaling the output (recomposition uses this albedo).
        let albedo = p.albedo.map(|a| a.map(|v| sanitize(v).clamp(0.0, 1.0)));
        let scaled = |f: f32| move |v: f32| if f == 1.0 { v } else { sanitize(v * f) };
        let (radiance, variance) = (scaled(exposure), scaled(exposure * exposure));
        let mut diffuse = p.diffuse.map(|d| d.map(|v| radiance(sanitize(v))));
        let mut specular = p.specular.map(|s| s.map(|v| radiance(sanitize(v))));

        // Depth: non-finite → 0, ≥ 0, divided by the frame's largest finite depth.
        let scale = if max_depth > 0.0 { 1.0 / max_depth as f64 } else { 0.0 };
        let depth = p.depth.map(|d| (sanitize(d).max(0.0) as f64 * scale) as f32);
        let depth_variance = p.depth_variance.map(|v| sanitize((clean_variance_of(v) as f64 * scale * scale) as f32));

        // Variance divisions in f64, results sanitised back to the f32 range.
        let mut d_variance = p.diffuse_variance.map(|v| variance(clean_variance_of(v)));
        d_variance.par_iter_mut().enumerate().for_each(|(i, v)| {
            let a = (albedo[0][i] + albedo[1][i] + albedo[2][i]) as f64 / 3.0 + EPSILON as f64;
            *v = sanitize((*v as f64 / (a * a)) as f32);
        });
        // Delta method for ln(1 + s): σ² / (1 + s)², with the mean of (1 + s) over RGB.
        let mut s_variance = p.specular_variance.map(|v| variance(clean_variance_of(v)));
        s_variance.par_iter_mut().enumerate().for_each(|(i, v)| {
            let m = 1.0 + (0..3).map(|c| specular[c][i].max(0.0) as f64).sum::<f64>() / 3.0;
            *v = sanitize((*v as f64 / (m * m)) as f32);
        });
        for (d, a) in diffuse.iter_mut().zip(&albedo) {
            d.par_iter_mut().zip(a).for_each(|(d, &a)| *d = sanitize(demodulated(*d, a)));
        }
        for s in &mut specular {
            s.par_iter_mut().for_each(|v| *v = log_specular_of(*v));
        }
        debug_assert!(depth.len() == n && d_variance.len() == n);
        Features {
            width: w,
            height: h,
            d_tilde: diffuse,
            s_tilde: specular,
            normal: p.normal.map(|p| p.map(|v| sanitize(v).clamp(-1.0, 1.0))),
            albedo,
            depth,
            d_variance,
            s_variance,
            normal_variance: p.normal_variance.map(clean_variance_of),
            albedo_variance: p.albedo_variance.map(clean_variance_of),
            depth_variance,
            exposure,
        }
    }

    /// The variance of the branch's noisy colour (of d̃ or s̃).
    pub fn variance(&self, b: Branch) -> &[f32] {
        match b {
            Branch::Diffuse => &self.d_variance,
            Branch::Specular => &self.s_variance,
        }
    }

    /// The branch's noisy colour c̃ (d̃ or s̃).
    pub fn colour(&self, b: Branch) -> &[Vec<f32>; 3] {
        match b {
            Branch::Diffuse => &self.d_tilde,
            Branch::Specular => &self.s_tilde,
        }
    }

    /// Planes of region (`x0`, `y0`, `w`×`h`) — which may extend past the frame, reflected —
    /// as CHW, one plane per source.
    pub fn region(&self, planes: &[&[f32]], x0: isize, y0: isize, w: usize, h: usize) -> Vec<f32> {
        self.rows(planes.len(), x0, y0, w, h, |i, fy, columns, row, _| {
            columns.gather(row, &planes[i][fy * self.width..][..self.width], 0);
        })
    }

    /// `planes` planes of the region (`x0`, `y0`, `w`×`h`), rows in parallel: each row
    /// filled by `fill(plane, frame row, columns, row, scratch)` with the region's rows
    /// and columns ([`Columns`]) reflected into the frame.
    fn rows(
        &self,
        planes: usize,
        x0: isize,
        y0: isize,
        w: usize,
        h: usize,
        fill: impl Fn(usize, usize, &Columns, &mut [f32], &mut Vec<f32>) + Sync,
    ) -> Vec<f32> {
        // From the pool: a stream's inputs come a few rows at a time, and a fresh buffer's
        // pages are zeroed by the kernel on first touch.
        let mut out = crate::kernel::buffers::zeroed(planes * w * h);
        if w > 0 && h > 0 {
            let columns = Columns::new((0..w).map(|x| reflect(x0 + x as isize, self.width)));
            out.par_chunks_mut(w).enumerate().for_each_init(Vec::new, |scratch, (i, row)| {
                fill(i / h, reflect(y0 + (i % h) as isize, self.height), &columns, row, scratch)
            });
        }
        out
    }

    /// The 10 planes whose gradients are inputs: c̃, normal, albedo, depth.
    pub(crate) fn guides(&self, b: Branch) -> [&[f32]; 10] {
        let c = self.colour(b);
        [
            &c[0],
            &c[1],
            &c[2],
            &self.normal[0],
            &self.normal[1],
            &self.normal[2],
            &self.albedo[0],
            &self.albedo[1],
            &self.albedo[2],
            &self.depth,
        ]
    }

    /// The 4 variance planes of branch `b`'s input.
    pub(crate) fn variances(&self, b: Branch) -> [&[f32]; 4] {
        let var = match b {
            Branch::Diffuse => &self.d_variance,
            Branch::Specular => &self.s_variance,
        };
        [var, &self.normal_variance, &self.albedo_variance, &self.depth_variance]
    }

    /// The 27-channel input of branch `b` over a region (CHW, reflected past the frame).
    pub fn branch_input(&self, b: Branch, x0: isize, y0: isize, w: usize, h: usize) -> Vec<f32> {
        let guides = self.guides(b);
        let variances = self.variances(b);
        let fw = self.width;
        let out = self.rows(INPUT_CHANNELS, x0, y0, w, h, |i, fy, columns, row, scratch| match i {
            0..3 => columns.gather(row, &guides[i][fy * fw..][..fw], 0),
            3..23 => {
                let (g, along_x) = (guides[(i - 3) % 10], i < 13);
                gradient_row(g, fw, fy, along_x, columns.span(), scratch);
                columns.gather(row, scratch, columns.span().start);
            }
            _ => columns.gather(row, &variances[i - 23][fy * fw..][..fw], 0),
        });
        debug_assert_eq!(out.len(), INPUT_CHANNELS * w * h);
        out
    }
}

/// A branch's 27-channel input (CHW, [`Features::branch_input`]) with its colour seen in
/// log, in place: `c̃` becomes `ln(1 + c̃)`, each of its backward differences `c̃ − c̃'`
/// becomes `ln(1 + c̃) − ln(1 + c̃')` (the neighbour `c̃'` is `c̃` less the difference), and
/// its variance `σ² / (1 + m)²` with `m` the mean of `c̃` over RGB (the delta method, as
/// for `s̃`). Negative values count as 0.
pub fn log_colour_input(input: &mut [f32]) {
    let n = input.len() / INPUT_CHANNELS;
    let (colour, rest) = input.split_at_mut(3 * n);
    let (gx, rest) = rest.split_at_mut(10 * n);
    let (gy, variance) = rest.split_at_mut(10 * n);
    let (r, g, b) = (&colour[..n], &colour[n..2 * n], &colour[2 * n..]);
    variance[..n].par_iter_mut().enumerate().for_each(|(i, v)| {
        let mean = r[i].max(0.0) / 3.0 + g[i].max(0.0) / 3.0 + b[i].max(0.0) / 3.0;
        *v = sanitize(*v / ((1.0 + mean) * (1.0 + mean)));
    });
    let ln = |v: f32| v.max(0.0).ln_1p();
    let planes = colour.par_chunks_mut(n.max(1)).zip(gx.par_chunks_mut(n.max(1))).zip(gy.par_chunks_mut(n.max(1)));
    planes.for_each(|((c, gx), gy)| {
        for ((v, x), y) in c.iter_mut().zip(gx).zip(gy) {
            let l = ln(*v);
            *x = sanitize(l - ln(v.max(0.0) - *x));
            *y = sanitize(l - ln(v.max(0.0) - *y));
            *v = l;
        }
    });
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A `w`×`h` frame whose planes are `f(pixel index)` plus a per-plane offset.
    pub(crate) fn inputs(w: usize, h: usize, f: impl Fn(usize) -> f32) -> KpcnInputs {
        let p = |o: f32| (0..w * h).map(|i| f(i) + o).collect::<Vec<f32>>();
        KpcnInputs {
            width: w,
            height: h,
            color: [p(0.0), p(0.0), p(0.0)],
            diffuse: [p(0.1), p(0.2), p(0.3)],
            specular: [p(0.0), p(0.5), p(1.0)],
            albedo: [p(0.5), p(0.5), p(0.5)],
            normal: [p(0.0), p(0.0), p(1.0)],
            depth: p(1.0),
            visibility: None,
            color_variance: p(0.0),
            diffuse_variance: p(0.01),
            specular_variance: p(0.04),
            albedo_variance: p(0.001),
            normal_variance: p(0.002),
            depth_variance: p(0.5),
        }
    }

    #[test]
    fn preprocessing_matches_hand_computed_values() {
        // A constant frame: every value is its hand-computed transform, gradients are 0.
        let f = Features::new(&inputs(3, 2, |_| 0.0));
        let d = planes(&f, Branch::Diffuse);
        assert_eq!(d.len(), INPUT_CHANNELS);
        assert!((d[0][4] - 0.1 / (0.5 + EPSILON)).abs() < 1e-6);
        assert!((d[2][4] - 0.3 / (0.5 + EPSILON)).abs() < 1e-6);
        assert!(d[3..23].iter().all(|g| g.iter().all(|&v| v == 0.0)), "gradients of a constant frame are 0");
        let expect = (0.01f64 / (0.5 + EPSILON as f64).powi(2)) as f32;
        assert!((d[23][0] - expect).abs() < 1e-6, "{} vs {expect}", d[23][0]);
        assert_eq!(d[24][0], 0.002);
        assert_eq!(d[25][0], 0.001);
        // Depth 1 everywhere normalises to 1; its variance 0.5 to 0.5 / 1².
        assert_eq!(d[26][0], 0.5);
        let s = planes(&f, Branch::Specular);
        assert!((s[1][0] - 1.5f32.ln()).abs() < 1e-6);
        assert!((s[2][0] - 2f32.ln()).abs() < 1e-6);
        let m = 1.0 + (0.0 + 0.5 + 1.0) / 3.0;
        assert!((s[23][0] - (0.04 / (m * m)) as f32).abs() < 1e-6);
    }

    /// Owned inputs become features in place, borrowed ones are copied: the same bits,
    /// hostile samples included, at a scaled exposure too; and `Features::PLANES` counts them.
    #[test]
    fn owned_and_borrowed_inputs_give_the_same_features() {
        let hostile = [f32::NAN, f32::INFINITY, -1e30, -0.5, 0.0, 3e-3, 0.7, 1e4, f32::NEG_INFINITY];
        let k = inputs(9, 4, |i| hostile[i % hostile.len()] * if i % 2 == 0 { 1.0 } else { 0.01 });
        for stats in [FrameStats { max_depth: 7.0, exposure: 1.0 }, FrameStats { max_depth: 0.0, exposure: 0.3 }] {
            let (a, b) =
                (Features::for_frame(Cow::Borrowed(&k), stats), Features::for_frame(Cow::Owned(k.clone()), stats));
            let all = |f: &Features| -> Vec<Vec<u32>> {
                let mut p: Vec<&Vec<f32>> =
                    [&f.d_tilde, &f.s_tilde, &f.normal, &f.albedo].into_iter().flatten().collect();
                p.extend([
                    &f.depth,
                    &f.d_variance,
                    &f.s_variance,
                    &f.normal_variance,
                    &f.albedo_variance,
                    &f.depth_variance,
                ]);
                p.iter().map(|v| v.iter().map(|x| x.to_bits()).collect()).collect()
            };
            assert_eq!(all(&a), all(&b));
            assert_eq!(all(&a).len(), Features::PLANES);
            assert!(all(&a).iter().flatten().all(|&x| f32::from_bits(x).is_finite()));
        }
    }

    /// The whole frame's input as 27 planes.
    fn planes(f: &Features, b: Branch) -> Vec<Vec<f32>> {
        let n = f.width * f.height;
        f.branch_input(b, 0, 0, f.width, f.height).chunks(n).map(<[f32]>::to_vec).collect()
    }

    #[test]
    fn columns_gather_as_a_column_by_column_reflection_would() {
        for fw in [1, 2, 5, 40] {
            let src: Vec<f32> = (0..fw).map(|x| x as f32 * 1.5 - 7.0).collect();
            for (x0, w) in [(-50, 130), (-3, 46), (0, fw), (2, 1), (-1, 3), (7, 9)] {
                let xs: Vec<usize> = (0..w).map(|x| reflect(x0 + x as isize, fw)).collect();
                let columns = Columns::new(xs.iter().copied());
                let mut row = vec![f32::NAN; w];
                columns.gather(&mut row, &src, 0);
                let want: Vec<f32> = xs.iter().map(|&x| src[x]).collect();
                assert_eq!(row, want, "frame {fw} wide, region {x0} + {w}");
                assert_eq!(columns.span(), *xs.iter().min().unwrap()..xs.iter().max().unwrap() + 1);
                // Gathered from the span alone, as the gradients are.
                let span = columns.span();
                columns.gather(&mut row, &src[span.clone()], span.start);
                assert_eq!(row, want, "frame {fw} wide, region {x0} + {w}, from its span");
            }
        }
        // A region past both sides of a frame is three runs: down, up, down.
        let columns = Columns::new((0..46).map(|x| reflect(x - 3, 40)));
        assert_eq!(columns.runs.len(), 3);
    }

    #[test]
    fn gradient_rows_are_the_gradients_pixel_by_pixel() {
        let (w, h) = (9, 4);
        let hostile = [f32::NAN, f32::INFINITY, -1e30, 1e30];
        let p: Vec<f32> = (0..w * h).map(|i| if i % 11 == 5 { hostile[i % 4] } else { (i * 7 % 13) as f32 }).collect();
        let mut out = Vec::new();
        for y in 0..h {
            for along_x in [true, false] {
                for span in [0..w, 0..1, 1..w, 3..6] {
                    gradient_row(&p, w, y, along_x, span.clone(), &mut out);
                    let want: Vec<f32> = span.clone().map(|x| grad_at(&p, w, x, y, along_x)).collect();
                    assert_eq!(out, want, "row {y}, along x {along_x}, columns {span:?}");
                }
            }
        }
    }

    #[test]
    fn regions_past_the_border_are_reflected() {
        assert_eq!((-3..6).map(|i| reflect(i, 3)).collect::<Vec<_>>(), [1, 2, 1, 0, 1, 2, 1, 0, 1]);
        assert_eq!(reflect(-5, 1), 0);
        let f = Features::new(&inputs(3, 1, |i| i as f32));
        let r = f.region(&[&f.depth], -2, 0, 7, 1);
        let d = &f.depth;
        assert_eq!(r, [d[2], d[1], d[0], d[1], d[2], d[1], d[0]]);
    }

    #[test]
    fn a_region_equals_the_same_part_of_the_whole_input() {
        let f = Features::new(&inputs(7, 5, |i| ((i * 7919) % 13) as f32 * 0.1));
        let whole = planes(&f, Branch::Specular);
        let part = f.branch_input(Branch::Specular, 2, 1, 4, 3);
        for (c, plane) in whole.iter().enumerate() {
            for y in 0..3 {
                for x in 0..4 {
                    assert_eq!(part[c * 12 + y * 4 + x], plane[(y + 1) * 7 + x + 2], "channel {c}");
                }
            }
        }
    }

    #[test]
    fn the_log_input_is_the_input_of_the_colour_seen_in_log() {
        // Sparse bright hits among dim values, a region past the frame's edges.
        let k = inputs(9, 7, |i| if i % 17 == 3 { 40.0 + i as f32 } else { ((i * 7919) % 13) as f32 * 0.05 });
        let f = Features::new(&k);
        let mut logged = f.clone();
        for c in 0..3 {
            logged.d_tilde[c] = f.d_tilde[c].iter().map(|&v| v.max(0.0).ln_1p()).collect();
        }
        for (i, v) in logged.d_variance.iter_mut().enumerate() {
            let m = 1.0 + (0..3).map(|c| f.d_tilde[c][i]).sum::<f32>() / 3.0;
            *v /= m * m;
        }
        let mut got = f.branch_input(Branch::Diffuse, -2, -1, 12, 9);
        log_colour_input(&mut got);
        let want = logged.branch_input(Branch::Diffuse, -2, -1, 12, 9);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            assert!((g - w).abs() <= 1e-5 * (1.0 + w.abs()), "channel {}, pixel {}: {g} against {w}", i / 108, i % 108);
        }
        // Only c̃'s planes change.
        let plain = f.branch_input(Branch::Diffuse, -2, -1, 12, 9);
        for c in (6..13).chain(16..23).chain(24..27) {
            assert_eq!(got[c * 108..][..108], plain[c * 108..][..108], "channel {c}");
        }
    }

    #[test]
    fn gradients_are_backward_differences_on_the_whole_frame() {
        // 3×2 ramp: p = x + 10 y.
        let p: Vec<f32> = (0..6).map(|i| (i % 3) as f32 + 10.0 * (i / 3) as f32).collect();
        let (gx, gy) = gradients(&p, 3, 2);
        assert_eq!(gx, [0.0, 1.0, 1.0, 0.0, 1.0, 1.0]);
        assert_eq!(gy, [0.0, 0.0, 0.0, 10.0, 10.0, 10.0]);
    }

    #[test]
    fn depth_is_normalised_by_the_largest_finite_depth() {
        let mut k = inputs(4, 1, |i| i as f32);
        k.depth = vec![2.0, f32::INFINITY, f32::NAN, 8.0];
        let f = Features::new(&k);
        // Guides: c̃ 3, normal 3, albedo 3, depth → Gx of depth is plane 3 + 9.
        let gx_depth = &planes(&f, Branch::Diffuse)[12];
        assert_eq!(gx_depth, &vec![0.0, -0.25, 0.0, 1.0]);
    }

    #[test]
    fn hostile_values_become_finite() {
        let mut k = inputs(2, 2, |_| 0.0);
        k.diffuse[0] = vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e30];
        k.albedo[0] = vec![0.0, -1.0, f32::MAX, 0.0];
        k.diffuse_variance = vec![f32::INFINITY, 1e38, -5.0, f32::NAN];
        let f = Features::new(&k);
        for p in planes(&f, Branch::Diffuse).iter().chain(&planes(&f, Branch::Specular)) {
            assert!(p.iter().all(|v| v.is_finite()), "{p:?}");
        }
    }
}
