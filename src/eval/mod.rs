//! Error metrics (ARCHITECTURE.md §Metrics), with the conventions of the team's Cycles baseline so numbers
//! compare: relMSE on linear values; PSNR and SSIM on `T(v) = clamp((v/(1+v))^(1/2.2), 0, 1)`
//! with `v ≥ 0`; SSIM per RGB channel with an 11×11 Gaussian window (σ 1.5), K1 0.01,
//! K2 0.03, over the valid region, averaged.

pub mod plot;
pub mod study;

/// RGB planes of one image.
pub type Rgb<'a> = [&'a [f32]; 3];

/// Borrows owned RGB planes as [`Rgb`].
pub fn rgb(p: &[Vec<f32>; 3]) -> Rgb<'_> {
    [&p[0], &p[1], &p[2]]
}

/// The metrics of one image against its reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metrics {
    /// Mean of `(x − y)² / (y² + 0.01)` over pixels and channels.
    pub relmse: f64,
    /// PSNR of the tonemapped images, dB (infinite when identical).
    pub psnr: f64,
    /// 1 − SSIM of the tonemapped images.
    pub one_minus_ssim: f64,
    /// relMSE with the image's own worst [`TRIMMED`] shares of pixels dropped (per-pixel
    /// relMSE, RGB mean, ranked): outliers and bulk seen apart.
    pub relmse_trimmed: [f64; 2],
    /// The image's mean over the reference's (RGB, every pixel): light kept or lost as a
    /// whole, which relMSE forgives (light missing from a bright pixel costs less than the
    /// same light put in a dark one).
    pub brightness: f64,
}

/// The shares of worst pixels [`Metrics::relmse_trimmed`] drops: 0.1 % and 1 %.
pub const TRIMMED: [f64; 2] = [0.001, 0.01];

/// relMSE without the worst `share` of pixels by per-pixel relMSE ([`relmse_map`]).
pub fn relmse_trimmed(x: Rgb, y: Rgb, share: f64) -> f64 {
    let mut e = relmse_map(x, y);
    let keep = e.len() - ((e.len() as f64 * share).ceil() as usize).min(e.len());
    if keep == 0 {
        return 0.0;
    }
    e.select_nth_unstable_by(keep - 1, f32::total_cmp);
    e[..keep].iter().map(|&v| v as f64).sum::<f64>() / keep as f64
}

