//! The layered-EXR contract (SPEC §3): which channels of a file hold which KPCN input.
//!
//! A [`Layout`] is a renderer's naming convention; a [`Mapping`] is a layout applied to
//! one file's channel names, saying for every input whether it is present, derived from
//! other passes, estimated, or missing. [`Mapping::extract`] turns a frame into
//! [`KpcnInputs`], the planes the denoiser consumes.

use super::error::IoError;
use super::frame::FrameBuffers;
use std::collections::HashSet;
use std::fmt;
use std::path::Path;
use std::str::FromStr;

/// A renderer's naming convention for the KPCN inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Layout {
    /// The KPCN training-set layout: `R,G,B`, `diffuse.R`, `diffuseVariance.Z`, …
    Native,
    /// Blender Cycles multilayer passes (`ViewLayer.DiffDir.R` or `Diffuse Direct`).
    Cycles,
    /// RenderMan `denoise_batch` AOVs (`Ci`, `mse`, `diffuse_mse`, `zfiltered`, …).
    RenderMan,
}

impl Layout {
    /// Every layout, in detection-preference order.
    pub const ALL: [Layout; 3] = [Layout::Native, Layout::Cycles, Layout::RenderMan];

    /// Command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Layout::Native => "native",
            Layout::Cycles => "cycles",
            Layout::RenderMan => "renderman",
        }
    }

    fn hint(self) -> &'static str {
        match self {
            Layout::Native => {
                "write the SPEC §3 AOVs (R,G,B, diffuse, specular, albedo, normal, depth and their …Variance channels), or name the renderer with --layout cycles|renderman"
            }
            Layout::Cycles => {
                "enable the Combined, Diffuse Direct/Indirect/Color, Normal and Z passes in Blender's View Layer properties and save as multilayer EXR"
            }
            Layout::RenderMan => {
                "add the denoise AOVs (Ci, mse, diffuse, diffuse_mse, specular, specular_mse, albedo, albedo_var, normal, normal_var, zfiltered, zfiltered_var) to the display"
            }
        }
    }
}

impl fmt::Display for Layout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Layout {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Layout::ALL
            .into_iter()
            .find(|l| l.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("unknown layout `{s}` (choose native, cycles or renderman)"))
    }
}

/// The quantities of SPEC §3.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Quantity {
    /// Beauty = diffuse + specular.
    Color,
    /// Diffuse radiance (albedo not divided out).
    Diffuse,
    /// Everything not diffuse.
    Specular,
    /// Diffuse reflectance at the first hit.
    Albedo,
    /// Shading normal at the first hit.
    Normal,
    /// Distance camera → first hit.
    Depth,
    /// Fraction of unoccluded light samples at the first hit.
    Visibility,
}

impl Quantity {
    /// All quantities in report order.
    pub const ALL: [Quantity; 7] = [
        Quantity::Color,
        Quantity::Diffuse,
        Quantity::Specular,
        Quantity::Albedo,
        Quantity::Normal,
        Quantity::Depth,
        Quantity::Visibility,
    ];

    /// The layer name of SPEC §3 (`color` is stored as root `R,G,B`).
    pub fn name(self) -> &'static str {
        match self {
            Quantity::Color => "color",
            Quantity::Diffuse => "diffuse",
            Quantity::Specular => "specular",
            Quantity::Albedo => "albedo",
            Quantity::Normal => "normal",
            Quantity::Depth => "depth",
            Quantity::Visibility => "visibility",
        }
    }

    /// Channels per pixel.
    pub fn components(self) -> usize {
        match self {
            Quantity::Depth | Quantity::Visibility => 1,
            _ => 3,
        }
    }

    /// Whether the network needs it. Visibility is recorded but is not a network input.
    pub fn required(self) -> bool {
        self != Quantity::Visibility
    }
}

/// Where an input's mean comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    /// These channels, one per component.
    Channels(Vec<String>),
    /// Component-wise sum.
    Sum(Box<Source>, Box<Source>),
    /// Component-wise difference.
    Difference(Box<Source>, Box<Source>),
    /// Component-wise product.
    Product(Box<Source>, Box<Source>),
    /// Values at or above the threshold are camera misses and become 0 (Cycles' Z pass).
    MissAbove(Box<Source>, f32),
    /// Not in the file; the channels looked for.
    Missing(Vec<String>),
}

