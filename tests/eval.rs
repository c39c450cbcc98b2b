//! Metrics against the team's independently computed Cycles baseline, and `kpcn eval`.

use crate::util::{cycles_dev, native_frame, write};
use kpcn::eval::metrics;
use kpcn::io::FrameBuffers;
use std::process::Command;

fn rgb(fb: &FrameBuffers) -> [&[f32]; 3] {
    ["R", "G", "B"].map(|c| fb.channel(c).unwrap())
}

#[test]
fn metrics_reproduce_the_cycles_baseline() {
    let Some(dir) = cycles_dev() else { return };
    let csv = std::fs::read_to_string(dir.join("baseline.csv")).unwrap();
    let mut checked = 0;
    for row in csv.lines().skip(1) {
        let c: Vec<&str> = row.split(',').collect();
        let (scene, spp, method) = (c[0], c[1].parse::<u32>().unwrap(), c[2]);
        let (relmse, psnr, ssim): (f64, f64, f64) =
            (c[3].parse().unwrap(), c[4].parse().unwrap(), c[5].parse().unwrap());
        let suffix = match method {
            "noisy" => String::new(),
            m => format!(".{m}"),
        };
        let x = FrameBuffers::read(&dir.join(format!("{scene}-{spp:05}spp{suffix}.exr"))).unwrap();
        let y = FrameBuffers::read(&dir.join(format!("{scene}-ref.exr"))).unwrap();
        let m = metrics(rgb(&x), rgb(&y), y.width(), y.height());
        // The CSV rounds to about 4–6 significant digits.
        assert!((m.relmse - relmse).abs() <= 1e-4 * relmse + 1e-6, "{row}: relMSE {}", m.relmse);
        assert!((m.psnr - psnr).abs() < 1e-3, "{row}: PSNR {}", m.psnr);
        assert!((1.0 - m.one_minus_ssim - ssim).abs() < 1e-4, "{row}: SSIM {}", 1.0 - m.one_minus_ssim);
        checked += 1;
    }
    // Every scene of the folder, each at 4/16/64 spp for the noisy input and both OIDNs.
    let scenes = std::fs::read_dir(&dir)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().ends_with("-ref.exr"))
        .count();
    assert!(scenes >= 2, "{scenes} scenes");
    assert_eq!(checked, scenes * 3 * 3, "{scenes} scenes × 3 sample counts × 3 methods");
}

#[test]
fn eval_prints_json_and_writes_error_maps() {
    let dir = tempfile::tempdir().unwrap();
    let reference = write(&native_frame(16, 12, 1, &[]), dir.path(), "ref.exr");
    let noisy = write(&native_frame(16, 12, 2, &[]), dir.path(), "noisy.exr");
    let maps = dir.path().join("maps");
    let out = Command::new(env!("CARGO_BIN_EXE_kpcn"))
        .args(["eval", "-r", reference.to_str().unwrap(), noisy.to_str().unwrap(), reference.to_str().unwrap()])
        .args(["--format", "json", "--error-maps", maps.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(doc["files"][0]["relmse"].as_f64().unwrap() > 0.0);
    assert_eq!(doc["files"][1]["relmse"].as_f64().unwrap(), 0.0, "the reference against itself");
    assert_eq!(doc["files"][1]["brightness"].as_f64().unwrap(), 1.0, "the reference against itself");
    let bright = doc["files"][0]["brightness"].as_f64().unwrap();
    assert!(bright.is_finite() && bright > 0.0 && bright != 1.0, "brightness {bright}");
    assert!(maps.join("noisy.relmse.png").is_file());
    let small = write(&native_frame(8, 8, 3, &[]), dir.path(), "small.exr");
    let out = Command::new(env!("CARGO_BIN_EXE_kpcn"))
        .args(["eval", "-r", reference.to_str().unwrap(), small.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("is 8x8 but the reference"));
}

#[test]
fn a_tiny_study_writes_its_csv_summary_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let args = ["study", "-o", out.to_str().unwrap(), "--families", "cornell,product", "--spp", "2,6"];
    let rest = ["--reference-spp", "32", "--resolution", "40x24", "--oidn", "off", "--threads", "2", "-q"];
    let o = Command::new(env!("CARGO_BIN_EXE_kpcn")).args(args).args(rest).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();
    // 2 scenes × 2 sample counts × (Monte Carlo + the default model).
    assert_eq!(csv.lines().count(), 1 + 8, "{csv}");
    for line in csv.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        let relmse: f64 = c[6].parse().unwrap();
        assert!(relmse.is_finite() && relmse > 0.0, "{line}");
    }
    // More samples, less Monte Carlo error; the denoiser beats the noisy input.
    let err = |scene: &str, spp: &str, m: &str| -> f64 {
        let l = csv.lines().find(|l| l.starts_with(&format!("{scene},{spp},{m},"))).unwrap();
        l.split(',').nth(6).unwrap().parse().unwrap()
    };
    for s in ["cornell-0000", "product-0000"] {
        assert!(err(s, "2", "kpcn-default") < err(s, "2", "monte-carlo"), "{csv}");
    }
    let md = std::fs::read_to_string(out.join("summary.md")).unwrap();
    let flop = kpcn::model::Model::embedded_default().unwrap().arch.flops_per_pixel();
    let start = format!("| kpcn-default | {:.0} k |", flop / 1e3);
    // The child's own peak memory, not the study process's (Linux's wait4 would mix them).
    let row = md.lines().find(|l| l.starts_with(&start)).unwrap_or_else(|| panic!("no `{start}` row: {md}"));
    let mb: f64 = row.split('|').nth(4).unwrap().trim().trim_end_matches(" MB").parse().unwrap();
    assert!((20.0..1000.0).contains(&mb), "{row}");
    assert!(out.join("cornell-0000.png").is_file() && out.join("product-0000.png").is_file());
}
