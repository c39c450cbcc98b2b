//! The film: per-pixel running statistics (Welford) of every per-sample value, snapshot at
//! the requested sample counts and at their halves (for the half buffers), and turned into
//! the layered frames of ARCHITECTURE.md §Layout.

use super::integrator::{ALBEDO, COLOR, DEPTH, DIFFUSE, NORMAL, SAMPLE_LEN, SPECULAR, VISIBILITY};
use super::rng::{SCRAMBLES, Sampler, scramble_of};
use crate::io::{Attribute, FrameBuffers, IoError, SampleFormat};

/// Quantities: (layer, offset into a sample, components).
pub const QUANTITIES: [(&str, usize, usize); 7] = [
    ("color", COLOR, 3),
    ("diffuse", DIFFUSE, 3),
    ("specular", SPECULAR, 3),
    ("albedo", ALBEDO, 3),
    ("normal", NORMAL, 3),
    ("depth", DEPTH, 1),
    ("visibility", VISIBILITY, 1),
];

/// The pixel filter, applied by importance sampling: each sample lands at an offset from
/// the pixel centre drawn from the filter and counts with weight one, as in Cycles, so
/// pixels stay independent estimates and their variances stay exact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PixelFilter {
    /// Uniform over the pixel's square.
    Box,
    /// Blackman–Harris window with Cycles' width convention: support ±`width` px.
    BlackmanHarris(f32),
}

/// Cycles' default: Blackman–Harris, width 1.5 px.
impl Default for PixelFilter {
    fn default() -> Self {
        PixelFilter::BlackmanHarris(1.5)
    }
}

impl PixelFilter {
    /// The name used on the command line and in file metadata.
    pub fn name(self) -> String {
        match self {
            PixelFilter::Box => "box".into(),
            PixelFilter::BlackmanHarris(w) => format!("blackman-harris:{w}"),
        }
    }

    /// Parses `box`, `blackman-harris` (width 1.5) or `blackman-harris:W`.
    pub fn parse(s: &str) -> Result<PixelFilter, String> {
        let bad = || format!("pixel filter `{s}`: use box, blackman-harris or blackman-harris:WIDTH (0.5…4 px)");
        match s.split_once(':') {
            None if s == "box" => Ok(PixelFilter::Box),
            None if s == "blackman-harris" => Ok(PixelFilter::default()),
            Some(("blackman-harris", w)) => match w.parse::<f32>() {
                Ok(w) if (0.5..=4.0).contains(&w) => Ok(PixelFilter::BlackmanHarris(w)),
                _ => Err(bad()),
            },
            _ => Err(bad()),
        }
    }

    /// The sampler of offsets from the pixel centre.
    pub fn sampler(self) -> FilterSampler {
        let PixelFilter::BlackmanHarris(width) = self else {
            return FilterSampler { half_width: 0.5, inverse_cdf: Vec::new() };
        };
        // Tabulate the CDF over [−width, width] and invert it on a uniform grid.
        const N: usize = 1024;
        let window = |t: f64| {
            let a = std::f64::consts::TAU * t;
            0.35875 - 0.48829 * a.cos() + 0.14128 * (2.0 * a).cos() - 0.01168 * (3.0 * a).cos()
        };
        let mut cdf = vec![0f64; N + 1];
        for i in 0..N {
            let t = (i as f64 + 0.5) / N as f64;
            cdf[i + 1] = cdf[i] + window(t);
        }
        let total = cdf[N];
        let mut inverse_cdf = Vec::with_capacity(N + 1);
        let mut j = 0;
        for k in 0..=N {
            let target = total * k as f64 / N as f64;
            while j < N - 1 && cdf[j + 1] < target {
                j += 1;
            }
            let span = (cdf[j + 1] - cdf[j]).max(1e-300);
            let t = (j as f64 + ((target - cdf[j]) / span).clamp(0.0, 1.0)) / N as f64;
            inverse_cdf.push(((t - 0.5) * 2.0 * width as f64) as f32);
        }
        FilterSampler { half_width: width, inverse_cdf }
    }
}

/// Draws film offsets from a [`PixelFilter`].
#[derive(Debug, Clone)]
pub struct FilterSampler {
    half_width: f32,
    // Offsets from the centre at uniform steps of the CDF; empty for the box.
    inverse_cdf: Vec<f32>,
}

