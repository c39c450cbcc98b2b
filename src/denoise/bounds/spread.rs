//! Where the light the diffuse ceiling takes goes ([`crate::model::Architecture::diffuse_spread`]):
//! shared out over the window around the pixel it was taken from, in proportion to the
//! noisy light there, each pixel taking at most its own light again. Kernels that carry the
//! light of a sun patch into the sparse, noisy floor beside it make blotches there; the
//! ceiling takes what the floor's own samples cannot show, and the spread gives it back to
//! the patch, or thinly to the surroundings where they are lit alike, so the frame keeps
//! its light (a room lit through a slit keeps its brightness).

use super::{BandPlanes, box_sums};
use rayon::prelude::*;

/// What each pixel weighs beside its light when the spread shares out what was taken:
/// a window of dark pixels takes it evenly, rather than dividing by nothing (exposed
/// radiance: an auto-exposed frame's key is 0.18).
const DARK_WEIGHT: f32 = 1e-3;

/// The light `taken` from each pixel of `rows` rows of a `w`-wide frame (`taken[c]` holds
/// them: what the ceiling took, radiance) shared out over the (2r + 1)² window around the
/// pixel it was taken from, cut at the frame's edges, in proportion to the noisy `light`
/// there (per pixel, the upper median of the 3×3 pixels around it, plus [`DARK_WEIGHT`]):
/// what each pixel of those rows receives, but never more than that light again (what
/// would be more is dropped). Light a kernel carried from a sun patch into the dark floor
/// beside it goes back to the patch, whose every sample saw the sun; among lit pixels
/// alike it spreads evenly; among pixels whose samples mostly saw nothing (the dark around
/// a night scene's caustic hits) it is dropped; a lone bright pixel (a firefly) weighs as
/// its neighbours do, so the light does not gather into it, and a firefly far brighter than
/// the wall it is on does not light the wall. Where no pixel takes its own light again,
/// every bit taken is shared out (`Σ weight ÷ window's weight` over a window is 1). Exact
/// for rows whose window's windows' medians (2r + 1 rows each side)
/// lie within these rows or beyond the frame's edges; each sum in the same order whatever
/// the rows are, so that bands of a frame receive what the whole frame would, bit for bit.
fn spread(taken: &[Vec<f32>], light: &[f32], w: usize, r: usize, rows: usize) -> [Vec<f32>; 3] {
    let n = w * rows;
    if taken.iter().all(|p| p.iter().all(|&v| v == 0.0)) {
        return std::array::from_fn(|_| vec![0f32; n]);
    }
    // A NaN counts as no light; sums of the weights stay finite.
    let mean: Vec<f32> = light.par_iter().map(|&v| if v > 0.0 { v.min(1e20) } else { 0.0 }).collect();
    let mut weight = vec![0f32; n];
    weight.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        let mut near = Vec::with_capacity(9);
        for (x, o) in out.iter_mut().enumerate() {
            near.clear();
            for yy in y.saturating_sub(1)..(y + 2).min(rows) {
                near.extend_from_slice(&mean[yy * w + x.saturating_sub(1)..yy * w + (x + 2).min(w)]);
            }
            let half = near.len() / 2;
            *o = *near.select_nth_unstable_by(half, f32::total_cmp).1 + DARK_WEIGHT;
        }
    });
    let window_weight = box_sums(&weight, w, r, rows);
    std::array::from_fn(|c| {
        let share: Vec<f32> = taken[c].par_iter().zip(&window_weight).map(|(t, s)| t / s).collect();
        let received = box_sums(&share, w, r, rows);
        // No pixel takes more than its own light again: light that would is dropped.
        received.into_par_iter().zip(&weight).map(|(s, &k)| (s * k).min(k)).collect()
    })
}

/// What a diffuse ceiling took from rows of a band (planes 0–2: `[c][pixel]`), and their
/// noisy light (plane 3: the mean of the channels), both exposed radiance: what [`spread`]
/// shares out, and by.
pub(crate) type Take = BandPlanes<4>;

