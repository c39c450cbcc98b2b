//! Preprocessing (SPEC §4): from the renderer's buffers to the 27-channel network input of
//! each branch.
//!
//! Per branch, in this order: `[c̃ 3][Gx of (c̃ 3, normal 3, albedo 3, depth 1)][Gy of the
//! same 10][σ̃²_c 1][σ²_normal 1, σ²_albedo 1, σ²_depth 1]`, where c̃ is the demodulated
//! diffuse `d̃ = diffuse / (albedo + ε)` or the log specular `s̃ = ln(1 + max(specular, 0))`.

use crate::io::layout::KpcnInputs;
use rayon::prelude::*;
use std::borrow::Cow;

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
pub enum Branch {
    /// Demodulated diffuse.
    Diffuse,
    /// Log specular.
    Specular,
}

/// One of the square's eight symmetries (mirrors and transposition), for training
/// augmentation: a mirrored or transposed render is as plausible as the render itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Orientation {
    /// Mirrored left to right.
    pub flip_x: bool,
    /// Mirrored top to bottom.
    pub flip_y: bool,
    /// Rows and columns exchanged (before the mirrors).
    pub transpose: bool,
}

impl Orientation {
    /// Symmetry `i` of the eight (bits: mirror x, mirror y, transpose); 0 is the identity.
    pub fn from_index(i: u64) -> Orientation {
        Orientation { flip_x: i & 1 != 0, flip_y: i & 2 != 0, transpose: i & 4 != 0 }
    }

    /// CHW planes of `side`² squares, oriented.
    pub fn apply(self, planes: &[f32], side: usize) -> Vec<f32> {
        let n = side * side;
        let mut out = Vec::with_capacity(planes.len());
        for plane in planes.chunks_exact(n) {
            for v in 0..side {
                for u in 0..side {
                    let (mut x, mut y) = if self.transpose { (v, u) } else { (u, v) };
                    if self.flip_x {
                        x = side - 1 - x;
                    }
                    if self.flip_y {
                        y = side - 1 - y;
                    }
                    out.push(plane[y * side + x]);
                }
            }
        }
        out
    }
}

/// The colour channels reordered (training augmentation: a render with its red and blue
/// exchanged is as plausible as the render): channel `c` of the result is channel
/// `self.0[c]` of the original, in colour, albedo and references alike.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelOrder(pub [usize; 3]);

impl Default for ChannelOrder {
    /// R, G, B as they are.
    fn default() -> Self {
        ChannelOrder([0, 1, 2])
    }
}

impl ChannelOrder {
    /// Order `i` of the six (0 is the identity).
    pub fn from_index(i: u64) -> ChannelOrder {
        const ALL: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
        ChannelOrder(ALL[(i % 6) as usize])
    }

    /// Three planes (R, G, B) in this order.
    pub fn pick<T>(self, planes: &[T; 3]) -> [&T; 3] {
        self.0.map(|c| &planes[c])
    }
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

/// The key an auto-exposed frame is scaled to: its geometric-mean block luminance.
pub const EXPOSURE_KEY: f32 = 0.18;
/// Side of the blocks whose mean luminance [`ExposureMeter`] averages.
pub const EXPOSURE_BLOCK: usize = 16;

/// A frame's autoexposure, measured row by row so that a streamed frame is read once: the
/// mean luminance of each 16×16 block (partial at the right and bottom edges), then the
/// factor that brings the geometric mean of the lit blocks (> 1e-8) to [`EXPOSURE_KEY`].
/// Blocks, not pixels, so that a few bright samples of a low-spp frame (or its empty
/// pixels) move it little. A frame with no lit block gets 1.
#[derive(Debug, Clone)]
pub struct ExposureMeter {
    width: usize,
    /// Luminance sums of the current row of blocks.
    sums: Vec<f64>,
    /// Rows of the current row of blocks added so far.
    rows: usize,
    /// Σ ln(block mean) over the lit blocks finished so far, and their count.
    log_sum: f64,
    lit: usize,
}

impl ExposureMeter {
    /// A meter for frames `width` pixels wide.
    pub fn new(width: usize) -> ExposureMeter {
        ExposureMeter { width, sums: vec![0.0; width.div_ceil(EXPOSURE_BLOCK)], rows: 0, log_sum: 0.0, lit: 0 }
    }