impl FilterSampler {
    /// Where a sample lands relative to the pixel's corner, in pixels (the centre is ½),
    /// for a uniform `u` in [0, 1).
    pub fn jitter(&self, u: f32) -> f32 {
        if self.inverse_cdf.is_empty() {
            return u;
        }
        let x = u.clamp(0.0, 1.0) * (self.inverse_cdf.len() - 1) as f32;
        let i = (x as usize).min(self.inverse_cdf.len() - 2);
        let f = x - i as f32;
        0.5 + (self.inverse_cdf[i] * (1.0 - f) + self.inverse_cdf[i + 1] * f).clamp(-self.half_width, self.half_width)
    }
}

/// A snapshot of one pixel after some number of samples.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot {
    /// Means of every per-sample value.
    pub mean: [f32; SAMPLE_LEN],
    /// Variance of the mean per quantity (RGB quantities: the channel average).
    pub variance: [f32; 7],
}

/// Welford accumulator over one pixel's samples, and with the Sobol' sampler the sums of
/// each of its [`SCRAMBLES`] (samples arrive in order: sample `n` is scramble
/// [`scramble_of`]`(n)`).
#[derive(Clone)]
pub struct PixelStats {
    n: u64,
    mean: [f64; SAMPLE_LEN],
    m2: [f64; SAMPLE_LEN],
    scrambles: Option<[[f64; SAMPLE_LEN]; SCRAMBLES as usize]>,
}

impl PixelStats {
    /// An empty accumulator for samples placed by `sampler`.
    pub fn new(sampler: Sampler) -> PixelStats {
        let scrambles = (sampler == Sampler::Sobol).then_some([[0.0; SAMPLE_LEN]; SCRAMBLES as usize]);
        PixelStats { n: 0, mean: [0.0; SAMPLE_LEN], m2: [0.0; SAMPLE_LEN], scrambles }
    }

    /// Adds the next sample.
    pub fn add(&mut self, s: &[f32; SAMPLE_LEN]) {
        if let Some(sums) = self.scrambles.as_mut() {
            for (sum, &x) in sums[scramble_of(self.n as u32) as usize].iter_mut().zip(s) {
                *sum += x as f64;
            }
        }
        self.n += 1;
        let inv = 1.0 / self.n as f64;
        for ((&x, mean), m2) in s.iter().zip(&mut self.mean).zip(&mut self.m2) {
            let x = x as f64;
            let d = x - *mean;
            *mean += d * inv;
            *m2 += d * (x - *mean);
        }
    }

    /// Means and variances of the mean so far. Independent samples (`random`): the sample
    /// variance over `n`. Sobol': the spread of the scrambles' means, which are independent
    /// where the points within one are not (with a sample count the scrambles do not share
    /// evenly, the former).
    pub fn snapshot(&self) -> Snapshot {
        let mut snap = Snapshot { mean: [0.0; SAMPLE_LEN], variance: [0.0; 7] };
        for (out, m) in snap.mean.iter_mut().zip(&self.mean) {
            *out = *m as f32;
        }
        if self.n < 2 {
            return snap;
        }
        for (q, (_, off, comps)) in QUANTITIES.iter().enumerate() {
            let v: f64 = (0..*comps).map(|c| self.variance_of_mean(off + c)).sum::<f64>() / *comps as f64;
            snap.variance[q] = v as f32;
        }
        snap
    }

    /// The variance of value `ch`'s mean over the samples so far (at least two).
    fn variance_of_mean(&self, ch: usize) -> f64 {
        let g = self.n.min(SCRAMBLES as u64);
        match &self.scrambles {
            Some(sums) if self.n.is_multiple_of(g) => {
                let per = (self.n / g) as f64;
                let means = sums[..g as usize].iter().map(|s| s[ch] / per);
                let m = means.clone().sum::<f64>() / g as f64;
                means.map(|x| (x - m) * (x - m)).sum::<f64>() / (g * (g - 1)) as f64
            }
            _ => self.m2[ch] / ((self.n - 1) as f64 * self.n as f64),
        }
    }
}

/// The sample counts to snapshot: the checkpoints and their halves, sorted, unique.
pub fn snapshot_counts(checkpoints: &[u32]) -> Vec<u32> {
    let mut v: Vec<u32> = checkpoints.iter().flat_map(|&c| [c, c / 2]).filter(|&c| c > 0).collect();
    v.sort_unstable();
    v.dedup();
    v
}

