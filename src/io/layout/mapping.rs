//! A layout applied to one file's channel names: the three renderer conventions.

use super::filters::{average, box3, spatial_variance};
use super::source::{Entry, Source, VarianceSource, VarianceStatus};
use super::{KpcnInputs, Layout, Quantity};
use crate::io::{FrameBuffers, IoError};
use std::collections::HashSet;
use std::path::Path;

/// A layout applied to one file's channels.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// The layout used.
    pub layout: Layout,
    /// Whether it was auto-detected (rather than asked for).
    pub detected: bool,
    /// One entry per quantity, in [`Quantity::ALL`] order.
    pub entries: Vec<Entry>,
    /// The Blender view layer read (Cycles layout), e.g. `ViewLayer`; empty for files
    /// without view-layer prefixes.
    pub view_layer: Option<String>,
    /// Every view layer in the file (Cycles layout), in name order.
    pub view_layers: Vec<String>,
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
    /// Three per-channel variances (RenderMan's `mse.r/g/b`) are preferred to one, which
    /// would otherwise match `.r` alone as a scalar; ARCHITECTURE.md §Layout averages them.
    fn variance(&self, layers: &[&str]) -> Option<Vec<String>> {
        layers.iter().find_map(|l| self.find(l, 3).or_else(|| self.find(l, 1)))
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
        Self::for_view_layer(channels, layout, None)
    }

    /// [`Mapping::new`] reading Blender view layer `view_layer` (Cycles layout) instead of
    /// the first one by name. A layer the file lacks leaves its passes missing (see
    /// [`Mapping::view_layers`]).
    pub fn for_view_layer<'a>(
        channels: impl IntoIterator<Item = &'a str>,
        layout: Option<Layout>,
        view_layer: Option<&str>,
    ) -> Mapping {
        let names = Names(channels.into_iter().collect());
        match layout {
            Some(l) => Self::build(&names, l, false, view_layer),
            None => {
                let candidates = Layout::ALL.map(|l| Self::build(&names, l, true, view_layer));
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

    fn build(n: &Names, layout: Layout, detected: bool, view_layer: Option<&str>) -> Mapping {
        let view_layers = Self::cycles_view_layers(n);
        let (entries, view_layer) = match layout {
            Layout::Native => (Self::native(n), None),
            Layout::Cycles => {
                // The first view layer in name order, so the choice does not depend on hashing.
                let chosen = view_layer.map(str::to_string).or_else(|| view_layers.first().cloned());
                (Self::cycles(n, chosen.as_deref()), chosen)
            }
            Layout::RenderMan => (Self::renderman(n), None),
        };
        let view_layers = if layout == Layout::Cycles { view_layers } else { Vec::new() };
        Mapping { layout, detected, entries, view_layer, view_layers }
    }

    /// Prefixes of Blender's passes (`ViewLayer` of `ViewLayer.Combined.R`), sorted;
    /// empty when passes have no prefix.
    fn cycles_view_layers(n: &Names) -> Vec<String> {
        let mut layers: Vec<String> =
            n.0.iter()
                .filter_map(|c| ["Combined.R", "DiffDir.R", "Diffuse Direct.R"].iter().find_map(|p| c.strip_suffix(p)))
                .filter_map(|p| p.strip_suffix('.'))
                .map(str::to_string)
                .collect();
        layers.sort();
        layers.dedup();
        layers
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
        // A beauty written as `rgba.*` (some renderers' default) is the colour too.
        let mut color = n.source(&["", "rgba"], 3);
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

    fn cycles(n: &Names, view_layer: Option<&str>) -> Vec<Entry> {
        // The view-layer prefix, e.g. "ViewLayer." (empty for files without prefixes).
        let unprefixed = n.0.contains("Combined.R") || n.0.contains("DiffDir.R");
        let prefix = match view_layer {
            Some(l) => format!("{l}."),
            None if unprefixed => String::new(),
            None => "ViewLayer.".into(),
        };
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
        // Cycles writes 1e10 at misses; ARCHITECTURE.md §Layout wants 0.
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
        // A pass can be missing for two inputs (Cycles' DiffCol: diffuse and albedo).
        let mut seen = HashSet::new();
        out.retain(|c| seen.insert(c.clone()));
        out
    }

    /// Network inputs whose variance is not in the file and will be estimated.
    pub fn estimated_variances(&self) -> Vec<&Entry> {
        self.entries
            .iter()
            .filter(|e| e.quantity.required() && e.variance_status() == VarianceStatus::Estimated)
            .collect()
    }

    /// Whether the colour's variance comes from the file itself (per-pixel variances or half
    /// buffers), rather than only from the 3×3 spatial estimate, as for Blender's own
    /// files: what `kpcn denoise --model auto` picks `default` or `spatial` by.
    pub fn colour_variance_in_file(&self) -> bool {
        !matches!(self.entry_for(Quantity::Color).variance, VarianceSource::Spatial | VarianceSource::Unavailable)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::layout::MeanStatus;

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
        assert_eq!(m.entry_for(Quantity::Visibility).mean_status(), MeanStatus::Missing);
        assert_eq!(m.entry_for(Quantity::Depth).variance_status(), VarianceStatus::Present);
        assert!(m.colour_variance_in_file());
        // Without `colorVariance`, the colour's variance is the spatial estimate.
        let names: Vec<&str> = names.iter().map(String::as_str).filter(|n| *n != "colorVariance.Z").collect();
        assert!(!Mapping::new(names, Some(Layout::Native)).colour_variance_in_file());
    }

    #[test]
    fn specular_is_derived_when_only_color_and_diffuse_exist() {
        let names: Vec<String> = native_names().into_iter().filter(|n| !n.starts_with("specular")).collect();
        let m = Mapping::new(names.iter().map(String::as_str), Some(Layout::Native));
        assert_eq!(m.entry_for(Quantity::Specular).mean_status(), MeanStatus::Derived);
        assert_eq!(m.entry_for(Quantity::Specular).variance_status(), VarianceStatus::Estimated);
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
        assert_eq!(m.entry_for(Quantity::Color).variance_status(), VarianceStatus::Present);
        // All three of mse.r/g/b are averaged, not `.r` alone.
        let three = |c: &str| ["r", "g", "b"].map(|x| format!("{c}.{x}")).to_vec();
        assert_eq!(m.entry_for(Quantity::Color).variance, VarianceSource::Channels(three("mse")));
        assert_eq!(m.entry_for(Quantity::Albedo).variance, VarianceSource::Channels(three("albedo_var")));
        assert_eq!(m.entry_for(Quantity::Depth).variance, VarianceSource::Channels(vec!["zfiltered_var.r".into()]));
    }
}