impl Source {
    fn is_missing(&self) -> bool {
        match self {
            Source::Channels(_) => false,
            Source::Missing(_) => true,
            Source::Sum(a, b) | Source::Difference(a, b) | Source::Product(a, b) => a.is_missing() || b.is_missing(),
            Source::MissAbove(a, _) => a.is_missing(),
        }
    }

    fn missing_channels(&self, out: &mut Vec<String>) {
        match self {
            Source::Channels(_) => {}
            Source::Missing(c) => out.extend(c.iter().cloned()),
            Source::Sum(a, b) | Source::Difference(a, b) | Source::Product(a, b) => {
                a.missing_channels(out);
                b.missing_channels(out);
            }
            Source::MissAbove(a, _) => a.missing_channels(out),
        }
    }

    fn channels(&self, out: &mut Vec<String>) {
        match self {
            Source::Channels(c) => out.extend(c.iter().cloned()),
            Source::Missing(_) => {}
            Source::Sum(a, b) | Source::Difference(a, b) | Source::Product(a, b) => {
                a.channels(out);
                b.channels(out);
            }
            Source::MissAbove(a, _) => a.channels(out),
        }
    }

    fn is_derived(&self) -> bool {
        !matches!(self, Source::Channels(_) | Source::Missing(_))
    }

    fn eval(&self, fb: &FrameBuffers) -> Option<Vec<Vec<f32>>> {
        let zip = |a: &Source, b: &Source, f: fn(f32, f32) -> f32| {
            let (a, b) = (a.eval(fb)?, b.eval(fb)?);
            Some(a.iter().zip(&b).map(|(x, y)| x.iter().zip(y).map(|(x, y)| f(*x, *y)).collect()).collect())
        };
        match self {
            Source::Channels(c) => c.iter().map(|n| fb.channel(n).map(<[f32]>::to_vec)).collect(),
            Source::Sum(a, b) => zip(a, b, |x, y| x + y),
            Source::Difference(a, b) => zip(a, b, |x, y| x - y),
            Source::Product(a, b) => zip(a, b, |x, y| x * y),
            Source::MissAbove(a, t) => {
                let t = *t;
                Some(
                    a.eval(fb)?
                        .into_iter()
                        .map(|c| c.into_iter().map(|v| if v >= t { 0.0 } else { v }).collect())
                        .collect(),
                )
            }
            Source::Missing(_) => None,
        }
    }
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Source::Channels(c) => f.write_str(&compact_channels(c)),
            Source::Sum(a, b) => write!(f, "({a} + {b})"),
            Source::Difference(a, b) => write!(f, "({a} − {b})"),
            Source::Product(a, b) => write!(f, "{a} × {b}"),
            Source::MissAbove(a, t) => write!(f, "{a} (≥ {t:e} → 0)"),
            Source::Missing(c) => f.write_str(&compact_channels(c)),
        }
    }
}

/// `diffuse.R, diffuse.G, diffuse.B` → `diffuse.R/G/B`.
fn compact_channels(c: &[String]) -> String {
    let Some((layer, _)) = c.first().and_then(|f| f.rsplit_once('.')) else { return c.join(",") };
    let suffixes: Option<Vec<&str>> =
        c.iter().map(|n| n.rsplit_once('.').filter(|(l, _)| *l == layer).map(|(_, s)| s)).collect();
    match suffixes {
        Some(s) if c.len() > 1 => format!("{layer}.{}", s.join("/")),
        _ => c.join(","),
    }
}

/// Where an input's variance (of the pixel mean) comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum VarianceSource {
    /// These channels, averaged when there are several.
    Channels(Vec<String>),
    /// `(mean − half)²` averaged over components, box-filtered 3×3 (unbiased: E[(M−A)²] = Var M).
    HalfBuffer(Vec<String>),
    /// Local 3×3 variance of the mean: exact for pure noise, too high at edges and texture.
    Spatial,
    /// The mean itself is missing.
    Unavailable,
}

