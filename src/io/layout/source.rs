//! Where an input's mean and variance come from in a file: a tree of channel operations.

use super::Quantity;
use crate::io::FrameBuffers;
use std::fmt;

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
    pub(super) fn is_missing(&self) -> bool {
        match self {
            Source::Channels(_) => false,
            Source::Missing(_) => true,
            Source::Sum(a, b) | Source::Difference(a, b) | Source::Product(a, b) => a.is_missing() || b.is_missing(),
            Source::MissAbove(a, _) => a.is_missing(),
        }
    }

    pub(super) fn missing_channels(&self, out: &mut Vec<String>) {
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

    pub(super) fn channels(&self, out: &mut Vec<String>) {
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

    pub(super) fn is_derived(&self) -> bool {
        !matches!(self, Source::Channels(_) | Source::Missing(_))
    }

    pub(super) fn eval(&self, fb: &FrameBuffers) -> Option<Vec<Vec<f32>>> {
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
pub(super) fn compact_channels(c: &[String]) -> String {
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

/// Where an input's mean stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeanStatus {
    /// In the file.
    Present,
    /// Computed from other channels (e.g. specular = colour − diffuse).
    Derived,
    /// Not in the file and not derivable.
    Missing,
}

/// Where an input's variance stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VarianceStatus {
    /// In the file.
    Present,
    /// Estimated (from half buffers or spatially).
    Estimated,
    /// Missing, because its mean is.
    Missing,
}

impl fmt::Display for MeanStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.pad(match self {
            MeanStatus::Present => "present",
            MeanStatus::Derived => "derived",
            MeanStatus::Missing => "missing",
        })
    }
}

impl fmt::Display for VarianceStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.pad(match self {
            VarianceStatus::Present => "present",
            VarianceStatus::Estimated => "estimated",
            VarianceStatus::Missing => "missing",
        })
    }
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

    /// Whether the mean is in the file, derived from other channels, or missing.
    pub fn mean_status(&self) -> MeanStatus {
        if self.mean.is_missing() {
            MeanStatus::Missing
        } else if self.mean.is_derived() {
            MeanStatus::Derived
        } else {
            MeanStatus::Present
        }
    }

    /// Whether the variance is in the file, estimated, or missing (with its mean).
    pub fn variance_status(&self) -> VarianceStatus {
        match self.variance {
            VarianceSource::Channels(_) => VarianceStatus::Present,
            VarianceSource::HalfBuffer(_) | VarianceSource::Spatial => VarianceStatus::Estimated,
            VarianceSource::Unavailable => VarianceStatus::Missing,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compact_channel_names() {
        let c = ["diffuse.R", "diffuse.G", "diffuse.B"].map(String::from);
        assert_eq!(compact_channels(&c), "diffuse.R/G/B");
        assert_eq!(compact_channels(&["R", "G", "B"].map(String::from)), "R,G,B");
    }
}
