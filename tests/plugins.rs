//! Host plugins on the C ABI, built and run in their real hosts, headless.

use super::capi::{EXAMPLE, prefix, root, run};
use kpcn::io::FrameBuffers;
use std::path::Path;
use std::process::Command;

/// `oiiotool FRAME.exr.kpcn` through `kpcn.imageio.so` gives exactly `kpcn denoise`'s layer
/// (`idiff` passes with no tolerance), and a bad configuration is an error naming it.
#[test]
fn oiio_plugin_denoises_inside_oiiotool() {
    let dir = tempfile::tempdir().unwrap();
    let plugins = dir.path().join("plugins");
    run(Command::new(root().join("plugins/oiio/build.sh"))
        .arg(&plugins)
        .env("PKG_CONFIG_PATH", prefix().join("lib/pkgconfig")));
    let oiiotool = |args: &[&str]| {
        Command::new("oiiotool").args(args).env("OIIO_LIBRARY_PATH", &plugins).output().expect("oiiotool runs")
    };
    let den = dir.path().join("den.exr");
    let input = format!("{EXAMPLE}.kpcn");
    let out = oiiotool(&[&input, "-o", den.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    let cli = dir.path().join("cli.exr");
    run(Command::new(env!("CARGO_BIN_EXE_kpcn")).args(["denoise", EXAMPLE, "--separate", "-q", "-o"]).arg(&cli));
    let idiff = run(Command::new("idiff").args(["-fail", "0", "-warn", "0"]).arg(&den).arg(&cli));
    assert!(idiff.contains("PASS"), "{idiff}");

    let info = oiiotool(&["--info", "-v", &input]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("160 x   96, 3 channel, float kpcn") && text.contains("R, G, B"), "{text}");

    // A model that does not exist fails the read, with the library's message.
    let bad = oiiotool(&["--iconfig", "kpcn:model", "/nonexistent/m.safetensors", &input, "-o", den.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("/nonexistent/m.safetensors"), "{err}");
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
