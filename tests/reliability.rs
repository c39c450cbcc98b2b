//! Issue 14's farm-reliability fixes, each proven on real files through the `kpcn` binary.

use kpcn::io::FrameBuffers;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const EXAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/data/spheres-crop-00016spp.exr");

fn kpcn(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kpcn")).args(args).output().expect("kpcn runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A copy of the example frame in `dir`.
fn example_copy(dir: &Path, name: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::copy(EXAMPLE, &p).unwrap();
    p
}

fn channels(p: &Path) -> usize {
    FrameBuffers::read(p).unwrap().channel_names().count()
}

#[test]
fn an_output_that_is_the_input_is_refused_unless_in_place() {
    let dir = tempfile::tempdir().unwrap();
    let a = example_copy(dir.path(), "a.exr");
    let a_s = a.to_str().unwrap();
    let link = dir.path().join("link.exr");
    std::os::unix::fs::symlink(&a, &link).unwrap();
    // Before the fix, `--separate` left only the denoised channels: the render was gone.
    for out in [a_s, link.to_str().unwrap()] {
        for extra in [&["--separate"][..], &[]] {
            let o = kpcn(&[&["denoise", a_s, "-o", out, "-q"][..], extra].concat());
            assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
            // A separate output would hold only the new layers: even in place, it erases.
            let why = if extra.is_empty() { "--in-place" } else { "erased" };
            assert!(stderr(&o).contains("is the input") && stderr(&o).contains(why), "{}", stderr(&o));
            assert_eq!(channels(&a), 38, "the render is untouched");
        }
    }
    let o = kpcn(&["denoise", a_s, "-o", a_s, "--in-place", "--separate"]);
    assert_eq!(o.status.code(), Some(2), "--separate with --in-place is a usage error: {}", stderr(&o));
    let o = kpcn(&["denoise", a_s, "-o", a_s, "--in-place", "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(channels(&a), 41, "every pass kept, the denoised layer added");
}

#[test]
fn outputs_are_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let t = std::time::Instant::now();
    let o = kpcn(&["denoise", EXAMPLE, "-o", dir.path().to_str().unwrap(), "-q"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("is a folder"), "{}", stderr(&o));
    let missing = dir.path().join("no/such/out.exr");
    let o = kpcn(&["denoise", EXAMPLE, "-o", missing.to_str().unwrap(), "-q"]);
    assert!(stderr(&o).contains("does not exist"), "{}", stderr(&o));
    // Refused up front: no model was loaded, nothing denoised.
    assert!(t.elapsed().as_secs_f64() < 5.0, "{:?}", t.elapsed());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn a_linked_output_is_written_through_and_keeps_its_mode() {
    let dir = tempfile::tempdir().unwrap();
    let target = example_copy(dir.path(), "target.exr");
    std::fs::set_permissions(&target, std::fs::Permissions::from_mode(0o640)).unwrap();
    let link = dir.path().join("link.exr");
    std::os::unix::fs::symlink("target.exr", &link).unwrap();
    let o = kpcn(&["denoise", EXAMPLE, "-o", link.to_str().unwrap(), "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "the link is still a link");
    assert_eq!(channels(&target), 41, "the target got the result");
    assert_eq!(std::fs::metadata(&target).unwrap().permissions().mode() & 0o777, 0o640);
}

#[test]
fn a_file_the_user_cannot_write_is_not_replaced() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o777)).unwrap();
    let input = example_copy(dir.path(), "in.exr");
    std::fs::set_permissions(&input, std::fs::Permissions::from_mode(0o644)).unwrap();
    let locked = dir.path().join("locked.exr");
    std::fs::write(&locked, b"keep me").unwrap();
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o444)).unwrap();
    // As root every file is writable: run as `nobody`, for whom the 0444 file (owned by
    // someone else) is read-only although its folder is writable.
    // SAFETY: geteuid has no preconditions.
    let mut cmd = if unsafe { libc::geteuid() } == 0 {
        // A copy of the binary that `nobody` may run, wherever the checkout lives.
        let bin = dir.path().join("kpcn");
        std::fs::copy(env!("CARGO_BIN_EXE_kpcn"), &bin).unwrap();
        std::fs::set_permissions(&bin, std::fs::Permissions::from_mode(0o755)).unwrap();
        let mut c = Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups"]).arg(&bin);
        c
    } else {
        Command::new(env!("CARGO_BIN_EXE_kpcn"))
    };
    let o = cmd.args(["denoise", input.to_str().unwrap(), "-o", locked.to_str().unwrap(), "-q"]).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("not writable"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&locked).unwrap(), b"keep me");
    assert_eq!(std::fs::metadata(&locked).unwrap().permissions().mode() & 0o777, 0o444);
}

