//! The C ABI as C and C++ hosts see it: the generated header is current and compiles alone,
//! the library exports only `kpcn_*`, and C99/C++17 programs linked through pkg-config
//! (shared, static, and under AddressSanitizer) give exactly what `kpcn denoise` gives.

use kpcn::io::FrameBuffers;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

pub const EXAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/data/spheres-crop-00016spp.exr");

pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `cmd`, panicking with its output when it fails.
pub fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{cmd:?} failed ({}):\n{text}", out.status);
    text
}

/// `scripts/install.sh` into a scratch prefix, once per test run (the debug build).
pub fn prefix() -> &'static Path {
    static PREFIX: OnceLock<PathBuf> = OnceLock::new();
    PREFIX.get_or_init(|| {
        let p = Path::new(env!("CARGO_TARGET_TMPDIR")).join("capi-prefix");
        let _ = std::fs::remove_dir_all(&p);
        run(Command::new(root().join("scripts/install.sh")).arg(&p).env("KPCN_PROFILE", "dev"));
        p
    })
}

/// `pkg-config` against the scratch prefix.
fn pkg_config(args: &[&str]) -> Vec<String> {
    let pc = prefix().join("lib/pkgconfig");
    run(Command::new("pkg-config").args(args).arg("kpcn").env("PKG_CONFIG_PATH", pc))
        .split_whitespace()
        .map(String::from)
        .collect()
}

#[test]
fn header_is_current_and_exports_are_prefixed() {
    let header = root().join("include/kpcn.h");
    let fresh = Path::new(env!("CARGO_TARGET_TMPDIR")).join("kpcn.h");
    let cbindgen = Command::new("cbindgen")
        .current_dir(root())
        .args(["--config", "include/cbindgen.toml", "--quiet", "--output"])
        .arg(&fresh)
        .output()
        .expect("cbindgen runs (scripts/setup-debian.sh installs it with `cargo install cbindgen`)");
    assert!(cbindgen.status.success(), "cbindgen failed: {}", String::from_utf8_lossy(&cbindgen.stderr));
    let (now, want) = (std::fs::read_to_string(&header).unwrap_or_default(), std::fs::read_to_string(&fresh).unwrap());
    if std::env::var_os("KPCN_BLESS").is_some() {
        std::fs::write(&header, &want).unwrap();
    } else {
        assert!(now == want, "include/kpcn.h is stale: rerun with KPCN_BLESS=1 to regenerate it");
    }

    // Every exported function starts with kpcn_ and is declared in the header.
    let so = prefix().join("lib/libkpcn.so");
    let nm = run(Command::new("nm").args(["-D", "--defined-only"]).arg(&so));
    let exported: Vec<&str> = nm.lines().filter_map(|l| l.split_whitespace().nth(2)).collect();
    assert!(exported.len() >= 14, "{nm}");
    for sym in &exported {
        assert!(sym.starts_with("kpcn_"), "libkpcn.so exports `{sym}`");
        let declared = [" ", "*"].iter().any(|before| want.contains(&format!("{before}{sym}(")));
        assert!(declared, "`{sym}` is exported but not in kpcn.h");
    }
    let readelf = run(Command::new("readelf").arg("-d").arg(&so));
    assert!(readelf.contains(&format!("Library soname: [libkpcn.so.{}]", env!("KPCN_ABI"))), "{readelf}");
    run(Command::new("pkg-config").args(["--validate", "kpcn"]).env("PKG_CONFIG_PATH", prefix().join("lib/pkgconfig")));

    // The header compiles alone, as C and as C++.
    for (cc, lang, std) in [("gcc", "c", "-std=c99"), ("g++", "c++", "-std=c++17")] {
        run(Command::new(cc)
            .args(["-fsyntax-only", "-Wall", "-Wextra", "-Werror", "-pedantic", std, "-x", lang])
            .arg(&header));
    }
}

