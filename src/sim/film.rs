//! The film: per-pixel running statistics (Welford) of every per-sample value, snapshot at
//! the requested sample counts and at their halves (for the half buffers), and turned into
//! the layered frames of SPEC §3.

use super::integrator::{ALBEDO, COLOR, DEPTH, DIFFUSE, NORMAL, SAMPLE_LEN, SPECULAR, VISIBILITY};
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

/// A snapshot of one pixel after some number of samples.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot {
    /// Means of every per-sample value.
    pub mean: [f32; SAMPLE_LEN],
    /// Variance of the mean per quantity (RGB quantities: the channel average).
    pub variance: [f32; 7],
}

/// Welford accumulator over one pixel's samples.
#[derive(Clone)]
pub struct PixelStats {
    n: u64,
    mean: [f64; SAMPLE_LEN],
    m2: [f64; SAMPLE_LEN],
}

impl Default for PixelStats {
    fn default() -> Self {
        PixelStats { n: 0, mean: [0.0; SAMPLE_LEN], m2: [0.0; SAMPLE_LEN] }
    }
}

impl PixelStats {
    /// Adds one sample.
    pub fn add(&mut self, s: &[f32; SAMPLE_LEN]) {
        self.n += 1;
        let inv = 1.0 / self.n as f64;
        for ((&x, mean), m2) in s.iter().zip(&mut self.mean).zip(&mut self.m2) {
            let x = x as f64;
            let d = x - *mean;
            *mean += d * inv;
            *m2 += d * (x - *mean);
        }
    }

    /// Means and variances of the mean so far.
    pub fn snapshot(&self) -> Snapshot {
        let mut snap = Snapshot { mean: [0.0; SAMPLE_LEN], variance: [0.0; 7] };
        for (out, m) in snap.mean.iter_mut().zip(&self.mean) {
            *out = *m as f32;
        }
        if self.n > 1 {
            let k = 1.0 / ((self.n - 1) as f64 * self.n as f64);
            for (q, (_, off, comps)) in QUANTITIES.iter().enumerate() {
                let v: f64 = (0..*comps).map(|c| self.m2[off + c] * k).sum::<f64>() / *comps as f64;
                snap.variance[q] = v as f32;
            }
        }
        snap
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
