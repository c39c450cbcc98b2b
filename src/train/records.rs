//! The training CSV files, typed, each with its one writer and reader: `manifest.csv`
//! (written by `kpcn dataset`, read by the trainer) and `log.csv` (written by `kpcn train`,
//! read back on `--resume` and by the curves).

use std::path::{Path, PathBuf};

/// Columns of `manifest.csv`.
pub const MANIFEST_HEADER: &str = "scene,family,seed,sample_seed,spp,file,reference,render_seconds";

/// One noisy frame of a dataset and its reference.
#[derive(Debug, Clone, PartialEq)]
pub struct ManifestRow {
    /// Scene name (its folder).
    pub scene: String,
    /// Scene family.
    pub family: String,
    /// Permutation seed.
    pub seed: u64,
    /// Monte Carlo stream.
    pub sample_seed: u64,
    /// Samples per pixel of the noisy frame.
    pub spp: u32,
    /// The noisy frame, relative to the dataset folder.
    pub file: String,
    /// Its reference, relative to the dataset folder.
    pub reference: String,
    /// Seconds the scene's noisy frames took to render.
    pub render_seconds: f64,
}

impl ManifestRow {
    /// The CSV line (no newline). Paths must not contain commas; dataset names never do.
    pub fn to_line(&self) -> String {
        format!(
            "{},{},{},{},{},{},{},{:.3}",
            self.scene,
            self.family,
            self.seed,
            self.sample_seed,
            self.spp,
            self.file,
            self.reference,
            self.render_seconds
        )
    }

    /// Parses one line; `None` when a column is missing or malformed.
    pub fn parse(line: &str) -> Option<ManifestRow> {
        let c: Vec<&str> = line.split(',').collect();
        let [scene, family, seed, sample_seed, spp, file, reference, seconds] = c.as_slice() else { return None };
        Some(ManifestRow {
            scene: scene.to_string(),
            family: family.to_string(),
            seed: seed.parse().ok()?,
            sample_seed: sample_seed.parse().ok()?,
            spp: spp.parse().ok()?,
            file: file.to_string(),
            reference: reference.to_string(),
            render_seconds: seconds.parse().ok()?,
        })
    }
}

/// Why a CSV file could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{}: {msg}", path.display())]
pub struct CsvError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong, with the line number.
    pub msg: String,
}

/// Writes a whole manifest, atomically (an interrupted dataset run keeps a valid one).
pub fn write_manifest(path: &Path, rows: &[ManifestRow]) -> Result<(), CsvError> {
    let text: String = std::iter::once(MANIFEST_HEADER.to_string()).chain(rows.iter().map(ManifestRow::to_line)).fold(
        String::new(),
        |mut s, l| {
            s.push_str(&l);
            s.push('\n');
            s
        },
    );
    crate::io::atomic::write_atomically(path, text.as_bytes())
        .map_err(|e| CsvError { path: path.into(), msg: format!("cannot write: {e}") })
}

/// Reads a manifest; a malformed line is an error naming it.
pub fn read_manifest(path: &Path) -> Result<Vec<ManifestRow>, CsvError> {
    let err = |msg: String| CsvError { path: path.into(), msg };
    let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
    text.lines()
        .enumerate()
        .skip(1)
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(n, l)| {
            ManifestRow::parse(l).ok_or_else(|| err(format!("line {}: expected the columns {MANIFEST_HEADER}", n + 1)))
        })
        .collect()
}

/// Columns of `log.csv`; new columns go at the end so older readers keep working.
pub const LOG_HEADER: &str = "step,phase,loss_diffuse,loss_specular,loss_combined,validation_relmse,patches_per_second,validation_median_relmse,dev_relmse_geomean";

/// One line of the training log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogRow {
    /// Step (1-based).
    pub step: u64,
    /// 1 or 2.
    pub phase: u8,
    /// Diffuse-branch L1 (phase 1; NaN in phase 2).
    pub loss_diffuse: f64,
    /// Specular-branch L1 (phase 1; NaN in phase 2).
    pub loss_specular: f64,
    /// Recomposed-colour L1 (phase 2; NaN in phase 1).
    pub loss_combined: f64,
    /// Mean relMSE of the held-out frames' denoised colour, when validated this step.
    pub validation_relmse: Option<f64>,
    /// Median of the same: one outlier frame (a kept firefly) cannot move it.
    pub validation_median_relmse: Option<f64>,
    /// Training throughput.
    pub patches_per_second: f64,
    /// Geometric mean relMSE over the frames of `kpcn train --dev` (a check set never
    /// trained on), when validated this step with one.
    pub dev_relmse: Option<f64>,
}

