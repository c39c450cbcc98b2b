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
    assert_eq!(checked, 18);
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
    assert!(maps.join("noisy.relmse.png").is_file());
    let small = write(&native_frame(8, 8, 3, &[]), dir.path(), "small.exr");
    let out = Command::new(env!("CARGO_BIN_EXE_kpcn"))
        .args(["eval", "-r", reference.to_str().unwrap(), small.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("is 8x8 but the reference"));
}