/// One input of a mapping.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    /// Which quantity.
    pub quantity: Quantity,
    /// Where its mean comes from.
    pub mean: Source,
    /// Where its variance comes from.
    pub variance: VarianceSource,
}

impl Entry {
    /// The file channels its mean is computed from.
    pub fn mean_channels(&self) -> Vec<String> {
        let mut out = Vec::new();
        self.mean.channels(&mut out);
        out
    }

    /// Its mean on `fb` (one plane per component); `None` when a channel is missing.
    pub fn eval_mean(&self, fb: &FrameBuffers) -> Option<Vec<Vec<f32>>> {
        self.mean.eval(fb)
    }

    /// One-word status of the mean: present, derived or missing.
    pub fn mean_status(&self) -> &'static str {
        if self.mean.is_missing() {
            "missing"
        } else if self.mean.is_derived() {
            "derived"
        } else {
            "present"
        }
    }

    /// One-word status of the variance: present, estimated or missing.
    pub fn variance_status(&self) -> &'static str {
        match self.variance {
            VarianceSource::Channels(_) => "present",
            VarianceSource::HalfBuffer(_) | VarianceSource::Spatial => "estimated",
            VarianceSource::Unavailable => "missing",
        }
    }

    /// Where the variance comes from, in words.
    pub fn variance_description(&self) -> String {
        match &self.variance {
            VarianceSource::Channels(c) => compact_channels(c),
            VarianceSource::HalfBuffer(c) => {
                format!("from half buffer {}: (mean − half)², 3×3 box", compact_channels(c))
            }
            VarianceSource::Spatial => "spatially: 3×3 local variance (too high at edges and texture)".into(),
            VarianceSource::Unavailable => "needs the mean first".into(),
        }
    }
}

/// The KPCN inputs of one frame as planes (`width * height` each, row-major).
#[derive(Debug, Clone, PartialEq)]
pub struct KpcnInputs {
    /// Frame width.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// Beauty RGB.
    pub color: [Vec<f32>; 3],
    /// Diffuse RGB.
    pub diffuse: [Vec<f32>; 3],
    /// Specular RGB.
    pub specular: [Vec<f32>; 3],
    /// Albedo RGB.
    pub albedo: [Vec<f32>; 3],
    /// Normal XYZ.
    pub normal: [Vec<f32>; 3],
    /// Depth.
    pub depth: Vec<f32>,
    /// Visibility, when the renderer wrote it.
    pub visibility: Option<Vec<f32>>,
    /// Variance of the mean of `color` (RGB average).
    pub color_variance: Vec<f32>,
    /// Variance of the mean of `diffuse`.
    pub diffuse_variance: Vec<f32>,
    /// Variance of the mean of `specular`.
    pub specular_variance: Vec<f32>,
    /// Variance of the mean of `albedo`.
    pub albedo_variance: Vec<f32>,
    /// Variance of the mean of `normal`.
    pub normal_variance: Vec<f32>,
    /// Variance of the mean of `depth`.
    pub depth_variance: Vec<f32>,
}

/// A layout applied to one file's channels.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// The layout used.
    pub layout: Layout,
    /// Whether it was auto-detected (rather than asked for).
    pub detected: bool,
    /// One entry per quantity, in [`Quantity::ALL`] order.
    pub entries: Vec<Entry>,
}

const RGB_SUFFIXES: [[&str; 3]; 4] = [["R", "G", "B"], ["r", "g", "b"], ["X", "Y", "Z"], ["x", "y", "z"]];
const SCALAR_SUFFIXES: [&str; 9] = ["Z", "z", "Y", "y", "R", "r", "V", "X", "x"];

/// Channel-name lookup over one file.
struct Names<'a>(HashSet<&'a str>);