/// The example frame's inputs as the raw arrays `tests/c/capi_test.c` reads.
fn write_inputs(dir: &Path) -> (usize, usize) {
    let fb = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
    let (w, h) = (fb.width(), fb.height());
    let ch = |n: &str| fb.channel(n).unwrap_or_else(|| panic!("example has {n}"));
    let interleave = |names: [String; 3]| -> Vec<f32> {
        let planes = names.map(|n| ch(&n));
        (0..w * h).flat_map(|i| planes.map(|p| p[i])).collect()
    };
    let rgb = |layer: &str| {
        interleave(["R", "G", "B"].map(|c| if layer.is_empty() { c.to_string() } else { format!("{layer}.{c}") }))
    };
    let f32s = |name: &str, v: &[f32]| {
        std::fs::write(dir.join(name), v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>()).unwrap()
    };
    f32s("color.f32", &rgb(""));
    for l in ["diffuse", "specular", "normal"] {
        f32s(&format!("{l}.f32"), &rgb(l));
    }
    f32s("depth.f32", ch("depth.Z"));
    for q in ["color", "diffuse", "specular", "albedo", "normal", "depth"] {
        f32s(&format!("{q}Variance.f32"), ch(&format!("{q}Variance.Z")));
    }
    let albedo: Vec<u8> = rgb("albedo").iter().flat_map(|&v| half::f16::from_f32(v).to_bits().to_le_bytes()).collect();
    std::fs::write(dir.join("albedo.f16"), albedo).unwrap();
    (w, h)
}

fn read_f32(path: &Path) -> Vec<f32> {
    std::fs::read(path).unwrap().chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect()
}

/// `kpcn denoise --aovs` of the example: the reference every C result must equal.
fn cli_result(dir: &Path) -> FrameBuffers {
    let out = dir.join("cli.exr");
    run(Command::new(env!("CARGO_BIN_EXE_kpcn")).args(["denoise", EXAMPLE, "--aovs", "-q", "-o"]).arg(&out));
    FrameBuffers::read(&out).unwrap()
}

/// Layer `layer` of `fb` interleaved as RGB, as bit patterns.
fn layer_bits(fb: &FrameBuffers, layer: &str) -> Vec<u32> {
    let planes = ["R", "G", "B"].map(|c| fb.channel(&format!("{layer}.{c}")).unwrap().to_vec());
    (0..fb.width() * fb.height()).flat_map(|i| planes.iter().map(move |p| p[i].to_bits())).collect()
}

/// Builds `tests/c/capi_test.c` with `link` flags and checks what it writes.
fn c_program(name: &str, extra: &[&str], link: Vec<String>, env: &[(&str, &str)]) {
    let dir = tempfile::tempdir().unwrap();
    let exe = dir.path().join(name);
    let mut cc = Command::new("gcc");
    cc.args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-g"])
        .args(extra)
        .arg(root().join("tests/c/capi_test.c"))
        .arg("-o")
        .arg(&exe)
        .args(pkg_config(&["--cflags"]))
        .args(link)
        .arg("-lpthread");
    let t = std::time::Instant::now();
    run(&mut cc);
    eprintln!("{name}: built in {:.1} s", t.elapsed().as_secs_f64());
    let (w, h) = write_inputs(dir.path());
    let text = run(Command::new(&exe)
        .arg(dir.path())
        .arg(w.to_string())
        .arg(h.to_string())
        .arg(EXAMPLE)
        .envs(env.iter().copied()));
    assert!(text.contains("all checks passed"), "{text}");
    eprintln!("{name}: ran in {:.1} s", t.elapsed().as_secs_f64());

    let cli = cli_result(dir.path());
    for (file, layer) in [
        ("output.f32", "denoised"),
        ("outputDiffuse.f32", "denoised_diffuse"),
        ("outputSpecular.f32", "denoised_specular"),
    ] {
        let got: Vec<u32> = read_f32(&dir.path().join(file)).iter().map(|v| v.to_bits()).collect();
        assert!(got == layer_bits(&cli, layer), "{name}: {file} differs from kpcn denoise's {layer}");
    }
    let file = FrameBuffers::read(&dir.path().join("file.exr")).unwrap();
    assert!(layer_bits(&file, "denoised") == layer_bits(&cli, "denoised"), "{name}: kpcn_denoise_file differs");
    assert_eq!(file.channel_names().count(), 38 + 3, "a copy of every input channel plus the denoised layer");
}

#[test]
fn c99_program_linked_to_the_shared_library_matches_the_cli() {
    let lib = prefix().join("lib");
    let mut link = pkg_config(&["--libs"]);
    link.push(format!("-Wl,-rpath,{}", lib.display()));
    c_program("shared", &[], link, &[]);
}

#[test]
fn c99_program_linked_to_the_static_library_matches_the_cli() {
    // The static archive by name, then what it needs (Libs.private, Requires.private).
    let link = pkg_config(&["--libs", "--static"])
        .into_iter()
        .map(|f| if f == "-lkpcn" { "-l:libkpcn.a".to_string() } else { f })
        .collect();
    c_program("static", &[], link, &[]);
}