impl Take {
    /// What it shares out over the window of radius `r` ([`spread`]) to each of its rows.
    pub(crate) fn spread(&self, w: usize, r: usize) -> [Vec<f32>; 3] {
        spread(&self.0[..3], &self.0[3], w, r, self.height(w))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(w: usize, h: usize, seed: u64) -> [Vec<f32>; 3] {
        let mut rng = crate::rng::SplitMix64(seed);
        std::array::from_fn(|_| {
            (0..w * h).map(|_| if rng.uniform_f32() < 0.1 { rng.uniform_f32() * 50.0 } else { 0.0 }).collect()
        })
    }

    fn sum(p: &[f32]) -> f64 {
        p.iter().map(|&v| v as f64).sum()
    }

    #[test]
    fn the_spread_shares_out_every_bit_of_light_it_takes_among_bright_pixels() {
        let (w, h) = (37, 23);
        let taken = frame(w, h, 3);
        // Bright enough everywhere that no pixel would take more than its own light again.
        let light: Vec<f32> = frame(w, h, 4)[0].iter().map(|v| v + 100.0).collect();
        for r in [1, 3, 7] {
            let out = spread(&taken, &light, w, r, h);
            for c in 0..3 {
                let (a, b) = (sum(&taken[c]), sum(&out[c]));
                assert!((a - b).abs() <= 1e-5 * a, "r {r}: {a} taken, {b} shared out");
            }
        }
    }

    #[test]
    fn light_taken_goes_to_the_lit_pixels_around_up_to_their_own_light() {
        let (w, h, r) = (15, 11, 2);
        let near = |v: f32, want: f32| (v - want).abs() <= 1e-4;
        let mut taken: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0f32; w * h]);
        taken[1][5 * w + 7] = 25.0;
        taken[2][0] = 9.0; // a corner: its window is 3×3
        // Evenly over a uniformly lit window.
        let lit = vec![1f32; w * h];
        let out = spread(&taken, &lit, w, r, h);
        for y in 0..h {
            for x in 0..w {
                let inside = x.abs_diff(7) <= r && y.abs_diff(5) <= r;
                assert!(near(out[1][y * w + x], if inside { 1.0 } else { 0.0 }), "({x}, {y}): {}", out[1][y * w + x]);
                assert!(near(out[2][y * w + x], if x <= r && y <= r { 1.0 } else { 0.0 }), "({x}, {y})");
            }
        }
        assert!(out[0].iter().all(|&v| v == 0.0));
        // Among dark pixels (a night scene's caustic hits) nothing: it is dropped.
        let dark = vec![0f32; w * h];
        assert!(spread(&taken, &dark, w, r, h).iter().flatten().all(|&v| v <= DARK_WEIGHT));
        // A lit patch two to the right of dark pixels (sun on the floor) takes its own
        // light again, the dark around it nothing.
        let mut patch = dark.clone();
        for (x, y) in [(9, 4), (9, 5), (9, 6), (10, 4), (10, 5), (10, 6)] {
            patch[y * w + x] = 2.0;
        }
        let out = spread(&taken, &patch, w, r, h);
        assert!(near(out[1][5 * w + 9], 2.0 + DARK_WEIGHT), "{}", out[1][5 * w + 9]);
        assert!(out[1].iter().enumerate().all(|(i, &v)| i == 5 * w + 9 || v <= DARK_WEIGHT));
        // A lone bright pixel (a firefly) on a lit wall takes what its neighbours do.
        let mut lone = lit.clone();
        lone[5 * w + 9] = 2000.0;
        let out = spread(&taken, &lone, w, r, h);
        assert!(near(out[1][5 * w + 9], 1.0), "{}", out[1][5 * w + 9]);
    }

    #[test]
    fn a_band_receives_what_the_whole_frame_does_bit_for_bit() {
        let (w, h, r) = (29, 40, 4usize);
        let [a, b, c] = frame(w, h, 8);
        let whole = Take::from([a, b, c, frame(w, h, 9)[0].clone()]);
        let all = whole.spread(w, r);
        for band in [0..9usize, 9..25, 25..40, 3..4] {
            // Its window's windows' medians: 2r + 1 rows each side.
            let rows = band.start.saturating_sub(2 * r + 1)..(band.end + 2 * r + 1).min(h);
            let out = whole.rows(rows.clone(), w).spread(w, r);
            for c in 0..3 {
                let (a, b) = (band.start - rows.start, band.end - rows.start);
                assert_eq!(out[c][a * w..b * w], all[c][band.start * w..band.end * w], "{band:?}");
            }
        }
        let (top, bottom) = (whole.rows(0..20, w), whole.rows(20..40, w));
        assert_eq!(top.then(&bottom).spread(w, r), all);
    }
}