impl Names<'_> {
    /// The `n` channels of `layer` (`""` = root), trying the usual component spellings.
    fn find(&self, layer: &str, n: usize) -> Option<Vec<String>> {
        let full = |s: &str| if layer.is_empty() { s.to_string() } else { format!("{layer}.{s}") };
        if n == 3 {
            return RGB_SUFFIXES
                .iter()
                .map(|set| set.map(full))
                .find(|set| set.iter().all(|c| self.0.contains(c.as_str())))
                .map(Vec::from);
        }
        SCALAR_SUFFIXES
            .iter()
            .map(|s| full(s))
            .chain((!layer.is_empty()).then(|| layer.to_string()))
            .find(|c| self.0.contains(c.as_str()))
            .map(|c| vec![c])
    }

    /// The quantity's channels under the first layer name that has them.
    fn source(&self, layers: &[&str], n: usize) -> Source {
        layers.iter().find_map(|l| self.find(l, n)).map(Source::Channels).unwrap_or_else(|| {
            let l = layers[0];
            Source::Missing(if n == 3 {
                RGB_SUFFIXES[0].map(|s| full_name(l, s)).to_vec()
            } else {
                vec![full_name(l, "Z")]
            })
        })
    }

    /// A variance layer: one channel, or three averaged.
    fn variance(&self, layers: &[&str]) -> Option<Vec<String>> {
        layers.iter().find_map(|l| self.find(l, 1).or_else(|| self.find(l, 3)))
    }
}

fn full_name(layer: &str, s: &str) -> String {
    if layer.is_empty() { s.to_string() } else { format!("{layer}.{s}") }
}

fn bx(s: Source) -> Box<Source> {
    Box::new(s)
}

