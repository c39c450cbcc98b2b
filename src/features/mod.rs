//! Preprocessing (SPEC §4): from the renderer's buffers to the 27-channel network input of
//! each branch.
//!
//! Per branch, in this order: `[c̃ 3][Gx of (c̃ 3, normal 3, albedo 3, depth 1)][Gy of the
//! same 10][σ̃²_c 1][σ²_normal 1, σ²_albedo 1, σ²_depth 1]`, where c̃ is the demodulated
//! diffuse `d̃ = diffuse / (albedo + ε)` or the log specular `s̃ = ln(1 + max(specular, 0))`.

use crate::io::layout::KpcnInputs;

/// The paper's ε, used in albedo demodulation and recomposition.
pub const EPSILON: f32 = 0.00316;
/// Channels of one branch's input.
pub const INPUT_CHANNELS: usize = 27;
/// The input layout's name, recorded in model files.
pub const INPUT_LAYOUT: &str = "kpcn27-v1";
/// Magnitude every input sample is clamped to after NaN/Inf removal. Far above physical
/// render values, low enough that products and squares of inputs stay finite in f32.
pub const MAX_MAGNITUDE: f32 = 1e15;

/// Network inputs of one frame (CHW planes, `width * height` each).
#[derive(Debug, Clone, PartialEq)]
pub struct Features {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// 27 planes for the diffuse branch.
    pub diffuse: Vec<Vec<f32>>,
    /// 27 planes for the specular branch.
    pub specular: Vec<Vec<f32>>,
    /// The noisy albedo (sanitised), for recomposition.
    pub albedo: [Vec<f32>; 3],
}

/// NaN and ±Inf become 0 (never float max: it poisons squares); then a magnitude clamp.
pub fn sanitize(v: f32) -> f32 {
    if v.is_finite() { v.clamp(-MAX_MAGNITUDE, MAX_MAGNITUDE) } else { 0.0 }
}

fn clean(p: &[f32]) -> Vec<f32> {
    p.iter().map(|&v| sanitize(v)).collect()
}

fn clean3(p: &[Vec<f32>; 3]) -> [Vec<f32>; 3] {
    [clean(&p[0]), clean(&p[1]), clean(&p[2])]
}

/// A variance: sanitised and never negative.
fn clean_variance(p: &[f32]) -> Vec<f32> {
    p.iter().map(|&v| sanitize(v).max(0.0)).collect()
}

/// Backward differences `I[x] − I[x−1]` (0 in the first column) and `I[y] − I[y−1]`.
pub fn gradients(p: &[f32], w: usize, h: usize) -> (Vec<f32>, Vec<f32>) {
    let mut gx = vec![0f32; w * h];
    let mut gy = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if x > 0 {
                gx[i] = p[i] - p[i - 1];
            }
            if y > 0 {
                gy[i] = p[i] - p[i - w];
            }
        }
    }
    (gx, gy)
}

/// Demodulated diffuse `diffuse / (albedo + ε)`.
pub fn demodulate(diffuse: &[f32], albedo: &[f32]) -> Vec<f32> {
    diffuse.iter().zip(albedo).map(|(d, a)| d / (a + EPSILON)).collect()
}

/// Log specular `ln(1 + max(s, 0))`.
pub fn log_specular(s: &[f32]) -> Vec<f32> {
    s.iter().map(|&v| v.max(0.0).ln_1p()).collect()
}

