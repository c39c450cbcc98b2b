//! The accuracy-vs-time study ("what accuracy costs in time"): for each scene, error against
//! the reference and total seconds (render + denoise) per sample count and method; from
//! those, the time each method needs to reach a given error and its speed-up over plain
//! Monte Carlo at equal error. `kpcn study` gathers the rows; this module does the sums.

use super::plot::{Chart, Series};
use std::fmt::Write as _;

/// The method name of the undenoised renders.
pub const MONTE_CARLO: &str = "monte-carlo";

/// One measurement: a scene rendered at `spp`, denoised by `method` (or not).
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Scene name.
    pub scene: String,
    /// Samples per pixel of the render.
    pub spp: u32,
    /// [`MONTE_CARLO`], a model name, or `oidn`.
    pub method: String,
    /// Seconds to render the noisy frame.
    pub render_seconds: f64,
    /// Seconds to denoise it (0 for Monte Carlo).
    pub denoise_seconds: f64,
    /// relMSE against the reference.
    pub relmse: f64,
    /// PSNR, dB.
    pub psnr: f64,
    /// 1 − SSIM.
    pub one_minus_ssim: f64,
}

impl Row {
    /// Render + denoise seconds.
    pub fn total_seconds(&self) -> f64 {
        self.render_seconds + self.denoise_seconds
    }
}

/// The CSV header of [`to_csv`].
pub const CSV_HEADER: &str = "scene,spp,method,render_seconds,denoise_seconds,total_seconds,relmse,psnr,one_minus_ssim";

/// All rows as CSV.
pub fn to_csv(rows: &[Row]) -> String {
    let mut s = format!("{CSV_HEADER}\n");
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{:.4},{:.4},{:.4},{:.6},{:.3},{:.5}",
            r.scene,
            r.spp,
            r.method,
            r.render_seconds,
            r.denoise_seconds,
            r.total_seconds(),
            r.relmse,
            r.psnr,
            r.one_minus_ssim
        );
    }
    s
}

/// When a method's curve reaches an error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reach {
    /// Reached at about this many seconds (log–log interpolation between measurements).
    At(f64),
    /// Already below the target at its cheapest measurement, this many seconds.
    By(f64),
    /// Never reached within the measured sample counts.
    Never,
}

/// Time at which the error curve `points` (seconds, error) first falls to `target`.
pub fn time_to_reach(points: &[(f64, f64)], target: f64) -> Reach {
    let mut p: Vec<(f64, f64)> = points.iter().copied().filter(|(t, e)| *t > 0.0 && *e > 0.0).collect();
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    match p.first() {
        None => return Reach::Never,
        Some(&(t, e)) if e <= target => return Reach::By(t),
        _ => {}
    }
    for w in p.windows(2) {
        let ((t0, e0), (t1, e1)) = (w[0], w[1]);
        if e1 <= target {
            if e0 == e1 {
                return Reach::At(t1);
            }
            let f = (target.ln() - e0.ln()) / (e1.ln() - e0.ln());
            return Reach::At((t0.ln() + f * (t1.ln() - t0.ln())).exp());
        }
    }
    Reach::Never
}

/// Methods in first-appearance order, Monte Carlo first.
fn methods(rows: &[Row]) -> Vec<String> {
    let mut m = vec![MONTE_CARLO.to_string()];
    for r in rows {
        if !m.contains(&r.method) {
            m.push(r.method.clone());
        }
    }
    m
}

fn scenes(rows: &[Row]) -> Vec<String> {
    let mut s: Vec<String> = Vec::new();
    for r in rows {
        if !s.contains(&r.scene) {
            s.push(r.scene.clone());
        }
    }
    s
}

fn curve(rows: &[Row], scene: &str, method: &str) -> Vec<(f64, f64)> {
    let mut c: Vec<(f64, f64)> =
        rows.iter().filter(|r| r.scene == scene && r.method == method).map(|r| (r.total_seconds(), r.relmse)).collect();
    c.sort_by(|a, b| a.0.total_cmp(&b.0));
    c
}

/// One chart per scene: relMSE against total seconds, log–log, a curve per method.
pub fn charts(rows: &[Row]) -> Vec<(String, Chart)> {
    scenes(rows)
        .into_iter()
        .map(|scene| {
            let series = methods(rows)
                .iter()
                .map(|m| Series { name: m.clone(), points: curve(rows, &scene, m), dashed: m == MONTE_CARLO })
                .filter(|s| !s.points.is_empty())
                .collect();
            let chart = Chart {
                title: format!("{scene}: error vs time (render + denoise)"),
                x_label: "total seconds (2 threads)".into(),
                y_label: "relMSE".into(),
                log_x: true,
                log_y: true,
                series,
            };
            (scene, chart)
        })
        .collect()
}

/// What one method costs per frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Cost {
    /// Method name.
    pub method: String,
    /// Network FLOP per pixel (`None` where unknown, e.g. OIDN).
    pub flop_per_pixel: Option<f64>,
    /// Denoise seconds per megapixel, mean over the study's frames.
    pub seconds_per_mpix: f64,
    /// Peak resident memory of a whole `kpcn denoise` (or OIDN) process, MB.
    pub peak_mb: Option<f64>,
}