impl Mapping {
    /// Applies `layout` (or the best-matching one when `None`) to a file's channels.
    pub fn new<'a>(channels: impl IntoIterator<Item = &'a str>, layout: Option<Layout>) -> Mapping {
        let names = Names(channels.into_iter().collect());
        match layout {
            Some(l) => Self::build(&names, l, false),
            None => {
                let candidates = Layout::ALL.map(|l| Self::build(&names, l, true));
                let score = |m: &Mapping| m.entries.iter().filter(|e| !e.mean.is_missing()).count();
                let best = candidates.iter().map(score).max().unwrap_or(0);
                // Ties go to the earliest (native first).
                candidates.into_iter().find(|m| score(m) == best).expect("three candidates")
            }
        }
    }

    /// The mapping for a frame.
    pub fn for_frame(fb: &FrameBuffers, layout: Option<Layout>) -> Mapping {
        Self::new(fb.channel_names(), layout)
    }

    fn build(n: &Names, layout: Layout, detected: bool) -> Mapping {
        let entries = match layout {
            Layout::Native => Self::native(n),
            Layout::Cycles => Self::cycles(n),
            Layout::RenderMan => Self::renderman(n),
        };
        Mapping { layout, detected, entries }
    }

    fn entry(quantity: Quantity, mean: Source, variance: Option<Vec<String>>, half: Option<Vec<String>>) -> Entry {
        let variance = match (mean.is_missing(), variance, half) {
            (true, _, _) => VarianceSource::Unavailable,
            (false, Some(v), _) => VarianceSource::Channels(v),
            (false, None, Some(h)) => VarianceSource::HalfBuffer(h),
            (false, None, None) => VarianceSource::Spatial,
        };
        Entry { quantity, mean, variance }
    }

    fn native(n: &Names) -> Vec<Entry> {
        let mut color = n.source(&[""], 3);
        let diffuse = n.source(&["diffuse"], 3);
        let mut specular = n.source(&["specular"], 3);
        if color.is_missing() && !diffuse.is_missing() && !specular.is_missing() {
            color = Source::Sum(bx(diffuse.clone()), bx(specular.clone()));
        }
        if specular.is_missing() && !color.is_missing() && !diffuse.is_missing() {
            specular = Source::Difference(bx(color.clone()), bx(diffuse.clone()));
        }
        let means = [color, diffuse, specular];
        Quantity::ALL
            .iter()
            .enumerate()
            .map(|(i, &q)| {
                let mean = means.get(i).cloned().unwrap_or_else(|| n.source(&[q.name()], q.components()));
                let derived = mean.is_derived();
                let var = n.variance(&[&format!("{}Variance", q.name())]);
                // A derived mean's half buffer would be inconsistent with it.
                let half = if derived { None } else { n.find(&format!("{}A", q.name()), q.components()) };
                Self::entry(q, mean, var, half)
            })
            .collect()
    }

    fn cycles(n: &Names) -> Vec<Entry> {
        // The view-layer prefix, e.g. "ViewLayer." (empty for single-layer files).
        // The first view layer in name order, so the choice does not depend on hashing.
        let prefix =
            n.0.iter()
                .filter_map(|c| ["Combined.R", "DiffDir.R", "Diffuse Direct.R"].iter().find_map(|p| c.strip_suffix(p)))
                .min()
                .unwrap_or("ViewLayer.")
                .to_string();
        let pass =
            |short: &str, long: &str, k: usize| n.source(&[&format!("{prefix}{short}"), &format!("{prefix}{long}")], k);
        let combined = pass("Combined", "Combined", 3);
        let diffuse = Source::Product(
            bx(Source::Sum(bx(pass("DiffDir", "Diffuse Direct", 3)), bx(pass("DiffInd", "Diffuse Indirect", 3)))),
            bx(pass("DiffCol", "Diffuse Color", 3)),
        );
        let specular = Source::Difference(bx(combined.clone()), bx(diffuse.clone()));
        let albedo = pass("DiffCol", "Diffuse Color", 3);
        let normal = pass("Normal", "Normal", 3);
        // Cycles writes 1e10 at misses; SPEC §3 wants 0.
        let depth = Source::MissAbove(bx(pass("Depth", "Depth", 1)), 1e9);
        let means = [combined, diffuse, specular, albedo, normal, depth, Source::Missing(vec![])];
        Quantity::ALL.iter().zip(means).map(|(&q, m)| Self::entry(q, m, None, None)).collect()
    }

    fn renderman(n: &Names) -> Vec<Entry> {
        let spec: [(&str, &[&str]); 7] = [
            ("Ci", &["mse"]),
            ("diffuse", &["diffuse_mse", "diffuse_var"]),
            ("specular", &["specular_mse", "specular_var"]),
            ("albedo", &["albedo_var", "albedo_mse"]),
            ("normal", &["normal_var", "normal_mse"]),
            ("zfiltered", &["zfiltered_var", "zfiltered_mse"]),
            ("visibility", &["visibility_var"]),
        ];
        Quantity::ALL
            .iter()
            .zip(spec)
            .map(|(&q, (layer, var))| Self::entry(q, n.source(&[layer], q.components()), n.variance(var), None))
            .collect()
    }

    /// The entry for `q`.
    pub fn entry_for(&self, q: Quantity) -> &Entry {
        self.entries.iter().find(|e| e.quantity == q).expect("every quantity has an entry")
    }

    /// Channels the network needs that the file lacks.
    pub fn missing_required(&self) -> Vec<String> {
        let mut out = Vec::new();
        for e in self.entries.iter().filter(|e| e.quantity.required()) {
            e.mean.missing_channels(&mut out);
        }
        out.dedup();
        out
    }

    /// Network inputs whose variance is not in the file and will be estimated.
    pub fn estimated_variances(&self) -> Vec<&Entry> {
        self.entries.iter().filter(|e| e.quantity.required() && e.variance_status() == "estimated").collect()
    }

    /// Every file channel [`extract`](Mapping::extract) reads, each once, in mapping order:
    /// what a streaming reader needs to load.
    pub fn channels(&self) -> Vec<String> {
        let mut all = Vec::new();
        for e in &self.entries {
            e.mean.channels(&mut all);
            if let VarianceSource::Channels(c) | VarianceSource::HalfBuffer(c) = &e.variance {
                all.extend(c.iter().cloned());
            }
        }
        let mut seen = HashSet::new();
        all.retain(|c| seen.insert(c.clone()));
        all
    }

    /// What to do about missing channels.
    pub fn hint(&self) -> &'static str {
        self.layout.hint()
    }

    /// An error naming `path`, the layout, every missing required channel and what to do,
    /// when the network cannot run on this mapping.
    pub fn check(&self, path: &Path) -> Result<(), IoError> {
        let missing = self.missing_required();
        if missing.is_empty() {
            return Ok(());
        }
        Err(IoError::MissingChannels {
            path: path.into(),
            layout: self.layout.to_string(),
            missing,
            hint: self.hint().into(),
        })
    }

    /// Builds the network's inputs from a frame, estimating absent variances.
    pub fn extract(&self, fb: &FrameBuffers) -> Result<KpcnInputs, IoError> {
        self.check(&fb.display_path())?;
        let (w, h) = (fb.width(), fb.height());
        let mean = |q: Quantity| self.entry_for(q).mean.eval(fb);
        let rgb = |q: Quantity| -> [Vec<f32>; 3] {
            let v = mean(q).expect("required inputs checked above");
            v.try_into().expect("three components")
        };
        let variance = |q: Quantity, m: &[Vec<f32>]| -> Vec<f32> {
            match &self.entry_for(q).variance {
                VarianceSource::Channels(c) => average(c.iter().map(|n| fb.channel(n).expect("mapped channel")), w * h),
                VarianceSource::HalfBuffer(c) => {
                    let sq = m.iter().zip(c).map(|(m, a)| {
                        let a = fb.channel(a).expect("mapped channel");
                        m.iter().zip(a).map(|(m, a)| (m - a) * (m - a)).collect::<Vec<f32>>()
                    });
                    box3(&average(sq.collect::<Vec<_>>().iter().map(Vec::as_slice), w * h), w, h)
                }
                VarianceSource::Spatial | VarianceSource::Unavailable => spatial_variance(m, w, h),
            }
        };
        let color = rgb(Quantity::Color);
        let diffuse = rgb(Quantity::Diffuse);
        let specular = rgb(Quantity::Specular);
        let albedo = rgb(Quantity::Albedo);
        let normal = rgb(Quantity::Normal);
        let depth = mean(Quantity::Depth).and_then(|mut v| v.pop()).expect("required inputs checked above");
        let visibility = mean(Quantity::Visibility).and_then(|mut v| v.pop());
        Ok(KpcnInputs {
            width: w,
            height: h,
            color_variance: variance(Quantity::Color, &color),
            diffuse_variance: variance(Quantity::Diffuse, &diffuse),
            specular_variance: variance(Quantity::Specular, &specular),
            albedo_variance: variance(Quantity::Albedo, &albedo),
            normal_variance: variance(Quantity::Normal, &normal),
            depth_variance: variance(Quantity::Depth, std::slice::from_ref(&depth)),
            color,
            diffuse,
            specular,
            albedo,
            normal,
            depth,
            visibility,
        })
    }
}