    /// Adds the next rows of the frame's colour (whole rows, top to bottom).
    pub fn add_rows(&mut self, color: [&[f32]; 3]) {
        let w = self.width;
        if w == 0 {
            return;
        }
        for y in 0..color[0].len() / w {
            for x in 0..w {
                let i = y * w + x;
                let l =
                    0.2126 * sanitize(color[0][i]) + 0.7152 * sanitize(color[1][i]) + 0.0722 * sanitize(color[2][i]);
                self.sums[x / EXPOSURE_BLOCK] += l.max(0.0) as f64;
            }
            self.rows += 1;
            if self.rows == EXPOSURE_BLOCK {
                self.finish_blocks();
            }
        }
    }

    fn finish_blocks(&mut self) {
        for (b, sum) in self.sums.iter_mut().enumerate() {
            let cols = EXPOSURE_BLOCK.min(self.width - b * EXPOSURE_BLOCK);
            let mean = *sum / (cols * self.rows) as f64;
            if mean > 1e-8 {
                self.log_sum += mean.ln();
                self.lit += 1;
            }
            *sum = 0.0;
        }
        self.rows = 0;
    }

    /// The factor to multiply the frame's radiance by.
    pub fn exposure(mut self) -> f32 {
        if self.rows > 0 {
            self.finish_blocks();
        }
        if self.lit == 0 {
            return 1.0;
        }
        let e = EXPOSURE_KEY as f64 / (self.log_sum / self.lit as f64).exp();
        if e.is_finite() && e > 0.0 { e as f32 } else { 1.0 }
    }
}

/// Whole-frame statistics that a band of rows is preprocessed with, so that it gets the
/// same features as the whole frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameStats {
    /// The largest finite depth ([`max_depth`]).
    pub max_depth: f32,
    /// The radiance factor (1, or [`ExposureMeter`]'s).
    pub exposure: f32,
}

/// [`ExposureMeter`]'s factor for a whole frame.
pub fn auto_exposure(k: &KpcnInputs) -> f32 {
    let mut m = ExposureMeter::new(k.width);
    m.add_rows(k.color.each_ref().map(Vec::as_slice));
    m.exposure()
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

/// Samples of one input that preprocessing had to repair.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Repairs {
    /// NaN or ±Inf, replaced by 0.
    pub nonfinite: usize,
    /// Finite but outside the input's physical range, clamped into it.
    pub out_of_range: usize,
}

