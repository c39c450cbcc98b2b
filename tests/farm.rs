//! The render-farm job template (`plugins/openjd/kpcn-denoise.yaml`) run as a farm runs it:
//! by `openjd run` (openjd-cli, installed by scripts/setup-debian.sh), in chunks of frames.

use super::capi::{EXAMPLE, root};
use kpcn::io::FrameBuffers;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// openjd-cli where scripts/setup-debian.sh puts it, else on PATH.
fn openjd() -> PathBuf {
    let cache = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(std::env::var_os("HOME").expect("HOME is set")).join(".cache"));
    let venv = cache.join("kpcn/openjd/bin/openjd");
    if venv.exists() { venv } else { PathBuf::from("openjd") }
}

fn template() -> PathBuf {
    root().join("plugins/openjd/kpcn-denoise.yaml")
}

/// `openjd run` of the template over frames 1-12 of `dir/in` in chunks of 4.
fn job(dir: &Path, frames: &str) -> Command {
    let mut cmd = Command::new(openjd());
    cmd.arg("run").arg(template());
    for p in [
        format!("Input={}", dir.join("in/f.####.exr").display()),
        format!("Output={}", dir.join("out/f.####.exr").display()),
        format!("Frames={frames}"),
        "ChunkSize=4".into(),
        format!("Kpcn={}", env!("CARGO_BIN_EXE_kpcn")),
    ] {
        cmd.arg("-p").arg(p);
    }
    cmd
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Twelve frames (the example frame, its colour scaled per frame so that frames differ).
fn sequence(dir: &Path) {
    std::fs::create_dir_all(dir.join("in")).unwrap();
    std::fs::create_dir_all(dir.join("out")).unwrap();
    let base = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
    for f in 1..=12 {
        let mut fb = base.clone();
        for c in ["R", "G", "B"] {
            let p = fb.channel(c).unwrap().iter().map(|v| v * (0.5 + f as f32 / 8.0)).collect();
            fb.insert(c, kpcn::io::SampleFormat::Float, p).unwrap();
        }
        fb.write(&dir.join(format!("in/f.{f:04}.exr")), &Default::default()).unwrap();
    }
}

fn denoised(path: &Path) -> Vec<Vec<u32>> {
    let fb = FrameBuffers::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    ["R", "G", "B"]
        .map(|c| fb.channel(&format!("denoised.{c}")).unwrap().iter().map(|v| v.to_bits()).collect())
        .to_vec()
}

#[test]
fn the_farm_template_denoises_in_chunks_as_one_command_does() {
    let check = Command::new(openjd()).arg("check").arg(template()).output().expect("openjd-cli runs");
    assert!(check.status.success() && text(&check).contains("passes validation"), "{}", text(&check));

    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    sequence(d);
    let o = job(d, "1-12").output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("--frames 1-4") && text(&o).contains("--frames 9-12"), "three chunks: {}", text(&o));
    // One `kpcn denoise` over the whole range gives the same images.
    let single = d.join("single");
    std::fs::create_dir(&single).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_kpcn"))
        .args(["denoise", d.join("in/f.####.exr").to_str().unwrap(), "-o"])
        .arg(single.join("f.####.exr"))
        .args(["--frames", "1-12", "-q"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    for f in 1..=12 {
        let name = format!("f.{f:04}.exr");
        assert_eq!(denoised(&d.join("out").join(&name)), denoised(&single.join(&name)), "{name}");
    }
}

#[test]
fn a_killed_task_reruns_only_what_is_missing_and_a_bad_frame_fails_its_task() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    sequence(d);
    // A node dies mid-job: kpcn is killed while the job runs (after some frames are out).
    let mut running = job(d, "1-12").stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
    // Finished frames: not kpcn's hidden temporary files.
    let outputs = |d: &Path| -> Vec<PathBuf> {
        let paths = std::fs::read_dir(d.join("out")).unwrap().map(|e| e.unwrap().path());
        let finished = |p: &PathBuf| {
            p.extension().is_some_and(|x| x == "exr") && !p.file_name().unwrap().to_string_lossy().starts_with('.')
        };
        paths.filter(finished).collect()
    };
    // Frames being written: kpcn's hidden temporary files. Killed while one is, the task
    // fails mid-frame rather than between frames or chunks.
    let writing = |d: &Path| {
        std::fs::read_dir(d.join("out")).unwrap().any(|e| e.unwrap().file_name().to_string_lossy().starts_with('.'))
    };
    let start = Instant::now();
    while !(outputs(d).len() >= 3 && writing(d)) && start.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(2));
    }
    // Only this job's kpcn (its input folder is in the command line): tests run in parallel.
    let ours = format!("{} denoise {}", env!("CARGO_BIN_EXE_kpcn"), d.join("in").display());
    let killed = Command::new("pkill").args(["-KILL", "-f", &ours]).status();
    assert!(killed.unwrap().success(), "no kpcn to kill");
    let status = running.wait().unwrap();
    assert!(!status.success(), "the job should fail with its task");
    let before: Vec<(PathBuf, std::time::SystemTime)> =
        outputs(d).into_iter().map(|p| (p.clone(), p.metadata().unwrap().modified().unwrap())).collect();
    assert!((3..12).contains(&before.len()), "{} frames out before the kill", before.len());
    // Requeued: every frame is there, each complete, and the finished ones were not redone.
    let o = job(d, "1-12").output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("kpcn: skipping"), "{}", text(&o));
    for (p, t) in &before {
        assert_eq!(p.metadata().unwrap().modified().unwrap(), *t, "{} was redone", p.display());
    }
    for f in 1..=12 {
        assert_eq!(denoised(&d.join(format!("out/f.{f:04}.exr"))).len(), 3);
    }
    let leftovers: Vec<_> = std::fs::read_dir(d.join("out"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !n.ends_with(".exr") || n.starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "partial files left: {leftovers:?}");

    // A truncated frame fails its task with the CLI's message and exit status.
    let bad = d.join("in/f.0006.exr");
    let bytes = std::fs::read(&bad).unwrap();
    std::fs::write(&bad, &bytes[..bytes.len() / 3]).unwrap();
    std::fs::remove_file(d.join("out/f.0006.exr")).unwrap();
    let o = job(d, "5-8").output().unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    let log = text(&o);
    assert!(log.contains("kpcn: error:") && log.contains("f.0006.exr") && log.contains("exited with code: 1"), "{log}");
}