/// Per-pixel mean over several planes.
fn average<'a>(planes: impl Iterator<Item = &'a [f32]>, n: usize) -> Vec<f32> {
    let mut sum = vec![0f32; n];
    let mut k = 0;
    for p in planes {
        sum.iter_mut().zip(p).for_each(|(s, v)| *s += v);
        k += 1;
    }
    let inv = 1.0 / k.max(1) as f32;
    sum.iter_mut().for_each(|s| *s *= inv);
    sum
}

/// Visits the 3×3 neighbourhood of every pixel, clamped at the frame border.
fn neighbourhood3(w: usize, h: usize, mut f: impl FnMut(usize, &mut dyn Iterator<Item = usize>)) {
    for y in 0..h {
        for x in 0..w {
            let ys = y.saturating_sub(1)..=(y + 1).min(h - 1);
            let mut it = ys.flat_map(|yy| (x.saturating_sub(1)..=(x + 1).min(w - 1)).map(move |xx| yy * w + xx));
            f(y * w + x, &mut it);
        }
    }
}

/// 3×3 box filter, clamped at the border.
pub fn box3(v: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0f32; v.len()];
    neighbourhood3(w, h, |i, nb| {
        let (s, k) = nb.fold((0f64, 0u32), |(s, k), j| (s + v[j] as f64, k + 1));
        out[i] = (s / k as f64) as f32;
    });
    out
}