/// What [`Features`] repairs in each input, counted over rows `rows` of `k` (the inner rows
/// of a band, so that a streamed frame counts each row once): NaN/Inf in every input, and
/// values outside the physical range of albedo [0, 1], normal [−1, 1], depth [0, ∞) and
/// the variances [0, 1e15] (a negative variance is 0; one above the largest radiance
/// kpcn keeps, squared or not, is no render's).
pub fn repairs(k: &KpcnInputs, rows: std::ops::Range<usize>) -> [(&'static str, &'static str, Repairs); 12] {
    let span = rows.start * k.width..rows.end.min(k.height) * k.width;
    let count = |planes: &[&Vec<f32>], lo: f32, hi: f32| {
        let mut r = Repairs::default();
        for p in planes {
            for &v in &p[span.clone()] {
                if !v.is_finite() {
                    r.nonfinite += 1;
                } else if v < lo || v > hi {
                    r.out_of_range += 1;
                }
            }
        }
        r
    };
    fn all(p: &[Vec<f32>; 3]) -> [&Vec<f32>; 3] {
        [&p[0], &p[1], &p[2]]
    }
    let inf = f32::INFINITY;
    [
        ("color", "", count(&all(&k.color), -inf, inf)),
        ("diffuse", "", count(&all(&k.diffuse), -inf, inf)),
        ("specular", "", count(&all(&k.specular), -inf, inf)),
        ("albedo", "[0, 1]", count(&all(&k.albedo), 0.0, 1.0)),
        ("normal", "[-1, 1]", count(&all(&k.normal), -1.0, 1.0)),
        ("depth", "[0, inf)", count(&[&k.depth], 0.0, inf)),
        ("colorVariance", "[0, 1e15]", count(&[&k.color_variance], 0.0, MAX_MAGNITUDE)),
        ("diffuseVariance", "[0, 1e15]", count(&[&k.diffuse_variance], 0.0, MAX_MAGNITUDE)),
        ("specularVariance", "[0, 1e15]", count(&[&k.specular_variance], 0.0, MAX_MAGNITUDE)),
        ("albedoVariance", "[0, 1e15]", count(&[&k.albedo_variance], 0.0, MAX_MAGNITUDE)),
        ("normalVariance", "[0, 1e15]", count(&[&k.normal_variance], 0.0, MAX_MAGNITUDE)),
        ("depthVariance", "[0, 1e15]", count(&[&k.depth_variance], 0.0, MAX_MAGNITUDE)),
    ]
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
        // Reflectance lies in [0, 1] (SPEC §3); clamping also keeps albedo + ε away from 0,
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
        self.rows(planes.len(), x0, y0, w, h, |i, fy, xs, row| {
            let src = &planes[i][fy * self.width..][..self.width];
            for (v, &x) in row.iter_mut().zip(xs) {
                *v = src[x];
            }
        })
    }

    /// `planes` planes of the region (`x0`, `y0`, `w`×`h`), rows in parallel: each row
    /// filled by `fill(plane, frame row, frame columns, row)` with the region's rows and
    /// columns reflected into the frame.
    fn rows(
        &self,
        planes: usize,
        x0: isize,
        y0: isize,
        w: usize,
        h: usize,
        fill: impl Fn(usize, usize, &[usize], &mut [f32]) + Sync,
    ) -> Vec<f32> {
        let mut out = vec![0f32; planes * w * h];
        if w > 0 && h > 0 {
            let xs: Vec<usize> = (0..w).map(|x| reflect(x0 + x as isize, self.width)).collect();
            out.par_chunks_mut(w)
                .enumerate()
                .for_each(|(i, row)| fill(i / h, reflect(y0 + (i % h) as isize, self.height), &xs, row));
        }
        out
    }

    /// The 10 planes whose gradients are inputs: c̃, normal, albedo, depth.
    fn guides(&self, b: Branch) -> [&[f32]; 10] {
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
    fn variances(&self, b: Branch) -> [&[f32]; 4] {
        let var = match b {
            Branch::Diffuse => &self.d_variance,
            Branch::Specular => &self.s_variance,
        };
        [var, &self.normal_variance, &self.albedo_variance, &self.depth_variance]
    }

    /// The input of branch `b` over the `side`² square at (`x0`, `y0`) as the network
    /// would see it in a mirrored or transposed frame whose colour channels are reordered
    /// (training augmentation): the planes are oriented first and the gradients taken
    /// afterwards, along the oriented axes; colour and albedo reordered alike. The identity
    /// is [`Features::branch_input`] exactly. (Normals keep their components; the network
    /// sees only their gradients.)
    pub fn branch_input_oriented(
        &self,
        b: Branch,
        (x0, y0): (isize, isize),
        side: usize,
        o: Orientation,
        order: ChannelOrder,
    ) -> Vec<f32> {
        if o == Orientation::default() && order == ChannelOrder::default() {
            return self.branch_input(b, x0, y0, side, side);
        }
        // One pixel of margin on every side, for the backward differences of the border.
        let m = side + 2;
        let all = self.guides(b);
        // c̃ (0..3) and albedo (6..9) reordered alike.
        let guides: [&[f32]; 10] = std::array::from_fn(|k| match k {
            0..3 => all[order.0[k]],
            6..9 => all[6 + order.0[k - 6]],
            _ => all[k],
        });
        let g = o.apply(&self.region(&guides, x0 - 1, y0 - 1, m, m), m);
        let at = |k: usize, x: usize, y: usize| g[(k * m + y) * m + x];
        let mut out = Vec::with_capacity(INPUT_CHANNELS * side * side);
        let square = |out: &mut Vec<f32>, f: &dyn Fn(usize, usize) -> f32| {
            (0..side).for_each(|y| (0..side).for_each(|x| out.push(f(x + 1, y + 1))));
        };
        for k in 0..3 {
            square(&mut out, &|x, y| at(k, x, y));
        }
        for k in 0..10 {
            square(&mut out, &|x, y| sanitize(at(k, x, y) - at(k, x - 1, y)));
        }
        for k in 0..10 {
            square(&mut out, &|x, y| sanitize(at(k, x, y) - at(k, x, y - 1)));
        }
        out.extend(o.apply(&self.region(&self.variances(b), x0, y0, side, side), side));
        out
    }

    /// The 27-channel input of branch `b` over a region (CHW, reflected past the frame).
    pub fn branch_input(&self, b: Branch, x0: isize, y0: isize, w: usize, h: usize) -> Vec<f32> {
        let guides = self.guides(b);
        let variances = self.variances(b);
        let fw = self.width;
        let out = self.rows(INPUT_CHANNELS, x0, y0, w, h, |i, fy, xs, row| match i {
            0..3 => row.iter_mut().zip(xs).for_each(|(v, &x)| *v = guides[i][fy * fw + x]),
            3..23 => {
                let (g, along_x) = (guides[(i - 3) % 10], i < 13);
                row.iter_mut().zip(xs).for_each(|(v, &x)| *v = grad_at(g, fw, x, fy, along_x));
            }
            _ => row.iter_mut().zip(xs).for_each(|(v, &x)| *v = variances[i - 23][fy * fw + x]),
        });
        debug_assert_eq!(out.len(), INPUT_CHANNELS * w * h);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_exposure_meter_reads_any_band_split_alike_and_scales_inversely() {
        let (w, h) = (37, 41);
        // A ramp with empty pixels, fireflies and a NaN: what a low-spp render holds.
        let plane = |c: usize| -> Vec<f32> {
            (0..w * h)
                .map(|i| match i % 13 {
                    0 => 0.0,
                    5 if c == 1 => 1e4,
                    7 if i == 7 => f32::NAN,
                    _ => 0.01 * (1 + (i / w) + c) as f32,
                })
                .collect()
        };
        let color = [plane(0), plane(1), plane(2)];
        let whole = {
            let mut m = ExposureMeter::new(w);
            m.add_rows(color.each_ref().map(Vec::as_slice));
            m.exposure()
        };
        assert!(whole.is_finite() && whole > 0.0);
        for band in [1, 4, 7, 16, 40] {
            let mut m = ExposureMeter::new(w);
            for y0 in (0..h).step_by(band) {
                let rows = y0 * w..(y0 + band).min(h) * w;
                m.add_rows(color.each_ref().map(|p| &p[rows.clone()]));
            }
            assert_eq!(m.exposure(), whole, "bands of {band} rows");
        }
        // Twice as bright, half the exposure.
        let brighter = color.each_ref().map(|p| p.iter().map(|v| v * 2.0).collect::<Vec<f32>>());
        let mut m = ExposureMeter::new(w);
        m.add_rows(brighter.each_ref().map(Vec::as_slice));
        let half = m.exposure();
        assert!((half * 2.0 / whole - 1.0).abs() < 1e-5, "{half} against {whole}");
    }

    #[test]
    fn a_frame_at_the_key_keeps_its_scale_and_a_black_one_gets_one() {
        let grey = vec![EXPOSURE_KEY; 20 * 20];
        let mut m = ExposureMeter::new(20);
        m.add_rows([&grey, &grey, &grey]);
        assert!((m.exposure() - 1.0).abs() < 1e-5);
        let black = vec![0.0; 20 * 20];
        let mut m = ExposureMeter::new(20);
        m.add_rows([&black, &black, &black]);
        assert_eq!(m.exposure(), 1.0);
        assert_eq!(ExposureMeter::new(0).exposure(), 1.0);
    }

    fn inputs(w: usize, h: usize, f: impl Fn(usize) -> f32) -> KpcnInputs {
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

    /// `k` with every plane mirrored left to right.
    fn mirrored(k: &KpcnInputs) -> KpcnInputs {
        let (w, h) = (k.width, k.height);
        let m = |p: &Vec<f32>| (0..w * h).map(|i| p[(i / w) * w + (w - 1 - i % w)]).collect::<Vec<f32>>();
        let m3 = |p: &[Vec<f32>; 3]| [m(&p[0]), m(&p[1]), m(&p[2])];
        KpcnInputs {
            width: w,
            height: h,
            color: m3(&k.color),
            diffuse: m3(&k.diffuse),
            specular: m3(&k.specular),
            albedo: m3(&k.albedo),
            normal: m3(&k.normal),
            depth: m(&k.depth),
            visibility: None,
            color_variance: m(&k.color_variance),
            diffuse_variance: m(&k.diffuse_variance),
            specular_variance: m(&k.specular_variance),
            albedo_variance: m(&k.albedo_variance),
            normal_variance: m(&k.normal_variance),
            depth_variance: m(&k.depth_variance),
        }
    }

    #[test]
    fn oriented_input_is_the_input_of_the_mirrored_frame() {
        let k = inputs(20, 16, |i| ((i * 7919) % 97) as f32 / 50.0);
        let (f, fm) = (Features::new(&k), Features::new(&mirrored(&k)));
        let (x0, y0, side) = (4, 5, 8);
        for b in [Branch::Diffuse, Branch::Specular] {
            let o = Orientation { flip_x: true, ..Default::default() };
            let got = f.branch_input_oriented(b, (x0, y0), side, o, ChannelOrder::default());
            let want = fm.branch_input(b, 20 - x0 - side as isize, y0, side, side);
            assert_eq!(got, want, "{b:?}");
            let id = f.branch_input_oriented(b, (x0, y0), side, Orientation::default(), ChannelOrder::default());
            assert_eq!(id, f.branch_input(b, x0, y0, side, side));
        }
        // Transposing twice, or mirroring twice, is the identity; the eight are distinct.
        let sq: Vec<f32> = (0..9).map(|v| v as f32).collect();
        let all: Vec<Vec<f32>> = (0..8).map(|i| Orientation::from_index(i).apply(&sq, 3)).collect();
        for (i, a) in all.iter().enumerate() {
            assert!(all[..i].iter().all(|b| b != a), "symmetry {i} repeats");
        }
        let t = Orientation { transpose: true, ..Default::default() };
        assert_eq!(t.apply(&t.apply(&sq, 3), 3), sq);
        assert_eq!(all[4], [0.0, 3.0, 6.0, 1.0, 4.0, 7.0, 2.0, 5.0, 8.0]);
    }

    #[test]
    fn channel_ordered_input_is_the_input_of_the_reordered_frame() {
        let mut k = inputs(20, 16, |i| ((i * 7919) % 97) as f32 / 50.0);
        k.albedo = std::array::from_fn(|c| k.albedo[c].iter().map(|a| a * (0.3 + 0.3 * c as f32)).collect());
        let f = Features::new(&k);
        let (x0, y0, side) = (4, 5, 8);
        for i in 1..6 {
            let order = ChannelOrder::from_index(i);
            let mut r = k.clone();
            for planes in [&mut r.color, &mut r.diffuse, &mut r.specular, &mut r.albedo] {
                *planes = order.pick(planes).map(Vec::clone);
            }
            let fr = Features::new(&r);
            for b in [Branch::Diffuse, Branch::Specular] {
                let o = Orientation::from_index(i);
                let got = f.branch_input_oriented(b, (x0, y0), side, o, order);
                let want = fr.branch_input_oriented(b, (x0, y0), side, o, ChannelOrder::default());
                // Equal but for the variances' RGB means, summed in another order.
                for (j, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!((g - w).abs() <= 1e-6 * w.abs().max(1e-3), "{b:?} order {order:?} value {j}: {g} {w}");
                }
                assert_ne!(got, f.branch_input_oriented(b, (x0, y0), side, o, ChannelOrder::default()));
            }
        }
        let all: Vec<[usize; 3]> = (0..6).map(|i| ChannelOrder::from_index(i).0).collect();
        assert!(all.iter().enumerate().all(|(i, a)| !all[..i].contains(a)), "six distinct orders: {all:?}");
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
