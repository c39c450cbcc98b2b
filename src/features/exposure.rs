//! Autoexposure: the factor that brings a frame's key to [`EXPOSURE_KEY`], measured as the
//! frame streams past, and the whole-frame statistics a band is preprocessed with.

use super::sanitize;
use crate::io::layout::KpcnInputs;

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
    /// The largest finite depth ([`super::max_depth`]).
    pub max_depth: f32,
    /// The radiance factor (1, or [`ExposureMeter`]'s).
    pub exposure: f32,
}

/// [`FrameStats`] gathered band by band, top to bottom (a streamed frame's first pass).
#[derive(Debug, Clone)]
pub struct FrameStatsMeter {
    max_depth: f32,
    /// Metering the exposure, for auto-exposed models.
    exposure: Option<ExposureMeter>,
}

impl FrameStatsMeter {
    /// For a frame `width` wide; `exposure`: the model is auto-exposed.
    pub fn new(width: usize, exposure: bool) -> Self {
        FrameStatsMeter { max_depth: 0.0, exposure: exposure.then(|| ExposureMeter::new(width)) }
    }

    /// Whether the next band's colour is wanted (else its depth suffices).
    pub fn wants_colour(&self) -> bool {
        self.exposure.is_some()
    }

    /// Adds a band's depth, and its colour (as the network's inputs hold it) when wanted.
    pub fn add(&mut self, depth: &[f32], colour: Option<[&[f32]; 3]>) {
        self.max_depth = self.max_depth.max(super::max_depth(depth));
        if let (Some(m), Some(c)) = (&mut self.exposure, colour) {
            m.add_rows(c);
        }
    }

    /// The frame's statistics.
    pub fn finish(self) -> FrameStats {
        FrameStats { max_depth: self.max_depth, exposure: self.exposure.map_or(1.0, |m| m.exposure()) }
    }
}

/// [`ExposureMeter`]'s factor for a whole frame.
pub fn auto_exposure(k: &KpcnInputs) -> f32 {
    let mut m = ExposureMeter::new(k.width);
    m.add_rows(k.color.each_ref().map(Vec::as_slice));
    m.exposure()
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
}