impl LogRow {
    /// The CSV line (no newline); NaN losses and absent validations are empty cells.
    pub fn to_line(&self) -> String {
        let loss = |v: f64| if v.is_nan() { String::new() } else { format!("{v:.6}") };
        let opt = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
        format!(
            "{},{},{},{},{},{},{:.3},{},{}",
            self.step,
            self.phase,
            loss(self.loss_diffuse),
            loss(self.loss_specular),
            loss(self.loss_combined),
            opt(self.validation_relmse),
            self.patches_per_second,
            opt(self.validation_median_relmse),
            opt(self.dev_relmse)
        )
    }

    /// Parses one line (also those of older logs without the last columns); `None` when the
    /// step or phase is malformed.
    pub fn parse(line: &str) -> Option<LogRow> {
        let c: Vec<&str> = line.split(',').collect();
        let num = |i: usize| c.get(i).and_then(|s| s.parse::<f64>().ok()).filter(|v| v.is_finite());
        Some(LogRow {
            step: c.first()?.parse().ok()?,
            phase: c.get(1)?.parse().ok()?,
            loss_diffuse: num(2).unwrap_or(f64::NAN),
            loss_specular: num(3).unwrap_or(f64::NAN),
            loss_combined: num(4).unwrap_or(f64::NAN),
            validation_relmse: num(5),
            patches_per_second: num(6).unwrap_or(0.0),
            validation_median_relmse: num(7),
            dev_relmse: num(8),
        })
    }
}

/// The rows of a log's text; malformed lines are skipped (a log cut by a crash stays readable).
pub fn read_log(text: &str) -> Vec<LogRow> {
    text.lines().skip(1).filter_map(LogRow::parse).collect()
}

/// Writes a whole log (the header, then `rows`), atomically.
pub fn write_log(path: &Path, rows: &[LogRow]) -> Result<(), CsvError> {
    let mut text = format!("{LOG_HEADER}\n");
    for r in rows {
        text.push_str(&r.to_line());
        text.push('\n');
    }
    crate::io::atomic::write_atomically(path, text.as_bytes())
        .map_err(|e| CsvError { path: path.into(), msg: format!("cannot write: {e}") })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_round_trip_through_their_lines() {
        let m = ManifestRow {
            scene: "cornell-0001".into(),
            family: "cornell".into(),
            seed: 1,
            sample_seed: 0,
            spp: 16,
            file: "cornell-0001/cornell-0001-00016spp.exr".into(),
            reference: "cornell-0001/cornell-0001-ref.exr".into(),
            render_seconds: 1.25,
        };
        assert_eq!(ManifestRow::parse(&m.to_line()), Some(m));
        assert_eq!(ManifestRow::parse("a,b,1"), None);
        let l = LogRow {
            step: 7,
            phase: 1,
            loss_diffuse: 0.5,
            loss_specular: 0.25,
            loss_combined: f64::NAN,
            validation_relmse: Some(0.0125),
            validation_median_relmse: None,
            patches_per_second: 40.5,
            dev_relmse: Some(0.03),
        };
        let back = LogRow::parse(&l.to_line()).unwrap();
        assert_eq!((back.step, back.loss_diffuse, back.validation_relmse), (7, 0.5, Some(0.0125)));
        assert_eq!(back.dev_relmse, Some(0.03));
        assert!(back.loss_combined.is_nan() && back.validation_median_relmse.is_none());
        // A log from before the median column.
        assert_eq!(LogRow::parse("3,2,,,0.1,,12.0").unwrap().loss_combined, 0.1);
        assert_eq!(read_log(&format!("{LOG_HEADER}\n1,1,0.1,0.2,,,1.0,\ngarbage\n")).len(), 1);
    }
}
