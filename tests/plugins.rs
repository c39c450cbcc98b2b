//! Host plugins on the C ABI, built and run in their real hosts, headless.

use super::capi::{EXAMPLE, prefix, root, run};
use kpcn::io::FrameBuffers;
use std::path::Path;
use std::process::Command;

/// `oiiotool FRAME.exr.kpcn` through `kpcn.imageio.so` gives exactly `kpcn denoise`'s layer
/// (`idiff` passes with no tolerance), denoising once per command however often OIIO opens
/// the file (none for a header), and a bad configuration is oiiotool's own error naming it.
#[test]
fn oiio_plugin_denoises_inside_oiiotool() {
    let dir = tempfile::tempdir().unwrap();
    let plugins = dir.path().join("plugins");
    run(Command::new(root().join("plugins/oiio/build.sh"))
        .arg(&plugins)
        .env("PKG_CONFIG_PATH", prefix().join("lib/pkgconfig")));
    let host = |program: &str, args: &[&str]| {
        Command::new(program)
            .args(args)
            .env("OIIO_LIBRARY_PATH", &plugins)
            .env("KPCN_IMAGEIO_VERBOSE", "1")
            .output()
            .expect("the OIIO tool runs")
    };
    let oiiotool = |args: &[&str]| host("oiiotool", args);
    let denoises = |o: &std::process::Output| String::from_utf8_lossy(&o.stderr).matches("kpcn: denoised ").count();
    let den = dir.path().join("den.exr");
    let input = format!("{EXAMPLE}.kpcn");
    let out = oiiotool(&[&input, "-o", den.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(denoises(&out), 1, "{}", String::from_utf8_lossy(&out.stderr));
    // The README's configured command, the same input twice, and a header: once, once, none.
    let conf = ["--iconfig", "kpcn:model", "balanced", "--iconfig", "kpcn:threads", "2"];
    let out = oiiotool(&[&conf[..], &[input.as_str(), "-o", den.to_str().unwrap()]].concat());
    assert_eq!(denoises(&out), 1, "{}", String::from_utf8_lossy(&out.stderr));
    let sum = dir.path().join("sum.exr");
    let out = oiiotool(&[&input, &input, "--add", "-o", sum.to_str().unwrap()]);
    assert!(out.status.success() && denoises(&out) == 1, "{}", String::from_utf8_lossy(&out.stderr));
    let info = host("iinfo", &[&input]);
    assert!(info.status.success() && denoises(&info) == 0, "{}", String::from_utf8_lossy(&info.stderr));
    let out = oiiotool(&[&input, "-o", den.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    let cli = dir.path().join("cli.exr");
    run(Command::new(env!("CARGO_BIN_EXE_kpcn")).args(["denoise", EXAMPLE, "--separate", "-q", "-o"]).arg(&cli));
    let idiff = run(Command::new("idiff").args(["-fail", "0", "-warn", "0"]).arg(&den).arg(&cli));
    assert!(idiff.contains("PASS"), "{idiff}");

    let info = oiiotool(&["--info", "-v", &input]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("160 x   96, 3 channel, float kpcn") && text.contains("R, G, B"), "{text}");

    // A model that does not exist fails the read, with the library's message in oiiotool's.
    let bad = oiiotool(&["--iconfig", "kpcn:model", "/nonexistent/m.safetensors", &input, "-o", den.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success() && err.contains("oiiotool ERROR: read") && err.contains("/nonexistent/m.safetensors"),
        "{err}"
    );
    // A file the library refuses (no diffuse, albedo, …): the library's message is
    // oiiotool's own error, not "File does not exist".
    let rgb = dir.path().join("rgb.exr");
    run(Command::new("oiiotool").args([EXAMPLE, "--ch", "R,G,B", "-o"]).arg(&rgb));
    let bad = oiiotool(&[&format!("{}.kpcn", rgb.display()), "-o", den.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success() && err.contains("ERROR: read") && err.contains("missing channels diffuse.R"),
        "{err}"
    );
    // Nothing is left in the temporary directory.
    let temp = std::env::temp_dir();
    let pid_files = std::fs::read_dir(&temp).unwrap().filter_map(|e| e.ok()).filter(|e| {
        e.file_name().to_string_lossy().starts_with("kpcn-imageio-")
            && Path::new(&e.path())
                .metadata()
                .is_ok_and(|m| m.modified().is_ok_and(|t| t.elapsed().is_ok_and(|d| d.as_secs() < 60)))
    });
    assert_eq!(pid_files.count(), 0, "temporary files left in {}", temp.display());
}

/// The ImageBuf helper (`plugins/oiio/kpcn_imagebuf.h`) in a C++ tool: half ImageBufs
/// picked by channel name give exactly `kpcn denoise` (`auto`: `spatial` on passes without
/// variances) on the same passes.
#[test]
fn oiio_imagebuf_helper_matches_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let exe = dir.path().join("imagebuf_test");
    let lib = prefix().join("lib");
    let flags = run(Command::new("pkg-config")
        .args(["--cflags", "--libs", "kpcn", "OpenImageIO"])
        .env("PKG_CONFIG_PATH", lib.join("pkgconfig")));
    run(Command::new("g++")
        .args(["-std=c++17", "-Wall", "-Wextra", "-Werror", "-Wno-deprecated-declarations"])
        .arg("-I")
        .arg(root().join("plugins/oiio"))
        .arg(root().join("tests/c/imagebuf_test.cpp"))
        .arg("-o")
        .arg(&exe)
        .args(flags.split_whitespace())
        .arg(format!("-Wl,-rpath,{}", lib.display())));
    let cli = cli_on_passes(dir.path(), "auto");
    let out = dir.path().join("out.exr");
    let text = run(Command::new(&exe).arg(dir.path().join("passes.exr")).arg(&out));
    assert!(text.contains("ok"), "{text}");
    let got = FrameBuffers::read(&out).unwrap();
    for c in ["R", "G", "B"] {
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(bits(got.channel(c).unwrap()) == bits(cli.channel(&format!("denoised.{c}")).unwrap()), "{c} differs");
    }
}

/// Debian's Blender renders a tiny Cycles scene at 4 spp with the add-on enabled: each
/// written multilayer EXR gets `ViewLayer.Denoised` in place with every pass kept, the
/// compositor's Image node lists it, "Denoise Last Render" works, and both results equal
/// `kpcn denoise` on the same file bit for bit.
#[test]
fn blender_addon_denoises_renders_in_blender() {
    let dir = tempfile::tempdir().unwrap();
    let addons = dir.path().join("scripts/addons");
    std::fs::create_dir_all(&addons).unwrap();
    std::fs::copy(root().join("plugins/blender/kpcn_denoise.py"), addons.join("kpcn_denoise.py")).unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let log = run(Command::new("blender")
        .args(["-b", "--factory-startup", "--python"])
        .arg(root().join("tests/blender/render.py"))
        .arg("--")
        .arg(&out)
        .env("BLENDER_USER_SCRIPTS", dir.path().join("scripts"))
        .env("KPCN_LIBRARY", prefix().join("lib")));
    assert!(log.contains("kpcn-test: done") && log.contains("kpcn: denoised"), "{log}");

    for name in ["frame_0001.exr", "operator.exr"] {
        let file = out.join(name);
        let fb = FrameBuffers::read(&file).unwrap();
        for pass in ["Combined.A", "Depth.Z", "DiffCol.R", "DiffDir.R", "DiffInd.R", "Normal.X", "Denoised.R"] {
            assert!(fb.channel(&format!("ViewLayer.{pass}")).is_some(), "{name} lacks ViewLayer.{pass}");
        }
        let cli = dir.path().join("cli.exr");
        run(Command::new(env!("CARGO_BIN_EXE_kpcn"))
            .args(["denoise", "--separate", "--layer", "cli", "-q", "-o"])
            .arg(&cli)
            .arg(&file));
        let cli = FrameBuffers::read(&cli).unwrap();
        for c in ["R", "G", "B"] {
            let ours = fb.channel(&format!("ViewLayer.Denoised.{c}")).unwrap();
            assert!(ours.iter().all(|v| v.is_finite()), "{name}: non-finite denoised samples");
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert!(bits(ours) == bits(cli.channel(&format!("cli.{c}")).unwrap()), "{name}: {c} differs from the CLI");
        }
    }
}

/// The passes a compositor or C++ tool has (no variances), by clip name: channels of the
/// example frame.
const PASSES: [(&str, &[&str]); 5] = [
    ("Source", &["R", "G", "B"]),
    ("Diffuse", &["diffuse.R", "diffuse.G", "diffuse.B"]),
    ("Albedo", &["albedo.R", "albedo.G", "albedo.B"]),
    ("Normal", &["normal.R", "normal.G", "normal.B"]),
    ("Depth", &["depth.Z"]),
];

/// Writes the example's [`PASSES`] to `dir/passes.exr` and returns `kpcn denoise
/// --separate --model MODEL` of it: variances estimated, specular derived, as for a host
/// without them (`auto` picks `spatial` there).
fn cli_on_passes(dir: &Path, model: &str) -> FrameBuffers {
    let fb = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
    let keep: Vec<&str> = PASSES.iter().flat_map(|(_, names)| names.iter().copied()).collect();
    let passes = dir.join("passes.exr");
    fb.select(&keep).unwrap().write(&passes, &Default::default()).unwrap();
    let cli = dir.join("cli.exr");
    run(Command::new(env!("CARGO_BIN_EXE_kpcn"))
        .args(["denoise", "--model", model, "--separate", "-q", "-o"])
        .arg(&cli)
        .arg(&passes));
    FrameBuffers::read(&cli).unwrap()
}

/// Writes `planes` (RGB, or 1 for depth) as a raw float RGBA image, rows bottom-up as OFX
/// lays them out.
fn write_ofx_rgba(path: &Path, planes: &[&[f32]], w: usize, h: usize) {
    let mut out = Vec::with_capacity(w * h * 16);
    for y in (0..h).rev() {
        for x in 0..w {
            for c in 0..4 {
                let v = planes.get(c).map_or(if c == 3 { 1.0 } else { 0.0 }, |p| p[y * w + x]);
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    std::fs::write(path, out).unwrap();
}

/// `kpcn.ofx` in a headless OpenFX host built on the OFX Association's HostSupport
/// (openfx-sys's sources): the general context with every optional clip, rows bottom-up,
/// gives exactly `kpcn denoise` on the same passes; the host's abort check cancels, leaving
/// the output untouched.
#[test]
fn openfx_plugin_renders_in_a_hostsupport_host() {
    let dir = tempfile::tempdir().unwrap();
    let pc = prefix().join("lib/pkgconfig");
    run(Command::new(root().join("plugins/openfx/build.sh"))
        .arg(dir.path().join("plugins"))
        .env("PKG_CONFIG_PATH", &pc));
    let host = dir.path().join("host");
    run(Command::new(root().join("tests/openfx/build-host.sh")).arg(&host));

    // The example's passes without its variances (a compositor has none), as clips and as
    // a native-layout EXR for the CLI.
    let fb = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
    let (w, h) = (fb.width(), fb.height());
    let images = dir.path().join("images");
    std::fs::create_dir_all(&images).unwrap();
    for (clip, names) in PASSES {
        let planes: Vec<&[f32]> = names.iter().map(|n| fb.channel(n).unwrap()).collect();
        write_ofx_rgba(&images.join(format!("{clip}.f32")), &planes, w, h);
    }
    let cli = cli_on_passes(dir.path(), "auto");

    let ofx_host = |extra: &[&str]| {
        let out = Command::new(host.join("ofx_host"))
            .args([w.to_string(), h.to_string()])
            .arg(&images)
            .args(extra)
            .env("OFX_PLUGIN_PATH", dir.path().join("plugins"))
            .output()
            .expect("ofx_host runs");
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "{text}");
        let pixels: Vec<f32> = std::fs::read(images.join("Output.f32"))
            .unwrap()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        (text, pixels)
    };
    let (text, pixels) = ofx_host(&[]);
    assert!(text.contains("render: 0") && text.contains("abort checks: 1"), "{text}");

    for (c, name) in ["denoised.R", "denoised.G", "denoised.B"].iter().enumerate() {
        let want = cli.channel(name).unwrap();
        for y in 0..h {
            for x in 0..w {
                let got = pixels[((h - 1 - y) * w + x) * 4 + c];
                assert_eq!(got.to_bits(), want[y * w + x].to_bits(), "{name} at ({x}, {y})");
            }
        }
    }
    assert!(pixels.chunks_exact(4).all(|p| p[3] == 1.0), "alpha comes from Source");

    let (text, pixels) = ofx_host(&["abort"]);
    assert!(text.contains("render: 0"), "{text}");
    assert!(pixels.iter().all(|&v| v == 0.0), "an aborted render leaves the output untouched");
}
