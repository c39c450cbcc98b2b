//! The `kpcn` binary: exit statuses and messages a pipeline can rely on.

use crate::util::{cycles_dev, garbage, mismatched_parts, native_frame, write};
use kpcn::io::FrameBuffers;
use std::path::Path;
use std::process::{Command, Output};

fn kpcn(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kpcn")).args(args).output().expect("kpcn runs")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn info_reports_a_complete_native_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&native_frame(20, 10, 1, &[]), dir.path(), "shot.0001.exr");
    let out = kpcn(&["info", path.to_str().unwrap()]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}{}", stdout, text(&out.stderr));
    assert!(stdout.contains("20x10"), "{stdout}");
    assert!(stdout.contains("native (auto-detected)"), "{stdout}");
    assert!(stdout.contains("verdict     complete"), "{stdout}");
    assert!(stdout.contains("diffuseVariance"), "{stdout}");
}

#[test]
fn info_fails_on_missing_channels_naming_them_and_the_fix() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&native_frame(8, 8, 2, &["normal"]), dir.path(), "nonormal.exr");
    let out = kpcn(&["info", path.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    let stderr = text(&out.stderr);
    let expect = format!("kpcn: error: {}: missing channels normal.R, normal.G, normal.B", path.display());
    assert!(stderr.starts_with(&expect), "{stderr}");
    assert!(stderr.contains(" — "), "{stderr}");
}

#[test]
fn openexrs_zip_chunks_go_through_the_commands_libdeflate() {
    // The dynamic linker's own report of where OpenEXR's zlib calls land: the command's
    // exported definitions (src/cli/zlib.rs), not libz's.
    let dir = tempfile::tempdir().unwrap();
    let input = write(&native_frame(16, 8, 4, &[]), dir.path(), "in.exr");
    let output = dir.path().join("out.exr");
    let out = Command::new(env!("CARGO_BIN_EXE_kpcn"))
        .args(["denoise", input.to_str().unwrap(), "-o", output.to_str().unwrap(), "-q"])
        .env("LD_DEBUG", "bindings")
        .output()
        .expect("kpcn runs");
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let exe = std::fs::canonicalize(env!("CARGO_BIN_EXE_kpcn")).unwrap();
    for symbol in ["compress2", "uncompress"] {
        let bound = stderr
            .lines()
            .filter(|l| l.contains("libOpenEXR-") && l.contains(&format!("`{symbol}'")))
            .collect::<Vec<_>>();
        assert!(!bound.is_empty(), "OpenEXR never binds {symbol}");
        for line in bound {
            let to = line.split(" to ").nth(1).and_then(|t| t.split(" [").next()).unwrap_or("");
            let to = std::fs::canonicalize(to).unwrap_or_default();
            assert_eq!(to, exe, "{line}");
        }
    }
}

#[test]
fn info_fails_on_unreadable_files_but_reports_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let good = write(&native_frame(8, 8, 3, &[]), dir.path(), "good.exr");
    let bad = dir.path().join("truncated.exr");
    let bytes = std::fs::read(&good).unwrap();
    std::fs::write(&bad, &bytes[..bytes.len() / 2]).unwrap();
    let corrupt = dir.path().join("corrupt.exr");
    garbage(&corrupt);
    let parts = dir.path().join("parts.exr");
    mismatched_parts(&parts);
    let files = ["/nonexistent.exr", bad.to_str().unwrap(), corrupt.to_str().unwrap(), parts.to_str().unwrap()];
    let out = kpcn(&[&["info"], &files[..], &[good.to_str().unwrap()]].concat());
    assert_eq!(out.status.code(), Some(1));
    let stderr = text(&out.stderr);
    assert!(stderr.contains("kpcn: error: /nonexistent.exr: cannot open"), "{stderr}");
    for f in &files[1..] {
        assert!(stderr.contains(&format!("kpcn: error: {f}: ")), "{f}: {stderr}");
    }
    assert!(stderr.contains("is 8x4 but part 0 is 16x8"), "{stderr}");
    assert_eq!(stderr.lines().count(), 4, "one line per bad file: {stderr}");
    assert!(text(&out.stdout).contains("good.exr"), "the good file is still reported");
}