/// Mean of `(x − y)² / (y² + 0.01)`; non-finite samples of `x` count as 0.
pub fn relmse(x: Rgb, y: Rgb) -> f64 {
    let mut sum = 0f64;
    let mut n = 0usize;
    for c in 0..3 {
        for (&a, &b) in x[c].iter().zip(y[c]) {
            let a = if a.is_finite() { a as f64 } else { 0.0 };
            let b = b as f64;
            sum += (a - b) * (a - b) / (b * b + 0.01);
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// The mean of `x` over the mean of `y` (RGB, every pixel; non-finite samples of `x` count
/// as 0, as in [`relmse`]); 1 where `y` is black and `x` is too, infinite where only `y` is.
pub fn brightness(x: Rgb, y: Rgb) -> f64 {
    let sum = |p: Rgb, finite_only: bool| -> f64 {
        p.iter().flat_map(|c| c.iter()).map(|&v| if finite_only && !v.is_finite() { 0.0 } else { v as f64 }).sum()
    };
    let (a, b) = (sum(x, true), sum(y, false));
    if a == b { 1.0 } else { a / b }
}

/// The display transform of the baseline: Reinhard, gamma 2.2, clamped.
pub fn tonemap(v: f32) -> f64 {
    let v = if v.is_finite() { (v as f64).max(0.0) } else { 0.0 };
    (v / (1.0 + v)).powf(1.0 / 2.2).clamp(0.0, 1.0)
}

/// PSNR (dB) of tonemapped images, peak 1.
pub fn psnr(x: Rgb, y: Rgb) -> f64 {
    let mut sum = 0f64;
    let mut n = 0usize;
    for c in 0..3 {
        for (&a, &b) in x[c].iter().zip(y[c]) {
            let d = tonemap(a) - tonemap(b);
            sum += d * d;
            n += 1;
        }
    }
    let mse = sum / n.max(1) as f64;
    if mse == 0.0 { f64::INFINITY } else { 10.0 * (1.0 / mse).log10() }
}

fn gaussian_window() -> [f64; 11] {
    let mut g = [0f64; 11];
    for (i, v) in g.iter_mut().enumerate() {
        let d = i as f64 - 5.0;
        *v = (-d * d / (2.0 * 1.5 * 1.5)).exp();
    }
    let s: f64 = g.iter().sum();
    g.map(|v| v / s)
}

/// Separable valid-region filtering of `p` (`w`×`h`) with the 11-tap window.
fn filter_valid(p: &[f64], w: usize, h: usize, g: &[f64; 11]) -> (Vec<f64>, usize, usize) {
    let (ow, oh) = (w - 10, h - 10);
    let mut rows = vec![0f64; ow * h];
    for y in 0..h {
        for x in 0..ow {
            rows[y * ow + x] = (0..11).map(|k| g[k] * p[y * w + x + k]).sum();
        }
    }
    let mut out = vec![0f64; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..11).map(|k| g[k] * rows[(y + k) * ow + x]).sum();
        }
    }
    (out, ow, oh)
}

/// Mean SSIM of one tonemapped channel; `None` when the image is smaller than the window.
pub fn ssim_channel(x: &[f32], y: &[f32], w: usize, h: usize) -> Option<f64> {
    if w < 11 || h < 11 {
        return None;
    }
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let g = gaussian_window();
    let tx: Vec<f64> = x.iter().map(|&v| tonemap(v)).collect();
    let ty: Vec<f64> = y.iter().map(|&v| tonemap(v)).collect();
    let prod = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(a, b)| a * b).collect::<Vec<f64>>();
    let (mx, ow, oh) = filter_valid(&tx, w, h, &g);
    let (my, ..) = filter_valid(&ty, w, h, &g);
    let (sxx, ..) = filter_valid(&prod(&tx, &tx), w, h, &g);
    let (syy, ..) = filter_valid(&prod(&ty, &ty), w, h, &g);
    let (sxy, ..) = filter_valid(&prod(&tx, &ty), w, h, &g);
    let mut sum = 0f64;
    for i in 0..ow * oh {
        let (a, b) = (mx[i], my[i]);
        let (vx, vy, cxy) = (sxx[i] - a * a, syy[i] - b * b, sxy[i] - a * b);
        sum += (2.0 * a * b + c1) * (2.0 * cxy + c2) / ((a * a + b * b + c1) * (vx + vy + c2));
    }
    Some(sum / (ow * oh) as f64)
}

/// All three metrics. SSIM needs at least 11×11 pixels (else it is reported as NaN).
pub fn metrics(x: Rgb, y: Rgb, w: usize, h: usize) -> Metrics {
    let ssim: Option<Vec<f64>> = (0..3).map(|c| ssim_channel(x[c], y[c], w, h)).collect();
    Metrics {
        relmse: relmse(x, y),
        psnr: psnr(x, y),
        one_minus_ssim: ssim.map_or(f64::NAN, |s| 1.0 - s.iter().sum::<f64>() / 3.0),
        relmse_trimmed: TRIMMED.map(|share| relmse_trimmed(x, y, share)),
        brightness: brightness(x, y),
    }
}

/// Per-pixel relMSE (mean over RGB), for error maps.
pub fn relmse_map(x: Rgb, y: Rgb) -> Vec<f32> {
    (0..x[0].len())
        .map(|i| {
            let s: f64 = (0..3)
                .map(|c| {
                    let a = if x[c][i].is_finite() { x[c][i] as f64 } else { 0.0 };
                    let b = y[c][i] as f64;
                    (a - b) * (a - b) / (b * b + 0.01)
                })
                .sum();
            (s / 3.0) as f32
        })
        .collect()
}