fn fmt_reach(r: Reach) -> String {
    match r {
        Reach::At(t) => format!("{t:.2} s"),
        Reach::By(t) => format!("≤ {t:.2} s"),
        Reach::Never => "not reached".into(),
    }
}

/// The markdown summary: per scene, the target error (plain Monte Carlo's error at its
/// highest sample count), each method's time to reach it and the speed-up over Monte
/// Carlo; then each method's cost.
pub fn summary(rows: &[Row], costs: &[Cost]) -> String {
    let mut s = String::from("# Accuracy vs time\n\n");
    s.push_str(
        "Target error per scene: plain Monte Carlo's relMSE at its highest sample count. Time to reach it is \
         interpolated log–log between measured sample counts; `≤` means the method is already below the target at \
         its cheapest measurement (so the speed-up is at least the figure shown).\n\n",
    );
    let methods = methods(rows);
    s.push_str("| scene | target relMSE |");
    for m in &methods {
        let _ = write!(s, " {m} |");
    }
    s.push_str("\n|---|---|");
    s.push_str(&"---|".repeat(methods.len()));
    s.push('\n');
    for scene in scenes(rows) {
        let mc = curve(rows, &scene, MONTE_CARLO);
        let Some(&(mc_time, target)) = mc.last() else { continue };
        let _ = write!(s, "| {scene} | {target:.5} |");
        for m in &methods {
            let reach = time_to_reach(&curve(rows, &scene, m), target);
            let speedup = match reach {
                Reach::At(t) => format!(" ({:.1}×)", mc_time / t),
                Reach::By(t) => format!(" (≥ {:.1}×)", mc_time / t),
                Reach::Never => String::new(),
            };
            let _ = write!(s, " {}{} |", fmt_reach(reach), if m == MONTE_CARLO { String::new() } else { speedup });
        }
        s.push('\n');
    }
    s.push_str("\n| method | FLOP / pixel | s / MPix (denoise) | peak RSS |\n|---|---|---|---|\n");
    for c in costs {
        let flop = c.flop_per_pixel.map_or("—".into(), |f| format!("{:.0} k", f / 1e3));
        let mem = c.peak_mb.map_or("—".into(), |m| format!("{m:.0} MB"));
        let _ = writeln!(s, "| {} | {flop} | {:.2} | {mem} |", c.method, c.seconds_per_mpix);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(scene: &str, spp: u32, method: &str, render: f64, denoise: f64, relmse: f64) -> Row {
        Row {
            scene: scene.into(),
            spp,
            method: method.into(),
            render_seconds: render,
            denoise_seconds: denoise,
            relmse,
            psnr: 0.0,
            one_minus_ssim: 0.0,
        }
    }

    #[test]
    fn time_to_reach_interpolates_log_log() {
        // Error ∝ 1/t: halfway (in log) between 1 s and 4 s for the error in between.
        let c = [(1.0, 1.0), (4.0, 0.25), (16.0, 0.0625)];
        match time_to_reach(&c, 0.5) {
            Reach::At(t) => assert!((t - 2.0).abs() < 1e-9, "{t}"),
            r => panic!("{r:?}"),
        }
        assert_eq!(time_to_reach(&c, 2.0), Reach::By(1.0));
        assert_eq!(time_to_reach(&c, 0.01), Reach::Never);
        assert_eq!(time_to_reach(&[], 0.1), Reach::Never);
    }

    #[test]
    fn summary_reports_speedups_at_equal_error() {
        let rows = vec![
            row("a", 4, MONTE_CARLO, 1.0, 0.0, 0.4),
            row("a", 16, MONTE_CARLO, 4.0, 0.0, 0.1),
            row("a", 4, "kpcn", 1.0, 1.0, 0.2),
            row("a", 16, "kpcn", 4.0, 1.0, 0.05),
            row("a", 4, "oidn", 1.0, 0.5, 0.05),
        ];
        let md = summary(
            &rows,
            &[Cost { method: "kpcn".into(), flop_per_pixel: Some(319e3), seconds_per_mpix: 2.5, peak_mb: None }],
        );
        // kpcn reaches 0.1 between 2 s (0.2) and 5 s (0.05): at sqrt(10) s ≈ 3.16 s → 1.3×.
        assert!(md.contains("3.16 s (1.3×)"), "{md}");
        assert!(md.contains("≤ 1.50 s (≥ 2.7×)"), "{md}");
        assert!(md.contains("| kpcn | 319 k | 2.50 | — |"), "{md}");
        let csv = to_csv(&rows);
        assert_eq!(csv.lines().count(), 6);
        assert!(csv.lines().nth(3).unwrap().starts_with("a,4,kpcn,1.0000,1.0000,2.0000,0.200000"));
        let charts = charts(&rows);
        assert_eq!(charts.len(), 1);
        assert_eq!(charts[0].1.series.len(), 3);
        assert!(charts[0].1.series[0].dashed);
    }
}
