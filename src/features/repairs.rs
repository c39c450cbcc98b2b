//! What preprocessing repairs in a frame's inputs, counted for the user.

use super::MAX_MAGNITUDE;
use crate::io::layout::KpcnInputs;

/// Samples of one input that preprocessing had to repair.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Repairs {
    /// NaN or ±Inf, replaced by 0.
    pub nonfinite: usize,
    /// Finite but outside the input's physical range, clamped into it.
    pub out_of_range: usize,
}

/// What [`super::Features`] repairs in each input, counted over rows `rows` of `k` (the inner rows
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
