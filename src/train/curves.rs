//! Training curves from `log.csv`: losses (smoothed) and validation relMSE against step,
//! as a [`Chart`] for [`crate::eval::plot::write_png`].

use crate::eval::plot::{Chart, Series};

/// Steps averaged for a smoothed loss curve: per-step losses of small batches are noisy.
const SMOOTHING: usize = 25;

/// One run's log, by column.
#[derive(Debug, Clone, Default)]
pub struct Log {
    /// (step, diffuse loss) in phase 1.
    pub diffuse: Vec<(f64, f64)>,
    /// (step, specular loss) in phase 1.
    pub specular: Vec<(f64, f64)>,
    /// (step, combined loss) in phase 2.
    pub combined: Vec<(f64, f64)>,
    /// (step, mean validation relMSE).
    pub validation: Vec<(f64, f64)>,
    /// (step, median validation relMSE); absent in logs from before it was logged.
    pub validation_median: Vec<(f64, f64)>,
    /// (step, geometric-mean relMSE of the `--dev` check set), when one was given.
    pub dev: Vec<(f64, f64)>,
}

/// A `kpcn train` log's columns (see [`super::records::LogRow`]); malformed rows are
/// skipped.
pub fn parse(text: &str) -> Log {
    let mut log = Log::default();
    let finite = |v: f64| v.is_finite().then_some(v);
    for r in super::records::read_log(text) {
        let step = r.step as f64;
        let columns = [
            (finite(r.loss_diffuse), &mut log.diffuse),
            (finite(r.loss_specular), &mut log.specular),
            (finite(r.loss_combined), &mut log.combined),
            (r.validation_relmse, &mut log.validation),
            (r.validation_median_relmse, &mut log.validation_median),
            (r.dev_relmse, &mut log.dev),
        ];
        for (v, out) in columns {
            if let Some(v) = v {
                out.push((step, v));
            }
        }
    }
    log
}

/// Running mean over `n` points (centred on the last), keeping the steps.
fn smooth(p: &[(f64, f64)], n: usize) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(p.len() / n + 1);
    for chunk in p.chunks(n) {
        let mean = chunk.iter().map(|q| q.1).sum::<f64>() / chunk.len() as f64;
        out.push((chunk[chunk.len() - 1].0, mean));
    }
    out
}

/// A chart of one or more named runs. With several runs only validation relMSE is drawn
/// (the comparable quantity); a single run also shows its smoothed losses.
pub fn chart(runs: &[(String, Log)]) -> Chart {
    let mut series = Vec::new();
    for (name, log) in runs {
        let prefix = if runs.len() > 1 { format!("{name}: ") } else { String::new() };
        // The median when logged: a single outlier frame dominates the mean.
        let (what, points) = if log.validation_median.is_empty() {
            ("validation relMSE (mean)", &log.validation)
        } else {
            ("validation relMSE (median)", &log.validation_median)
        };
        series.push(Series { name: format!("{prefix}{what}"), points: points.clone(), dashed: false });
        if !log.dev.is_empty() {
            let name = format!("{prefix}dev set relMSE (geometric mean)");
            series.push(Series { name, points: log.dev.clone(), dashed: false });
        }
        if runs.len() == 1 {
            for (what, p) in [("diffuse", &log.diffuse), ("specular", &log.specular), ("combined", &log.combined)] {
                if !p.is_empty() {
                    let name = format!("{what} L1 (mean of {SMOOTHING} steps)");
                    series.push(Series { name, points: smooth(p, SMOOTHING), dashed: true });
                }
            }
        }
    }
    let title = match runs {
        [(name, _)] => format!("kpcn train: {name}"),
        _ => "kpcn train: validation relMSE by step".to_string(),
    };
    Chart { title, x_label: "step".into(), y_label: "loss / relMSE".into(), log_x: false, log_y: true, series }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logs_parse_by_column_and_smooth() {
        let text = "step,phase,loss_diffuse,loss_specular,loss_combined,validation_relmse,patches_per_second\n\
                    1,1,0.5,0.1,,,2.0\n2,1,0.3,0.1,,0.04,2.0,0.02\nbad row\n3,2,,,0.2,0.03,2.0,0.01\n";
        let log = parse(text);
        assert_eq!(log.diffuse, vec![(1.0, 0.5), (2.0, 0.3)]);
        assert_eq!(log.combined, vec![(3.0, 0.2)]);
        assert_eq!(log.validation, vec![(2.0, 0.04), (3.0, 0.03)]);
        assert_eq!(log.validation_median, vec![(2.0, 0.02), (3.0, 0.01)]);
        assert_eq!(smooth(&log.diffuse, 2), vec![(2.0, 0.4)]);
        assert_eq!(chart(&[("a".into(), log.clone())]).series.len(), 4);
        assert_eq!(chart(&[("a".into(), log.clone()), ("b".into(), log)]).series.len(), 2);
    }
}