impl Features {
    /// Preprocesses one frame.
    pub fn new(k: &KpcnInputs) -> Features {
        let (w, h) = (k.width, k.height);
        let n = w * h;
        // Reflectance is never negative; clamping also keeps albedo + ε away from 0.
        let albedo = clean3(&k.albedo).map(|p| p.into_iter().map(|a| a.max(0.0)).collect::<Vec<f32>>());
        let normal = clean3(&k.normal);
        let diffuse = clean3(&k.diffuse);
        let specular = clean3(&k.specular);

        // Depth: non-finite → 0, ≥ 0, divided by the frame's largest finite depth.
        let depth_raw = clean(&k.depth);
        let max_depth = depth_raw.iter().fold(0f32, |m, &d| m.max(d));
        let scale = if max_depth > 0.0 { 1.0 / max_depth } else { 0.0 };
        let depth: Vec<f32> = depth_raw.iter().map(|&d| d.max(0.0) * scale).collect();
        let depth_variance: Vec<f32> = clean_variance(&k.depth_variance)
            .iter()
            .map(|&v| sanitize((v as f64 * (scale as f64).powi(2)) as f32))
            .collect();

        let d_tilde: [Vec<f32>; 3] = std::array::from_fn(|c| demodulate(&diffuse[c], &albedo[c]));
        let s_tilde: [Vec<f32>; 3] = std::array::from_fn(|c| log_specular(&specular[c]));
        let d_var = clean_variance(&k.diffuse_variance);
        let s_var = clean_variance(&k.specular_variance);
        // Variance divisions in f64, results sanitised back to the f32 range.
        let d_var_tilde: Vec<f32> = (0..n)
            .map(|i| {
                let a = (albedo[0][i] + albedo[1][i] + albedo[2][i]) as f64 / 3.0 + EPSILON as f64;
                sanitize((d_var[i] as f64 / (a * a)) as f32)
            })
            .collect();
        // Delta method for ln(1 + s): σ² / (1 + s)², with the mean of (1 + s) over RGB.
        let s_var_tilde: Vec<f32> = (0..n)
            .map(|i| {
                let m = 1.0 + (0..3).map(|c| specular[c][i].max(0.0) as f64).sum::<f64>() / 3.0;
                sanitize((s_var[i] as f64 / (m * m)) as f32)
            })
            .collect();

        let aux_variances = [clean_variance(&k.normal_variance), clean_variance(&k.albedo_variance), depth_variance];
        let branch = |c_tilde: &[Vec<f32>; 3], c_var: Vec<f32>| -> Vec<Vec<f32>> {
            let guides: Vec<&[f32]> = c_tilde
                .iter()
                .chain(&normal)
                .chain(&albedo)
                .map(Vec::as_slice)
                .chain(std::iter::once(depth.as_slice()))
                .collect();
            let (gx, gy): (Vec<Vec<f32>>, Vec<Vec<f32>>) =
                guides.iter().map(|g| gradients(g, w, h)).map(|(x, y)| (clean(&x), clean(&y))).unzip();
            let mut planes: Vec<Vec<f32>> = c_tilde.to_vec();
            planes.extend(gx);
            planes.extend(gy);
            planes.push(c_var);
            planes.extend(aux_variances.iter().cloned());
            debug_assert_eq!(planes.len(), INPUT_CHANNELS);
            planes
        };
        Features {
            width: w,
            height: h,
            diffuse: branch(&d_tilde, d_var_tilde),
            specular: branch(&s_tilde, s_var_tilde),
            albedo,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn preprocessing_matches_hand_computed_values() {
        // A constant frame: every value is its hand-computed transform, gradients are 0.
        let f = Features::new(&inputs(3, 2, |_| 0.0));
        let d = &f.diffuse;
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
        let s = &f.specular;
        assert!((s[1][0] - 1.5f32.ln()).abs() < 1e-6);
        assert!((s[2][0] - 2f32.ln()).abs() < 1e-6);
        let m = 1.0 + (0.0 + 0.5 + 1.0) / 3.0;
        assert!((s[23][0] - (0.04 / (m * m)) as f32).abs() < 1e-6);
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
        let gx_depth = &f.diffuse[12];
        assert_eq!(gx_depth, &vec![0.0, -0.25, 0.0, 1.0]);
    }

    #[test]
    fn hostile_values_become_finite() {
        let mut k = inputs(2, 2, |_| 0.0);
        k.diffuse[0] = vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e30];
        k.albedo[0] = vec![0.0, -1.0, f32::MAX, 0.0];
        k.diffuse_variance = vec![f32::INFINITY, 1e38, -5.0, f32::NAN];
        let f = Features::new(&k);
        for p in f.diffuse.iter().chain(&f.specular) {
            assert!(p.iter().all(|v| v.is_finite()), "{p:?}");
        }
    }
}