/// Local 3×3 sample variance, averaged over components.
pub fn spatial_variance(planes: &[Vec<f32>], w: usize, h: usize) -> Vec<f32> {
    let per_plane = planes.iter().map(|p| {
        let mut out = vec![0f32; p.len()];
        neighbourhood3(w, h, |i, nb| {
            let (mut s, mut s2, mut k) = (0f64, 0f64, 0u32);
            for j in nb {
                let v = p[j] as f64;
                s += v;
                s2 += v * v;
                k += 1;
            }
            out[i] = if k > 1 { ((s2 - s * s / k as f64) / (k - 1) as f64).max(0.0) as f32 } else { 0.0 };
        });
        out
    });
    let per_plane: Vec<Vec<f32>> = per_plane.collect();
    average(per_plane.iter().map(Vec::as_slice), w * h)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn native_names() -> Vec<String> {
        let mut v: Vec<String> = ["R", "G", "B"].map(String::from).to_vec();
        for q in ["diffuse", "specular", "albedo", "normal"] {
            v.extend(["R", "G", "B"].map(|c| format!("{q}.{c}")));
            v.push(format!("{q}Variance.Z"));
        }
        v.extend(["depth.Z", "depthVariance.Z", "colorVariance.Z"].map(String::from));
        v
    }

    #[test]
    fn native_layout_is_detected_and_complete() {
        let names = native_names();
        let m = Mapping::new(names.iter().map(String::as_str), None);
        assert_eq!(m.layout, Layout::Native);
        assert!(m.missing_required().is_empty());
        assert_eq!(m.entry_for(Quantity::Visibility).mean_status(), "missing");
        assert_eq!(m.entry_for(Quantity::Depth).variance_status(), "present");
    }

    #[test]
    fn specular_is_derived_when_only_color_and_diffuse_exist() {
        let names: Vec<String> = native_names().into_iter().filter(|n| !n.starts_with("specular")).collect();
        let m = Mapping::new(names.iter().map(String::as_str), Some(Layout::Native));
        assert_eq!(m.entry_for(Quantity::Specular).mean_status(), "derived");
        assert_eq!(m.entry_for(Quantity::Specular).variance_status(), "estimated");
    }

    #[test]
    fn missing_channels_are_named() {
        let m = Mapping::new(["R", "G", "B", "diffuse.R", "diffuse.G", "diffuse.B"], None);
        let miss = m.missing_required();
        assert!(miss.contains(&"albedo.R".to_string()), "{miss:?}");
        assert!(miss.contains(&"depth.Z".to_string()), "{miss:?}");
    }

    #[test]
    fn renderman_names_are_detected() {
        let mut names = Vec::new();
        for l in [
            "Ci",
            "mse",
            "diffuse",
            "diffuse_mse",
            "specular",
            "specular_mse",
            "albedo",
            "albedo_var",
            "normal",
            "normal_var",
        ] {
            names.extend(["r", "g", "b"].map(|c| format!("{l}.{c}")));
        }
        names.extend(["zfiltered.r", "zfiltered_var.r"].map(String::from));
        let m = Mapping::new(names.iter().map(String::as_str), None);
        assert_eq!(m.layout, Layout::RenderMan);
        assert!(m.missing_required().is_empty(), "{:?}", m.missing_required());
        assert_eq!(m.entry_for(Quantity::Color).variance_status(), "present");
    }

    #[test]
    fn spatial_variance_of_a_constant_is_zero_and_of_a_checker_is_positive() {
        let flat = vec![vec![2.0f32; 12]];
        assert!(spatial_variance(&flat, 4, 3).iter().all(|&v| v == 0.0));
        let checker = vec![(0..12).map(|i| ((i % 4 + i / 4) % 2) as f32).collect::<Vec<_>>()];
        assert!(spatial_variance(&checker, 4, 3).iter().all(|&v| v > 0.2));
    }

    #[test]
    fn box3_preserves_a_constant_and_averages_neighbours() {
        assert_eq!(box3(&[5.0; 6], 3, 2), vec![5.0; 6]);
        // 1×3 row [0, 3, 6]: centre averages all three, ends average two.
        assert_eq!(box3(&[0.0, 3.0, 6.0], 3, 1), vec![1.5, 3.0, 4.5]);
    }

    #[test]
    fn compact_channel_names() {
        let c = ["diffuse.R", "diffuse.G", "diffuse.B"].map(String::from);
        assert_eq!(compact_channels(&c), "diffuse.R/G/B");
        assert_eq!(compact_channels(&["R", "G", "B"].map(String::from)), "R,G,B");
    }
}