#[test]
fn absurd_thread_counts_are_capped() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.exr");
    let t = std::time::Instant::now();
    let o = kpcn(&["denoise", EXAMPLE, "-o", out.to_str().unwrap(), "--threads", "10000"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("capped"), "{}", stderr(&o));
    // 10,007 threads once took over 12 minutes here.
    assert!(t.elapsed().as_secs() < 120, "{:?}", t.elapsed());
}

/// A sequence of small native frames `dir/render.NNNN.exr` for `frames`.
fn sequence(dir: &Path, frames: &[i64]) {
    for &f in frames {
        super::util::write(&super::util::native_frame(24, 16, f as u64, &[]), dir, &format!("render.{f:04}.exr"));
    }
}

#[test]
fn frame_lists_and_padding_are_checked_the_same_way_in_dry_runs_and_runs() {
    let dir = tempfile::tempdir().unwrap();
    sequence(dir.path(), &[1, 2, 4]);
    let p = |s: &str| dir.path().join(s).to_str().unwrap().to_string();
    let (input, output) = (p("render.####.exr"), p("den.####.exr"));

    let t = std::time::Instant::now();
    let o = kpcn(&["denoise", &input, "-o", &output, "--frames", "1-100000000", "-n"]);
    assert_eq!(o.status.code(), Some(2), "a usage error");
    assert!(stderr(&o).contains("at most 1000000"), "{}", stderr(&o));
    assert!(t.elapsed().as_secs() < 10, "refused without expanding: {:?}", t.elapsed());

    // `@@@` names 3-digit files: the 4-digit ones are not its frames.
    let o = kpcn(&["denoise", &p("render.@@@.exr"), "-o", &p("den.@@@.exr"), "-n"]);
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stdout));
    assert!(stderr(&o).contains("padding"), "{}", stderr(&o));

    // Frames found on disk: the gap is reported.
    let o = kpcn(&["denoise", &input, "-o", &output, "-n"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("frames 3 are missing between 1 and 4"), "{}", stderr(&o));
    // Asked for explicitly, the missing frame fails the dry run as it would the run.
    let o = kpcn(&["denoise", &input, "-o", &output, "--frames", "1-4", "-n"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("1 input(s) missing"), "{}", stderr(&o));
    let o = kpcn(&["denoise", &input, "-o", &output, "--frames", "1-4", "-q"]);
    assert_eq!(o.status.code(), Some(1), "the run fails like the dry run");
}

#[test]
fn a_rerun_with_skip_existing_resumes_and_farm_logs_get_a_line_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    sequence(dir.path(), &[1, 2, 3]);
    let p = |s: &str| dir.path().join(s).to_str().unwrap().to_string();
    let (input, output) = (p("render.####.exr"), p("den.####.exr"));
    let o = kpcn(&["denoise", &input, "-o", &output]);
    assert!(o.status.success(), "{}", stderr(&o));
    // stderr is a pipe here, as on a farm: a line per frame, no bar.
    assert_eq!(stderr(&o).matches("kpcn: frame ").count(), 3, "{}", stderr(&o));
    assert!(stderr(&o).contains("kpcn: frame 2/3"), "{}", stderr(&o));

    // Preempted mid-frame: frame 2's output is cut short.
    let den2 = dir.path().join("den.0002.exr");
    let bytes = std::fs::read(&den2).unwrap();
    std::fs::write(&den2, &bytes[..bytes.len() / 2]).unwrap();
    let before = std::fs::metadata(dir.path().join("den.0001.exr")).unwrap().modified().unwrap();
    let o = kpcn(&["denoise", &input, "-o", &output, "--skip-existing"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("skipping 2 of 3"), "{}", stderr(&o));
    assert_eq!(std::fs::metadata(dir.path().join("den.0001.exr")).unwrap().modified().unwrap(), before);
    assert!(FrameBuffers::read(&den2).is_ok(), "frame 2 redone");
    let o = kpcn(&["denoise", &input, "-o", &output, "--skip-existing"]);
    assert!(o.status.success() && stderr(&o).contains("skipping 3 of 3"), "{}", stderr(&o));
    // --no-clobber keeps its meaning, and a dry run says so with the run's status.
    let o = kpcn(&["denoise", &input, "-o", &output, "--no-clobber", "-n"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("3 output(s) refused by --no-clobber"), "{}", stderr(&o));
}

#[test]
fn sigterm_and_sigint_remove_the_partial_output_and_exit_143_and_130() {
    for (sig, code) in [(libc::SIGTERM, 143), (libc::SIGINT, 130)] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out.exr");
        // A small memory budget: many bands, so the output is being written for a while.
        let mut child = Command::new(env!("CARGO_BIN_EXE_kpcn"))
            .args(["denoise", EXAMPLE, "-q", "--threads", "1", "--max-memory", "16", "-o"])
            .arg(&out)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let t = std::time::Instant::now();
        let writing = || {
            std::fs::read_dir(dir.path())
                .unwrap()
                .flatten()
                .any(|e| e.file_name().to_string_lossy().starts_with(".out.exr.kpcn-"))
        };
        while !writing() {
            assert!(t.elapsed().as_secs() < 60, "no temporary file appeared");
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        // SAFETY: signalling our own child.
        unsafe { libc::kill(child.id() as i32, sig) };
        let status = child.wait().unwrap();
        let mut err = String::new();
        std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
        assert_eq!(status.code(), Some(code), "signal {sig}: {status:?} {err}");
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().flatten().map(|e| e.file_name()).collect();
        assert!(left.is_empty(), "left behind: {left:?}");
    }
}

#[test]
fn exit_codes_are_documented_and_usage_errors_exit_2() {
    let help = kpcn(&["--help"]);
    let text = String::from_utf8_lossy(&help.stdout);
    for s in ["0 success", "1 runtime error", "2 usage error", "130", "143"] {
        assert!(text.contains(s), "--help lacks `{s}`:\n{text}");
    }
    let o = kpcn(&["denoise", "in.####.exr", "-o", "out.exr"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let o = kpcn(&["denoise", "--bogus"]);
    assert_eq!(o.status.code(), Some(2));
    let o = kpcn(&["denoise", "/nonexistent/in.exr", "-o", "/tmp/kpcn-out-never.exr", "-q"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
}

#[test]
fn small_messages_are_right() {
    let dir = tempfile::tempdir().unwrap();
    // A zero-byte file is called empty, not "not an OpenEXR file".
    let empty = dir.path().join("empty.exr");
    std::fs::write(&empty, b"").unwrap();
    let o = kpcn(&["info", empty.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("is empty (0 bytes)"), "{}", stderr(&o));

    // A Cycles file without the diffuse passes: DiffCol (diffuse and albedo) named once;
    // and `info` aligns its columns past Blender's long pass names.
    let mut fb = FrameBuffers::new(8, 4);
    for c in ["Combined.R", "Combined.G", "Combined.B", "Normal.X", "Normal.Y", "Normal.Z", "Depth.Z"]
        .into_iter()
        .chain(["Denoising Albedo.R", "Denoising Albedo.G", "Denoising Albedo.B"])
    {
        fb.insert(&format!("ViewLayer.{c}"), kpcn::io::SampleFormat::Half, vec![0.5; 32]).unwrap();
    }
    let partial = super::util::write(&fb, dir.path(), "partial.exr");
    let o = kpcn(&["info", partial.to_str().unwrap()]);
    assert_eq!(stderr(&o).matches("ViewLayer.DiffCol.R").count(), 1, "{}", stderr(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    let columns: Vec<usize> = stdout
        .lines()
        .filter(|l| l.starts_with("    ViewLayer."))
        .map(|l| l.find(" R G B").or_else(|| l.find(" X Y Z")).or_else(|| l.find(" Z ")).unwrap())
        .collect();
    assert_eq!(columns.len(), 4, "{stdout}");
    assert!(columns.iter().all(|&c| c == columns[0]), "misaligned: {columns:?}\n{stdout}");

    // Outputs are byte-identical across reruns: nothing like a fresh date is written.
    let input = super::util::write(&super::util::native_frame(16, 8, 3, &[]), dir.path(), "in.exr");
    let (a, b) = (dir.path().join("a.exr"), dir.path().join("b.exr"));
    for out in [&a, &b] {
        let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
        assert!(o.status.success(), "{}", stderr(&o));
        std::thread::sleep(std::time::Duration::from_millis(1100));
    }
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(), "reruns differ");
}

#[test]
fn info_speaks_json_and_flags_non_finite_samples() {
    let dir = tempfile::tempdir().unwrap();
    let mut fb = super::util::native_frame(8, 4, 1, &[]);
    let mut r = fb.channel("R").unwrap().to_vec();
    r[3] = f32::NAN;
    r[5] = f32::INFINITY;
    fb.insert("R", kpcn::io::SampleFormat::Float, r).unwrap();
    let nan = super::util::write(&fb, dir.path(), "nan.exr");
    let o = kpcn(&["info", nan.to_str().unwrap()]);
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("verdict     complete") && table.contains("2 samples are NaN/Inf"), "{table}");

    let garbage = dir.path().join("garbage.exr");
    std::fs::write(&garbage, b"not an image").unwrap();
    let o = kpcn(&["info", "--format", "json", nan.to_str().unwrap(), garbage.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "an unreadable file fails the run");
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON document");
    assert_eq!(doc[0]["verdict"], "complete");
    assert_eq!(doc[0]["nonfinite_samples"], 2);
    assert_eq!(doc[0]["layout"], "native");
    assert_eq!(doc[0]["inputs"][0]["variance"], "present");
    assert!(doc[1]["error"].as_str().unwrap().contains("garbage.exr"), "{doc}");
}

#[test]
fn eval_takes_the_reference_layer_from_its_own_flag() {
    let dir = tempfile::tempdir().unwrap();
    let mut reference = FrameBuffers::new(8, 4);
    for c in ["R", "G", "B"] {
        reference.insert(&format!("ViewLayer.Combined.{c}"), kpcn::io::SampleFormat::Float, vec![0.5; 32]).unwrap();
    }
    let reference = super::util::write(&reference, dir.path(), "ref.exr");
    let mut image = FrameBuffers::new(8, 4);
    for c in ["R", "G", "B"] {
        image.insert(c, kpcn::io::SampleFormat::Float, vec![0.25; 32]).unwrap();
    }
    let image = super::util::write(&image, dir.path(), "img.exr");
    let (r, i) = (reference.to_str().unwrap(), image.to_str().unwrap());
    let o = kpcn(&["eval", "-r", r, i]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("--reference-channels"), "{}", stderr(&o));
    let o = kpcn(&["eval", "-r", r, i, "--reference-channels", "ViewLayer.Combined", "--format", "json"]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// Runs `kpcn ARGS` under a 4 GB address-space limit and a 30 s timeout; the exit code, or
/// `None` for a signal or a hang.
fn kpcn_limited(args: &[&str]) -> (Option<i32>, String) {
    use std::os::unix::process::CommandExt;
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_kpcn"));
    cmd.args(args).stdout(std::process::Stdio::null()).stderr(std::process::Stdio::piped());
    // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            let limit = libc::rlimit { rlim_cur: 4 << 30, rlim_max: 4 << 30 };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = cmd.spawn().unwrap();
    let t = std::time::Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
            return (status.code(), err);
        }
        if t.elapsed().as_secs() > 30 {
            let _ = child.kill();
            let _ = child.wait();
            return (None, "hung for 30 s".into());
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
}

/// Bit flips and patched header fields on real EXRs (a scanline and a tiled one): `info`
/// and `denoise` end every case with status 0 or 1 — never a signal, an abort from a huge
/// allocation, or a hang — under a 4 GB address-space limit.
#[test]
fn mutated_exrs_never_crash_or_exhaust_memory() {
    let dir = tempfile::tempdir().unwrap();
    let originals = [
        std::fs::read(EXAMPLE).unwrap(),
        std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/spheres-48x32-tiled16.exr")).unwrap(),
    ];
    let mut rng = super::util::Rng(14);
    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    for (k, original) in originals.iter().enumerate() {
        // The header ends at the first "\0" after the last attribute: flip within ~the first KB.
        let header_end = original.windows(2).position(|w| w == b"\0\0").unwrap_or(1024).max(64) + 1;
        for i in 0..30 {
            let mut d = original.clone();
            let region = if i % 2 == 0 { header_end } else { d.len() };
            for _ in 0..1 + (rng.next_u64() % 8) {
                let at = (rng.next_u64() as usize) % region;
                d[at] ^= 1 << (rng.next_u64() % 8);
            }
            cases.push((format!("{k}-flip-{i}"), d));
        }
        // Windows claiming enormous, negative or inverted sizes.
        for (i, window) in [
            [0, 0, 59999, 59999],
            [0, 0, 199999, 199999],
            [0, 0, 16383, 16383],
            [-2147483647, 0, 2147483647, 5],
            [10, 10, 0, 0],
            [0, 0, 1 << 20, 0],
        ]
        .iter()
        .enumerate()
        {
            for name in [&b"dataWindow\0box2i\0"[..], &b"displayWindow\0box2i\0"[..]] {
                let mut d = original.clone();
                let Some(at) = d.windows(name.len()).position(|w| w == name) else { continue };
                let at = at + name.len() + 4;
                for (j, v) in window.iter().enumerate() {
                    d[at + 4 * j..at + 4 * j + 4].copy_from_slice(&i32::to_le_bytes(*v));
                }
                cases.push((format!("{k}-window-{i}-{}", name.len()), d));
            }
        }
    }
    let t = std::time::Instant::now();
    let mut failures = Vec::new();
    for (name, bytes) in &cases {
        let path = dir.path().join(format!("{name}.exr"));
        std::fs::write(&path, bytes).unwrap();
        let out = dir.path().join("out.exr");
        let p = path.to_str().unwrap();
        for args in [&["info", p][..], &["denoise", p, "-o", out.to_str().unwrap(), "-q", "--threads", "1"][..]] {
            // Denoising every flipped file would take minutes in a debug build: every eighth.
            if args[0] == "denoise" && !name.contains("window") && !name.ends_with('0') {
                continue;
            }
            let (code, err) = kpcn_limited(args);
            if !matches!(code, Some(0) | Some(1)) {
                failures.push(format!("{name} {}: {code:?} {}", args[0], err.lines().last().unwrap_or("")));
            }
        }
    }
    assert!(failures.is_empty(), "{} of {} cases crashed:\n{}", failures.len(), cases.len(), failures.join("\n"));
    eprintln!("{} mutated files in {:.1} s", cases.len(), t.elapsed().as_secs_f64());
}

/// Hostile values: 1e30 in albedo and NaN in colour are repaired (clamped to the physical
/// range, or set to 0), said once per input with the count, and the output stays finite
/// and inside the input's finite range.
#[test]
fn hostile_values_are_repaired_and_reported() {
    let dir = tempfile::tempdir().unwrap();
    // A real render (consistent passes), so its output range is meaningful.
    let mut fb = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
    let (w, h) = (fb.width(), fb.height());
    let mut set = |name: &str, f: &dyn Fn(usize, usize) -> Option<f32>| {
        let mut v = fb.channel(name).unwrap().to_vec();
        for y in 0..h {
            for x in 0..w {
                if let Some(s) = f(x, y) {
                    v[y * w + x] = s;
                }
            }
        }
        fb.insert(name, kpcn::io::SampleFormat::Float, v).unwrap();
    };
    for c in ["albedo.R", "albedo.G", "albedo.B"] {
        set(c, &|x, y| (x < 90 && y < 60).then_some(1e30));
    }
    set("R", &|x, y| (y == 70 && x < 30).then_some(f32::NAN));
    set("normal.R", &|x, _| (x == 159).then_some(7.0));
    let input = super::util::write(&fb, dir.path(), "hostile.exr");
    let out = dir.path().join("out.exr");
    let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("albedo: 16200 samples outside [0, 1] clamped"), "{err}");
    assert!(err.contains("color: 30 NaN/Inf samples set to 0"), "{err}");
    assert!(err.contains("normal: 96 samples outside [-1, 1] clamped"), "{err}");
    let d = FrameBuffers::read(&out).unwrap();
    let max_in = ["R", "G", "B"]
        .iter()
        .flat_map(|c| fb.channel(c).unwrap().iter().copied())
        .filter(|v| v.is_finite())
        .fold(0f32, f32::max);
    for c in ["denoised.R", "denoised.G", "denoised.B"] {
        let v = d.channel(c).unwrap();
        assert!(v.iter().all(|x| x.is_finite() && *x >= 0.0), "{c}");
        let max_out = v.iter().copied().fold(0f32, f32::max);
        // Before, 1e30 albedo gave outputs up to 4.8e14.
        assert!(max_out <= max_in, "{c}: {max_out} above the input's largest {max_in}");
    }
}

/// A Blender multilayer file with view layers `A` and `B` (different content).
fn two_view_layers(dir: &Path) -> PathBuf {
    let (w, h) = (24, 16);
    let mut fb = FrameBuffers::new(w, h);
    let mut rng = super::util::Rng(5);
    for vl in ["A", "B"] {
        for (pass, comps) in [
            ("Combined", &["R", "G", "B"][..]),
            ("DiffDir", &["R", "G", "B"]),
            ("DiffInd", &["R", "G", "B"]),
            ("DiffCol", &["R", "G", "B"]),
            ("Normal", &["X", "Y", "Z"]),
            ("Depth", &["Z"]),
        ] {
            for c in comps {
                let v: Vec<f32> = (0..w * h).map(|_| rng.uniform_f32() * if vl == "A" { 1.0 } else { 0.5 }).collect();
                fb.insert(&format!("{vl}.{pass}.{c}"), kpcn::io::SampleFormat::Float, v).unwrap();
            }
        }
    }
    super::util::write(&fb, dir, "layers.exr")
}

#[test]
fn blender_view_layers_are_chosen_named_and_all_denoised() {
    let dir = tempfile::tempdir().unwrap();
    let input = two_view_layers(dir.path());
    let i = input.to_str().unwrap();
    let out = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let o = kpcn(&["denoise", i, "-o", &out("a.exr")]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("denoising view layer `A` of 2 (A, B)"), "{}", stderr(&o));
    let a = FrameBuffers::read(Path::new(&out("a.exr"))).unwrap();
    assert!(a.channel("A.Denoised.R").is_some() && a.channel("denoised.R").is_none(), "named for Blender");

    let o = kpcn(&["denoise", i, "-o", &out("b.exr"), "--view-layer", "B", "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let b = FrameBuffers::read(Path::new(&out("b.exr"))).unwrap();
    assert!(b.channel("B.Denoised.R").is_some() && b.channel("A.Denoised.R").is_none());

    let o = kpcn(&["denoise", i, "-o", &out("all.exr"), "--view-layer", "all", "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let all = FrameBuffers::read(Path::new(&out("all.exr"))).unwrap();
    for (one, layer) in [(&a, "A.Denoised.G"), (&b, "B.Denoised.G")] {
        assert_eq!(all.channel(layer), one.channel(layer), "{layer}: the same as denoising that layer alone");
    }
    assert_ne!(all.channel("A.Denoised.G"), all.channel("B.Denoised.G"));

    let o = kpcn(&["info", i]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("view layer  A (of 2: A, B)"));
    let o = kpcn(&["denoise", i, "-o", &out("c.exr"), "--view-layer", "C"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("no view layer `C` — the file has A, B"), "{}", stderr(&o));
}

/// A multi-part file keeps its parts, their names and channels; the denoised layer joins
/// the part that holds the beauty, and equals the single-part result. Streamed in several
/// bands, so every part is written band by band.
#[test]
fn multi_part_files_keep_their_parts() {
    use kpcn::io::{FrameReader, Part, WriteOptions};
    let dir = tempfile::tempdir().unwrap();
    let fb = super::util::native_frame(24, 40, 4, &[]);
    let names: Vec<&str> = fb.channel_names().collect();
    // The auxiliaries first, so the beauty is not part 0.
    let (beauty, aux): (Vec<&str>, Vec<&str>) = names.iter().partition(|n| !n.contains('.'));
    let parts = [Part { name: "aux", channels: aux.clone() }, Part { name: "beauty", channels: beauty.clone() }];
    let multi = dir.path().join("multi.exr");
    fb.write_parts(&multi, &parts, &WriteOptions::default()).unwrap();
    let single = super::util::write(&fb, dir.path(), "single.exr");
    let (mo, so) = (dir.path().join("mo.exr"), dir.path().join("so.exr"));
    for (i, o) in [(&multi, &mo), (&single, &so)] {
        let r = kpcn(&["denoise", i.to_str().unwrap(), "-o", o.to_str().unwrap(), "-q", "--max-memory", "16"]);
        assert!(r.status.success(), "{}", stderr(&r));
    }
    let out = FrameReader::open(&mo).unwrap().parts();
    assert_eq!(out.iter().map(|p| p.name.as_str()).collect::<Vec<_>>(), ["aux", "beauty"]);
    // OpenEXR stores a part's channels in name order: compare sorted.
    let sorted = |mut v: Vec<String>| {
        v.sort();
        v
    };
    let in_part = |p: usize| sorted(out[p].channels.iter().map(|c| c.1.clone()).collect());
    let owned = |v: &[&str]| sorted(v.iter().map(|s| s.to_string()).collect());
    assert_eq!(in_part(0), owned(&aux));
    assert_eq!(in_part(1), owned(&[&beauty[..], &["denoised.R", "denoised.G", "denoised.B"]].concat()));
    let (m, s) = (FrameBuffers::read(&mo).unwrap(), FrameBuffers::read(&so).unwrap());
    for c in names.iter().chain(&["denoised.R", "denoised.G", "denoised.B"]) {
        assert_eq!(m.channel(c), s.channel(c), "{c}");
    }
}

/// `--max-memory` bounds what grows with the frame (bands and tiles); the process's fixed
/// cost comes on top (README, `--help`). Peak RSS of the whole process, measured by the
/// kernel (VmHWM), on a frame streamed in several bands (`compact`, whose bands need
/// few context rows) and on the default, whose 194 context rows make it one band here.
#[test]
fn max_memory_bounds_the_working_memory() {
    let dir = tempfile::tempdir().unwrap();
    let input = super::util::write(&super::util::native_frame(320, 192, 8, &[]), dir.path(), "in.exr");
    let out = dir.path().join("out.exr");
    for (model, budget) in [("compact", 16), ("compact", 128), ("default", 16)] {
        let o = Command::new(env!("CARGO_BIN_EXE_kpcn"))
            .args(["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "-v", "--model", model])
            .arg("--max-memory")
            .arg(budget.to_string())
            .env("KPCN_REPORT_PEAK_RSS", "1")
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        let stdout = String::from_utf8_lossy(&o.stdout);
        if model == "compact" && budget == 16 {
            let rows: Option<usize> = stdout.split("bands of ").nth(1).and_then(|r| r.split(' ').next()?.parse().ok());
            assert!(rows.is_some_and(|r| r < 192), "several bands: {stdout}");
        }
        let kb: u64 = stderr(&o)
            .lines()
            .find_map(|l| l.strip_prefix("peak-rss-kb "))
            .and_then(|v| v.trim().parse().ok())
            .expect("peak RSS reported");
        let fixed_mb = 640;
        assert!(kb / 1024 <= budget + fixed_mb, "{model}, {budget} MB budget: peak {} MB", kb / 1024);
    }
}