#[test]
fn c99_program_runs_clean_under_address_and_undefined_sanitizers() {
    let lib = prefix().join("lib");
    let mut link = pkg_config(&["--libs"]);
    link.push(format!("-Wl,-rpath,{}", lib.display()));
    c_program(
        "asan",
        &["-fsanitize=address,undefined", "-fno-omit-frame-pointer", "-fno-sanitize-recover=all"],
        link,
        &[("ASAN_OPTIONS", "detect_leaks=1:abort_on_error=0:exitcode=23"), ("UBSAN_OPTIONS", "halt_on_error=1")],
    );
}

#[test]
fn cpp17_program_denoises_a_file_through_pkg_config() {
    let dir = tempfile::tempdir().unwrap();
    let exe = dir.path().join("cpp");
    let lib = prefix().join("lib");
    run(Command::new("g++")
        .args(["-std=c++17", "-Wall", "-Wextra", "-Werror", "-pedantic"])
        .arg(root().join("tests/c/capi_test.cpp"))
        .arg("-o")
        .arg(&exe)
        .args(pkg_config(&["--cflags", "--libs"]))
        .arg(format!("-Wl,-rpath,{}", lib.display())));
    let out = dir.path().join("cpp.exr");
    let text = run(Command::new(&exe).arg(EXAMPLE).arg(&out));
    assert!(text.contains("ok"), "{text}");
    let cli = cli_result(dir.path());
    let got = FrameBuffers::read(&out).unwrap();
    for layer in ["denoised", "denoised_diffuse", "denoised_specular"] {
        assert!(layer_bits(&got, layer) == layer_bits(&cli, layer), "{layer} differs from kpcn denoise --aovs");
    }
    assert_eq!(got.channel_names().count(), 9, "--separate: only the new layers");
}

/// The crate C hosts link (`--no-default-features`) pulls in none of the tools' crates.
#[test]
fn the_library_core_depends_on_no_tool_crates() {
    let tree = run(Command::new("cargo").current_dir(root()).args([
        "tree",
        "--locked",
        "--offline",
        "-e",
        "normal",
        "--no-default-features",
        "--prefix",
        "none",
    ]));
    assert!(tree.contains("candle-core"), "{tree}");
    for tool in ["clap", "indicatif", "anyhow", "plotters", "ctrlc"] {
        assert!(!tree.lines().any(|l| l.starts_with(&format!("{tool} v"))), "the core depends on {tool}:\n{tree}");
    }
}

/// `tests/c/integrity_test.c`: the file call never erases or overwrites a render (output =
/// input or a link to it, colliding or empty layer names, a struct of another ABI), writes
/// in place only when asked, keeps a uint id channel bit for bit, and a frame too large
/// for the address space fails with `KPCN_ERROR_OUT_OF_MEMORY` instead of aborting the
/// host. Linked with pkg-config's flags alone: they carry the rpath it runs with.
#[test]
fn c_hosts_cannot_erase_a_render_and_out_of_memory_is_a_status() {
    use kpcn::io::{SampleFormat, WriteOptions};
    let dir = tempfile::tempdir().unwrap();
    let exe = dir.path().join("integrity");
    run(Command::new("gcc")
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-g"])
        .arg(root().join("tests/c/integrity_test.c"))
        .arg("-o")
        .arg(&exe)
        .args(pkg_config(&["--cflags", "--libs"])));
    let mut fb = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
    let ids: Vec<u32> = (0..fb.width() as u32 * fb.height() as u32).map(|i| i.wrapping_mul(2654435761) | 1).collect();
    fb.insert("objectId.id", SampleFormat::Uint, ids.iter().map(|&i| f32::from_bits(i)).collect()).unwrap();
    let with_ids = dir.path().join("ids.exr");
    fb.write(&with_ids, &WriteOptions::default()).unwrap();
    let text = run(Command::new(&exe).arg(dir.path()).arg(EXAMPLE).arg(&with_ids));
    assert!(text.contains("all checks passed"), "{text}");
    let out = FrameBuffers::read(&dir.path().join("ids-denoised.exr")).unwrap();
    assert!(out.channel("objectId.id").unwrap().iter().map(|v| v.to_bits()).eq(ids.iter().copied()), "ids kept");
}