/// Builds the layered frame for `spp` from per-pixel snapshots (`snaps[pixel][k]` at
/// `counts[k]`).
pub fn frame(
    width: usize,
    height: usize,
    spp: u32,
    counts: &[u32],
    snaps: &[Vec<Snapshot>],
    attributes: &[Attribute],
) -> Result<FrameBuffers, IoError> {
    let at = counts.iter().position(|&c| c == spp).expect("checkpoint was snapshot");
    let half = counts.iter().position(|&c| c == spp / 2).expect("half checkpoint was snapshot");
    let mut fb = FrameBuffers::new(width, height);
    let plane = |k: usize, f: &dyn Fn(&Snapshot) -> f32| -> Vec<f32> { snaps.iter().map(|p| f(&p[k])).collect() };
    for (q, (layer, off, comps)) in QUANTITIES.iter().enumerate() {
        let suffixes: &[&str] = if *comps == 3 { &["R", "G", "B"] } else { &["Z"] };
        for (c, s) in suffixes.iter().enumerate() {
            // Colour is written as diffuse + specular so the identity holds exactly in the file.
            let mean = |k: usize| -> Vec<f32> {
                if *layer == "color" {
                    plane(k, &|p| p.mean[DIFFUSE + c] + p.mean[SPECULAR + c])
                } else {
                    plane(k, &|p| p.mean[off + c])
                }
            };
            let name = if *layer == "color" { s.to_string() } else { format!("{layer}.{s}") };
            fb.insert(&name, SampleFormat::Float, mean(at))?;
            fb.insert(&format!("{layer}A.{s}"), SampleFormat::Float, mean(half))?;
        }
        fb.insert(&format!("{layer}Variance.Z"), SampleFormat::Float, plane(at, &|p| p.variance[q]))?;
    }
    for a in attributes {
        fb.set_attribute(a.clone());
    }
    fb.set_attribute(Attribute::int("kpcn:spp", spp as i32));
    Ok(fb)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blackman_harris_offsets_follow_the_window_over_cycles_support() {
        let s = PixelFilter::default().sampler();
        let n = 20_000;
        let xs: Vec<f32> = (0..n).map(|i| s.jitter((i as f32 + 0.5) / n as f32) - 0.5).collect();
        assert!(xs.iter().all(|x| x.abs() <= 1.5), "support ±1.5 px");
        assert!(xs.windows(2).all(|w| w[0] <= w[1]), "monotone in u, so strata map to strata");
        let mean = xs.iter().sum::<f32>() / n as f32;
        assert!(mean.abs() < 1e-3, "centred: {mean}");
        // Histogram in 12 bins of 0.25 px against the window's integral.
        let window = |x: f64| {
            let a = std::f64::consts::TAU * (x / 3.0 + 0.5);
            0.35875 - 0.48829 * a.cos() + 0.14128 * (2.0 * a).cos() - 0.01168 * (3.0 * a).cos()
        };
        let total: f64 = (0..3000).map(|i| window(-1.5 + (i as f64 + 0.5) * 1e-3)).sum();
        for b in 0..12 {
            let (lo, hi) = (-1.5 + 0.25 * b as f64, -1.25 + 0.25 * b as f64);
            let expect: f64 = (0..250).map(|i| window(lo + (i as f64 + 0.5) * 1e-3)).sum::<f64>() / total;
            let got = xs.iter().filter(|&&x| (x as f64) >= lo && (x as f64) < hi).count() as f64 / n as f64;
            assert!((got - expect).abs() < 2e-3, "bin [{lo}, {hi}): {got} vs {expect}");
        }
    }

    #[test]
    fn box_jitter_is_the_uniform_itself_and_names_round_trip() {
        let s = PixelFilter::Box.sampler();
        assert_eq!(s.jitter(0.1), 0.1);
        for f in [PixelFilter::Box, PixelFilter::default(), PixelFilter::BlackmanHarris(2.0)] {
            let back = PixelFilter::parse(&f.name()).unwrap();
            assert_eq!(back.name(), f.name());
        }
        assert_eq!(PixelFilter::parse("blackman-harris"), Ok(PixelFilter::BlackmanHarris(1.5)));
        let e = PixelFilter::parse("gauss").unwrap_err();
        assert!(e.contains("gauss") && e.contains("blackman-harris"), "{e}");
        assert!(PixelFilter::parse("blackman-harris:9").is_err());
    }
}