#[test]
fn info_honours_a_layout_override() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&native_frame(8, 8, 4, &[]), dir.path(), "n.exr");
    let out = kpcn(&["info", "--layout", "cycles", path.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1), "native channels do not satisfy the Cycles layout");
    assert!(text(&out.stdout).contains("cycles (from --layout)"));
    assert!(text(&out.stderr).contains("ViewLayer.Combined"), "{}", text(&out.stderr));
    let out = kpcn(&["info", "--layout", "arnold", path.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2), "clap rejects unknown layouts");
}

#[test]
fn info_on_the_checked_in_example_and_the_cycles_dev_set_reports_all_inputs() {
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/data/spheres-crop-00016spp.exr");
    let mut files = vec![example];
    if let Some(dir) = cycles_dev() {
        for s in ["spheres", "interior"] {
            for spp in ["00004", "00016", "00064"] {
                files.push(dir.join(format!("{s}-{spp}spp.exr")));
            }
        }
    }
    let args: Vec<&str> = std::iter::once("info").chain(files.iter().map(|f| f.to_str().unwrap())).collect();
    let out = kpcn(&args);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{stdout}{}", text(&out.stderr));
    assert_eq!(stdout.matches("verdict     complete").count(), files.len(), "{stdout}");
}

#[test]
fn render_writes_complete_frames_and_a_reference() {
    let dir = tempfile::tempdir().unwrap();
    let out = kpcn(&[
        "render",
        "--family",
        "cornell",
        "--seed",
        "1",
        "--spp",
        "4,16",
        "--reference-spp",
        "32",
        "--resolution",
        "32x18",
        "-q",
        "-o",
        dir.path().to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let files: Vec<String> = ["cornell-0001-00004spp.exr", "cornell-0001-00016spp.exr", "cornell-0001-ref.exr"]
        .iter()
        .map(|f| dir.path().join(f).display().to_string())
        .collect();
    let info = kpcn(&[&["info"], &files.iter().map(String::as_str).collect::<Vec<_>>()[..]].concat());
    let stdout = text(&info.stdout);
    assert!(info.status.success(), "{stdout}{}", text(&info.stderr));
    assert_eq!(stdout.matches("verdict     complete").count(), 3, "{stdout}");
    assert!(stdout.contains("visibility  present"), "{stdout}");
    // --no-clobber refuses to overwrite.
    let again = kpcn(&[
        "render",
        "--family",
        "cornell",
        "--seed",
        "1",
        "--spp",
        "4",
        "--resolution",
        "32x18",
        "-q",
        "--no-clobber",
        "-o",
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(again.status.code(), Some(1));
    assert!(text(&again.stderr).contains("--no-clobber"), "{}", text(&again.stderr));
}

#[test]
fn render_reads_scene_files_and_explains_their_errors() {
    let dir = tempfile::tempdir().unwrap();
    let example = kpcn(&["scenes", "--example"]);
    assert!(example.status.success());
    let scene = dir.path().join("scene.toml");
    std::fs::write(&scene, &example.stdout).unwrap();
    let render = || {
        kpcn(&[
            "render",
            scene.to_str().unwrap(),
            "--spp",
            "2",
            "--resolution",
            "8x8",
            "-q",
            "-o",
            dir.path().to_str().unwrap(),
        ])
    };
    let out = render();
    assert!(out.status.success(), "{}", text(&out.stderr));
    // Undeclare `glossy` but use a metal: a clear error.
    let broken = text(&example.stdout).replace("\"glossy\", ", "").replace(", \"glossy\"", "");
    let broken = broken.replace("type = \"diffuse\"", "type = \"conductor\"\ncolor = [0.9, 0.9, 0.9]");
    std::fs::write(&scene, broken).unwrap();
    let out = render();
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("needs the `glossy` effect"), "{}", text(&out.stderr));
    let out = kpcn(&["render", "--spp", "1", "--family", "dof", "-o", dir.path().to_str().unwrap()]);
    assert!(text(&out.stderr).contains("at least 2"), "{}", text(&out.stderr));
}

#[test]
fn scenes_lists_every_family_and_dataset_writes_and_extends_a_manifest() {
    let out = kpcn(&["scenes"]);
    assert!(out.status.success());
    let listed = text(&out.stdout).lines().filter(|l| l.contains("effects of seed 0")).count();
    assert_eq!(listed, kpcn::sim::families::FAMILIES.len(), "{}", text(&out.stdout));

    let dir = tempfile::tempdir().unwrap();
    let o = dir.path().to_str().unwrap();
    let dataset = |families: &str, count: &str| {
        let common = ["--spp", "2,4", "--reference-spp", "8", "--resolution", "16x9", "-q", "-o", o];
        kpcn(&[&["dataset", "--families", families, "--count", count][..], &common[..]].concat())
    };
    let out = dataset("glass,dof", "2");
    assert!(out.status.success(), "{}", text(&out.stderr));
    let manifest = std::fs::read_to_string(dir.path().join("manifest.csv")).unwrap();
    let rows: Vec<&str> = manifest.lines().collect();
    assert_eq!(rows.len(), 1 + 2 * 2 * 2, "{manifest}");
    for row in &rows[1..] {
        let cols: Vec<&str> = row.split(',').collect();
        assert!(dir.path().join(cols[5]).is_file(), "{row}");
        assert!(dir.path().join(cols[6]).is_file(), "{row}");
    }

    // Rerun with one more seed and another family: the listed scenes are kept, not
    // re-rendered (their files keep their times), a lost scene is rendered again.
    let kept = dir.path().join("glass-0000/glass-0000-00002spp.exr");
    let stamp = std::fs::metadata(&kept).unwrap().modified().unwrap();
    std::fs::remove_file(dir.path().join("dof-0001/dof-0001-00004spp.exr")).unwrap();
    let out = dataset("glass,dof,cornell", "3");
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("3 scenes already in"), "{}", text(&out.stdout));
    assert_eq!(std::fs::metadata(&kept).unwrap().modified().unwrap(), stamp, "kept, not rendered again");
    assert!(dir.path().join("dof-0001/dof-0001-00004spp.exr").is_file(), "the lost frame is back");
    let manifest = std::fs::read_to_string(dir.path().join("manifest.csv")).unwrap();
    assert_eq!(manifest.lines().count(), 1 + 3 * 3 * 2, "{manifest}");
    let mut lines: Vec<&str> = manifest.lines().skip(1).collect();
    lines.sort_unstable();
    lines.dedup();
    assert_eq!(lines.len(), 18, "no scene listed twice");
}

/// `--model auto` (the default) runs `default` on a file with per-pixel variances and
/// `spatial` on one with neither variances nor half buffers, exactly as naming it would.
#[test]
fn auto_picks_the_spatial_model_for_files_without_variances() {
    let dir = tempfile::tempdir().unwrap();
    let full = native_frame(48, 32, 5, &[]);
    let with = write(&full, dir.path(), "with.exr");
    // The same means, without variances and half buffers.
    let mut means = FrameBuffers::new(48, 32);
    for c in crate::util::native_channels() {
        if !c.contains("Variance") && !c.split('.').next().is_some_and(|l| l.ends_with('A')) {
            means.insert(&c, kpcn::io::SampleFormat::Float, full.channel(&c).unwrap().to_vec()).unwrap();
        }
    }
    let without = write(&means, dir.path(), "without.exr");
    let bits = |p: &Path| {
        let fb = FrameBuffers::read(p).unwrap();
        ["R", "G", "B"]
            .map(|c| fb.channel(&format!("denoised.{c}")).unwrap().iter().map(|v| v.to_bits()).collect::<Vec<_>>())
    };
    for (input, picked) in [(&with, "balanced"), (&without, "spatial")] {
        let auto = dir.path().join("auto.exr");
        let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", auto.to_str().unwrap(), "-v"]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        assert!(text(&o.stdout).contains(&format!("--model auto: `{picked}`")), "{}", text(&o.stdout));
        // -v also says where the time went.
        let stages = ["read ", "features ", "network ", "write "];
        assert!(stages.iter().all(|s| text(&o.stdout).contains(s)), "{}", text(&o.stdout));
        let named = dir.path().join("named.exr");
        let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", named.to_str().unwrap(), "-q", "--model", picked]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        assert_eq!(bits(&auto), bits(&named), "{}: auto is not `{picked}`", input.display());
    }
    // `spatial` is always fed spatial estimates: the file's own variances change nothing.
    let outs = [&with, &without].map(|input| {
        let out = dir.path().join(format!("spatial-{}", input.file_name().unwrap().to_string_lossy()));
        let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q", "--model", "spatial"]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        bits(&out)
    });
    assert_eq!(outs[0], outs[1]);
}

#[test]
fn quality_names_a_rung_of_the_ladder_and_refuses_a_model_beside_it() {
    let dir = tempfile::tempdir().unwrap();
    let input = write(&native_frame(40, 24, 6, &[]), dir.path(), "in.exr");
    let bits = |p: &Path| {
        let fb = FrameBuffers::read(p).unwrap();
        fb.channel("denoised.G").unwrap().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    let mut seen = Vec::new();
    for rung in ["fast", "balanced", "high"] {
        let (q, m) = (dir.path().join(format!("q-{rung}.exr")), dir.path().join(format!("m-{rung}.exr")));
        let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", q.to_str().unwrap(), "-q", "--quality", rung]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", m.to_str().unwrap(), "-q", "--model", rung]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        assert_eq!(bits(&q), bits(&m), "--quality {rung} is --model {rung}");
        seen.push(bits(&q));
    }
    assert!(seen[0] != seen[1] && seen[1] != seen[2], "three different models");
    let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", "x.exr", "--quality", "fast", "--model", "default"]);
    assert!(!o.status.success() && text(&o.stderr).contains("--quality"), "{}", text(&o.stderr));
}

#[test]
fn model_bound_rewrites_each_branchs_bound_and_info_shows_them() {
    // The shipped `high` is unbounded; bounded, then lifted again (`kpcn model info` prints
    // the bounds either way; `model::tests` checks that the weights stay bit for bit).
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let (bounded, both, lifted) =
        (path("high-bounded.safetensors"), path("high-both.safetensors"), path("lifted.safetensors"));
    let bound = |model: &str, branch: &str, errors: &str, out: &str| {
        let o = kpcn(&["model", "bound", model, "--branch", branch, "--errors", errors, "-o", out]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&kpcn(&["model", "info", out]).stdout)
    };
    let info = bound("high", "specular", "3", &bounded);
    assert!(info.contains("moved at most 3 standard errors") && info.contains("diffuse       unbounded"), "{info}");
    let info = bound(&bounded, "diffuse", "2", &both);
    assert!(info.contains("moved at most 3") && info.contains("brightened at most 2 standard errors"), "{info}");
    let info = bound(&both, "specular", "0", &lifted);
    assert!(info.contains("specular      unbounded") && info.contains("brightened at most 2"), "{info}");
    let out = kpcn(&["model", "bound", "high", "--errors", "2", "-o", "x.safetensors"]);
    assert!(!out.status.success() && text(&out.stderr).contains("--branch"), "{}", text(&out.stderr));
    let out = kpcn(&[
        "model",
        "bound",
        "no-such-model.safetensors",
        "--branch",
        "diffuse",
        "--errors",
        "2",
        "-o",
        "x.safetensors",
    ]);
    assert!(!out.status.success() && text(&out.stderr).contains("no-such-model.safetensors: cannot read the model"));
    // The diffuse ceiling's take dropped (the default's), or spread; only a diffuse ceiling
    // has one.
    assert!(info.contains("what the ceiling takes is dropped"), "{info}");
    let spread = path("spread.safetensors");
    let o = kpcn(&["model", "bound", &both, "--branch", "diffuse", "--errors", "1", "--spread", "7", "-o", &spread]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let info = text(&kpcn(&["model", "info", &spread]).stdout);
    assert!(info.contains("brightened at most 1") && info.contains("spread over the 15×15 window"), "{info}");
    for args in [["--branch", "specular", "--errors", "2"], ["--branch", "diffuse", "--errors", "0"]] {
        let out = kpcn(&[&["model", "bound", &both][..], &args, &["--spread", "7", "-o", "x.safetensors"]].concat());
        assert!(!out.status.success() && text(&out.stderr).contains("--spread spreads"), "{}", text(&out.stderr));
    }
    let out = kpcn(&[
        "model",
        "bound",
        &both,
        "--branch",
        "diffuse",
        "--errors",
        "1",
        "--spread",
        "16",
        "-o",
        "x.safetensors",
    ]);
    assert!(!out.status.success() && text(&out.stderr).contains("at most 15"), "{}", text(&out.stderr));
    // The diffuse detail restored, or not; at most 15 px.
    let detail = path("detail.safetensors");
    let o = kpcn(&["model", "detail", &both, "--radius", "7", "-o", &detail]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let info = text(&kpcn(&["model", "info", &detail]).stdout);
    assert!(info.contains("brightened at most 2") && info.contains("restored over 15×15 windows"), "{info}");
    let o = kpcn(&["model", "detail", &detail, "--radius", "0", "-o", &detail]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(!text(&kpcn(&["model", "info", &detail]).stdout).contains("restored over"));
    let out = kpcn(&["model", "detail", &both, "--radius", "16", "-o", "x.safetensors"]);
    assert!(!out.status.success() && text(&out.stderr).contains("at most 15"), "{}", text(&out.stderr));
}

#[test]
fn no_help_text_shows_rustdoc_markup() {
    // Doc comments are both the API docs and `--help`: a rustdoc link there reads as
    // noise to a user.
    fn commands(help: &str) -> Vec<String> {
        let listed = help.lines().skip_while(|l| !l.starts_with("Commands:")).skip(1);
        // A command's line starts with two spaces; its description's wrapped lines with more.
        let named = listed.take_while(|l| !l.trim().is_empty()).filter(|l| !l.starts_with("   "));
        let names = named.filter_map(|l| l.split_whitespace().next());
        names.filter(|n| *n != "help").map(str::to_owned).collect()
    }
    let help = |path: &[String]| {
        let mut args: Vec<&str> = path.iter().map(String::as_str).collect();
        args.push("--help");
        let out = kpcn(&args);
        assert!(out.status.success(), "kpcn {}", args.join(" "));
        text(&out.stdout)
    };
    let mut todo = vec![Vec::new()];
    let mut seen = 0;
    while let Some(path) = todo.pop() {
        let page = help(&path);
        for markup in ["[`", "](crate::", "](super::"] {
            assert!(!page.contains(markup), "`kpcn {} --help` shows {markup}:\n{page}", path.join(" "));
        }
        seen += 1;
        todo.extend(commands(&page).into_iter().map(|c| [path.clone(), vec![c]].concat()));
    }
    assert!(seen >= 8, "only {seen} help pages");
}

#[test]
fn denoise_keeps_every_input_channel_and_adds_the_layers() {
    let dir = tempfile::tempdir().unwrap();
    let mut inputs = vec![write(&native_frame(24, 16, 1, &[]), dir.path(), "in.exr")];
    if let Some(dev) = cycles_dev() {
        inputs.push(dev.join("interior-00004spp.exr"));
    }
    for input in inputs {
        let out = dir.path().join("out.exr");
        let r = kpcn(&[
            "denoise",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--aovs",
            "-q",
            "--model",
            "small",
            "--allow-untrained",
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let a = FrameBuffers::read(&input).unwrap();
        let b = FrameBuffers::read(&out).unwrap();
        for p in a.planes() {
            assert_eq!(b.channel(&p.name), Some(p.data.as_slice()), "{} kept", p.name);
        }
        assert_eq!(b.planes().len(), a.planes().len() + 9);
        assert!(b.channel("denoised_specular.G").is_some());
        assert!(b.attribute("kpcn:model").unwrap().contains("untrained"));
    }
}

#[test]
fn denoise_runs_a_sequence_and_reports_bad_frames() {
    let dir = tempfile::tempdir().unwrap();
    for f in 1..=5 {
        write(&native_frame(16, 12, f, &[]), dir.path(), &format!("render.{f:04}.exr"));
    }
    let pattern = dir.path().join("render.####.exr");
    let out = dir.path().join("den.%04d.exr");
    let (i, o) = (pattern.to_str().unwrap(), out.to_str().unwrap());
    let dry = kpcn(&["denoise", i, "-o", o, "-n"]);
    assert_eq!(String::from_utf8_lossy(&dry.stdout).lines().count(), 5);
    assert!(!dir.path().join("den.0001.exr").exists(), "a dry run writes nothing");

    // A budget of twice the default keeps two frames in flight (each within half of it).
    let r = kpcn(&["denoise", i, "-o", o, "-q", "--max-memory", "1024"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    // Frames in flight together give what one frame alone does.
    for f in 1..=5 {
        let single = dir.path().join("single.exr");
        let input = dir.path().join(format!("render.{f:04}.exr"));
        let r = kpcn(&["denoise", input.to_str().unwrap(), "-o", single.to_str().unwrap(), "-q"]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let (a, b) = (
            FrameBuffers::read(&single).unwrap(),
            FrameBuffers::read(&dir.path().join(format!("den.{f:04}.exr"))).unwrap(),
        );
        for c in ["denoised.R", "denoised.G", "denoised.B"] {
            let bits = |fb: &FrameBuffers| fb.channel(c).unwrap().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert!(bits(&a) == bits(&b), "frame {f}: {c} differs from the frame denoised alone");
        }
    }
    // Frame 3 corrupt: fail fast stops there; --skip-bad-frames goes on and reports it.
    std::fs::write(dir.path().join("render.0003.exr"), b"garbage").unwrap();
    let o2 = dir.path().join("two.@@@@.exr");
    let r = kpcn(&["denoise", i, "-o", o2.to_str().unwrap(), "--frames", "1-5", "-q", "--max-memory", "1024"]);
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("render.0003.exr"));
    assert!(!dir.path().join("two.0004.exr").exists(), "fail fast");
    let r = kpcn(&["denoise", i, "-o", o2.to_str().unwrap(), "--frames", "1-5x2", "--skip-bad-frames", "-q"]);
    assert_eq!(r.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&r.stderr).contains("1 of 3 frames failed"),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    assert!(dir.path().join("two.0005.exr").is_file());
}

#[test]
fn denoise_warns_about_untrained_models_and_estimated_variance() {
    let dir = tempfile::tempdir().unwrap();
    let input = write(&native_frame(8, 8, 2, &["diffuseVariance", "diffuseA"]), dir.path(), "in.exr");
    let out = dir.path().join("o.exr");
    let r = kpcn(&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--model", "small"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "untrained presets need --allow-untrained: {err}");
    assert!(err.contains("--allow-untrained") && !out.exists(), "{err}");
    // Not hidden by -q either.
    let r = kpcn(&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--model", "small", "-q"]);
    assert_eq!(r.status.code(), Some(2));
    let r = kpcn(&[
        "denoise",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--model",
        "small",
        "--allow-untrained",
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{err}");
    assert!(err.contains("UNTRAINED"), "{err}");
    // The shipped flat model has a name of its own.
    let r = kpcn(&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--model", "small-flat", "-q"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(err.contains("diffuse (spatially"), "{err}");
}