/// False colour for an error map: log10 error from 1e-4 (black) through blue, red and
/// yellow to 1 and above (white).
pub fn false_colour(e: f32) -> [u8; 3] {
    let t = ((e.max(1e-12).log10() + 4.0) / 4.0).clamp(0.0, 1.0);
    let stops = [[0.0, 0.0, 0.0], [0.1, 0.1, 0.8], [0.9, 0.1, 0.1], [1.0, 0.9, 0.1], [1.0, 1.0, 1.0]];
    let s = t * 4.0;
    let i = (s as usize).min(3);
    let f = s - i as f32;
    std::array::from_fn(|c| (255.0 * (stops[i][c] * (1.0 - f) + stops[i + 1][c] * f)).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rgb(v: &[f32]) -> [Vec<f32>; 3] {
        [v.to_vec(), v.to_vec(), v.to_vec()]
    }

    fn view(p: &[Vec<f32>; 3]) -> Rgb<'_> {
        [&p[0], &p[1], &p[2]]
    }

    #[test]
    fn relmse_matches_hand_computation() {
        let (x, y) = (rgb(&[1.0, 2.0]), rgb(&[0.0, 1.0]));
        // (1 − 0)² / 0.01 = 100 and (2 − 1)² / 1.01 per channel; the mean of the two.
        let expect = (100.0 + 1.0 / 1.01) / 2.0;
        assert!((relmse(view(&x), view(&y)) - expect).abs() < 1e-9);
        assert_eq!(relmse(view(&y), view(&y)), 0.0);
    }

    #[test]
    fn brightness_is_the_ratio_of_means() {
        let (x, y) = (rgb(&[1.0, 2.0]), rgb(&[3.0, 3.0]));
        assert!((brightness(view(&x), view(&y)) - 0.5).abs() < 1e-12);
        // A non-finite sample counts as black, as in relMSE; black against black is 1.
        let nan = rgb(&[f32::NAN, 3.0]);
        assert!((brightness(view(&nan), view(&y)) - 0.5).abs() < 1e-12);
        let black = rgb(&[0.0, 0.0]);
        assert_eq!(brightness(view(&black), view(&black)), 1.0);
        assert_eq!(brightness(view(&x), view(&black)), f64::INFINITY);
    }

    #[test]
    fn trimming_drops_the_worst_pixels_only() {
        // 1000 pixels: 999 with error 1 / 1.01 and one firefly of error 100 (at 0).
        let mut xv = vec![2.0f32; 1000];
        let mut yv = vec![1.0f32; 1000];
        xv[7] = 1.0;
        yv[7] = 0.0;
        let (x, y) = (rgb(&xv), rgb(&yv));
        let all = relmse(view(&x), view(&y));
        let trimmed = relmse_trimmed(view(&x), view(&y), 0.001);
        assert!((all - (999.0 / 1.01 + 100.0) / 1000.0).abs() < 1e-9);
        assert!((trimmed - 1.0 / 1.01).abs() < 1e-6, "{trimmed}");
        assert!((relmse_trimmed(view(&x), view(&y), 0.0) - all).abs() < 1e-6);
    }

    #[test]
    fn psnr_matches_hand_computation() {
        // T(1) = 0.5^(1/2.2), T(0) = 0: MSE = T(1)², PSNR = −20 log10 T(1).
        let (x, y) = (rgb(&[1.0]), rgb(&[0.0]));
        let t1 = 0.5f64.powf(1.0 / 2.2);
        assert!((psnr(view(&x), view(&y)) - (-20.0 * t1.log10())).abs() < 1e-9);
        assert_eq!(psnr(view(&x), view(&x)), f64::INFINITY);
    }

    #[test]
    fn ssim_of_constant_images_matches_the_formula() {
        let (w, h) = (13, 12);
        let (a, b) = (0.25f32, 1.0f32);
        let (x, y) = (vec![a; w * h], vec![b; w * h]);
        let (ta, tb) = (tonemap(a), tonemap(b));
        let c1 = 1e-4;
        // Zero variance: SSIM = (2 μx μy + C1) / (μx² + μy² + C1).
        let expect = (2.0 * ta * tb + c1) / (ta * ta + tb * tb + c1);
        assert!((ssim_channel(&x, &y, w, h).unwrap() - expect).abs() < 1e-9);
        assert!((ssim_channel(&x, &x, w, h).unwrap() - 1.0).abs() < 1e-12);
        assert!(ssim_channel(&x[..100], &y[..100], 10, 10).is_none());
    }

    #[test]
    fn false_colour_runs_from_black_to_white() {
        assert_eq!(false_colour(0.0), [0, 0, 0]);
        assert_eq!(false_colour(10.0), [255, 255, 255]);
        assert_eq!(false_colour(f32::NAN), [0, 0, 0]);
    }
}
