//! Issue 25's integrity guards through the `kpcn` binary, on real files: no channel lost or
//! retyped, no pass overwritten, no input that hangs, no abort when memory runs out. The C
//! ABI's side is `tests/c/integrity_test.c` (run by `tests/capi.rs`).

use kpcn::io::{FrameBuffers, FrameReader, SampleFormat, WriteOptions};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const EXAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/data/spheres-crop-00016spp.exr");

fn kpcn(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kpcn")).args(args).output().expect("kpcn runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The example frame with `edit` applied, written to `dir/name`.
fn edited(dir: &Path, name: &str, edit: impl FnOnce(&mut FrameBuffers)) -> PathBuf {
    let mut fb = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
    edit(&mut fb);
    let p = dir.join(name);
    fb.write(&p, &WriteOptions::default()).unwrap();
    p
}

/// `oiiotool`'s own word on a channel's format (an independent reader).
fn oiio_format(path: &Path, channel: &str) -> String {
    let out = Command::new("iinfo").arg("-v").arg(path).output().expect("iinfo runs (openimageio-tools)");
    let text = String::from_utf8_lossy(&out.stdout);
    let list = text.lines().find(|l| l.contains("channel list")).unwrap_or_default().to_string();
    let at = list.find(&format!("{channel} (")).unwrap_or_else(|| panic!("{channel} not in {list}"));
    list[at + channel.len() + 2..].split(')').next().unwrap().to_string()
}

/// Object ids (uint), halves and floats come back with their type and every bit, with and
/// without `--separate`/`--in-place`. Before the fix an id of 2654435761 came back as the
/// float 0.618 and 15359 of 15360 ids were lost.
#[test]
fn uint_half_and_float_channels_keep_their_type_and_bits() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = {
        let fb = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
        (fb.width(), fb.height())
    };
    let ids: Vec<u32> = (0..(w * h) as u64).map(|i| (i.wrapping_mul(2654435761) % (1 << 32)) as u32 | 1).collect();
    let input = edited(dir.path(), "ids.exr", |fb| {
        fb.insert("objectId.id", SampleFormat::Uint, ids.iter().map(|&i| f32::from_bits(i)).collect()).unwrap();
        let floats: Vec<f32> = (0..w * h).map(|i| i as f32 * 1.000_001).collect();
        fb.insert("mask.A", SampleFormat::Float, floats).unwrap();
    });
    assert_eq!(oiio_format(&input, "objectId.id"), "uint", "the input really holds uint ids");
    let before = FrameBuffers::read(&input).unwrap();
    let out = dir.path().join("out.exr");
    let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let after = FrameBuffers::read(&out).unwrap();
    assert_eq!(oiio_format(&out, "objectId.id"), "uint");
    assert_eq!(oiio_format(&out, "albedo.R"), "half");
    assert_eq!(oiio_format(&out, "mask.A"), "float");
    let got: Vec<u32> = after.channel("objectId.id").unwrap().iter().map(|v| v.to_bits()).collect();
    assert!(got == ids, "every id kept");
    for name in before.channel_names() {
        let (a, b) = (before.channel(name).unwrap(), after.channel(name).unwrap());
        assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "{name} kept bit for bit");
    }
    // In place too (the render keeps its ids).
    let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", input.to_str().unwrap(), "--in-place", "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let again = FrameBuffers::read(&input).unwrap();
    assert!(again.channel("objectId.id").unwrap().iter().map(|v| v.to_bits()).eq(ids.iter().copied()));
}

/// A layer name that would overwrite a pass, or names nothing, is refused before any work,
/// in place or not; a file kpcn wrote may have its own earlier result replaced.
#[test]
fn a_layer_name_never_overwrites_a_pass() {
    let dir = tempfile::tempdir().unwrap();
    let input = edited(dir.path(), "in.exr", |_| {});
    let i = input.to_str().unwrap();
    let out = dir.path().join("out.exr");
    let o_s = out.to_str().unwrap();
    for (layer, extra, says) in [
        ("albedo", &[][..], "albedo.R"),
        ("albedo", &["--in-place"][..], "albedo.R"),
        ("diffuse", &["--aovs"][..], "diffuse.R"),
        ("", &[][..], "empty or malformed"),
        ("den.", &[][..], "empty or malformed"),
    ] {
        let target = if extra.contains(&"--in-place") { i } else { o_s };
        let o = kpcn(&[&["denoise", i, "-o", target, "--layer", layer, "-q"][..], extra].concat());
        assert_eq!(o.status.code(), Some(1), "--layer {layer:?} {extra:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(says), "--layer {layer:?}: {}", stderr(&o));
    }
    assert!(!out.exists());
    assert_eq!(FrameBuffers::read(&input).unwrap().channel_names().count(), 38, "the render is untouched");
    // kpcn's own earlier result is replaced, in place, as often as asked.
    for _ in 0..2 {
        let o = kpcn(&["denoise", i, "-o", i, "--in-place", "-q"]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    assert_eq!(FrameBuffers::read(&input).unwrap().channel_names().count(), 41);
}

/// Emission added to the beauty only, and a beauty named `rgba.*`: the output keeps what
/// the beauty holds beyond diffuse + specular (undenoised), and `-v` says so.
#[test]
fn what_the_beauty_holds_beyond_diffuse_and_specular_is_kept() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain.exr");
    let o = kpcn(&["denoise", EXAMPLE, "-o", plain.to_str().unwrap(), "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let w = FrameBuffers::read(Path::new(EXAMPLE)).unwrap().width();
    let in_box = |i: usize| (20..40).contains(&(i / w)) && (30..60).contains(&(i % w));
    let emitting = edited(dir.path(), "emit.exr", |fb| {
        for c in ["R", "G", "B"] {
            let mut v = fb.channel(c).unwrap().to_vec();
            v.iter_mut().enumerate().filter(|(i, _)| in_box(*i)).for_each(|(_, x)| *x += 5.0);
            fb.insert(c, SampleFormat::Float, v).unwrap();
        }
    });
    let out = dir.path().join("emit-den.exr");
    let o = kpcn(&["denoise", emitting.to_str().unwrap(), "-o", out.to_str().unwrap(), "-v", "--aovs"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("beyond diffuse + specular") && said.contains("600 pixels"), "{said}");
    let (a, b) = (FrameBuffers::read(&plain).unwrap(), FrameBuffers::read(&out).unwrap());
    let gain: Vec<f32> =
        a.channel("denoised.R").unwrap().iter().zip(b.channel("denoised.R").unwrap()).map(|(x, y)| y - x).collect();
    let boxed: Vec<f32> = gain.iter().enumerate().filter(|(i, _)| in_box(*i)).map(|(_, g)| *g).collect();
    let mean = boxed.iter().sum::<f32>() / boxed.len() as f32;
    assert!((mean - 5.0).abs() < 0.1, "the box keeps its emission: +{mean}");
    // The AOVs still add up to the beauty.
    for c in ["R", "G", "B"] {
        let (col, d, s) = (
            b.channel(&format!("denoised.{c}")).unwrap(),
            b.channel(&format!("denoised_diffuse.{c}")).unwrap(),
            b.channel(&format!("denoised_specular.{c}")).unwrap(),
        );
        assert!(col.iter().zip(d).zip(s).all(|((x, d), s)| (x - (d + s)).abs() <= 1e-5 * x.abs().max(1.0)));
    }
    // Components brighter than the beauty are no emission: the passes disagree, and the
    // user is told (the difference is still kept, as in the file).
    let disagreeing = edited(dir.path(), "disagree.exr", |fb| {
        for c in ["diffuse.R", "diffuse.G", "diffuse.B"] {
            let v: Vec<f32> = fb.channel(c).unwrap().iter().map(|x| x * 1.5 + 0.05).collect();
            fb.insert(c, SampleFormat::Float, v).unwrap();
        }
    });
    let out = dir.path().join("disagree-den.exr");
    let o = kpcn(&["denoise", disagreeing.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("the passes disagree"), "{}", stderr(&o));
    let again = dir.path().join("emit-again.exr");
    let o = kpcn(&["denoise", emitting.to_str().unwrap(), "-o", again.to_str().unwrap()]);
    assert!(!stderr(&o).contains("passes disagree"), "emission is no disagreement: {}", stderr(&o));
    // A beauty named rgba.* is the colour: the same result as the plain file.
    let rgba = edited(dir.path(), "rgba.exr", |fb| {
        for c in ["R", "G", "B"] {
            let p = fb.remove(c).unwrap();
            fb.insert(&format!("rgba.{c}"), p.format, p.data).unwrap();
        }
    });
    let out = dir.path().join("rgba-den.exr");
    let o = kpcn(&["denoise", rgba.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(FrameBuffers::read(&out).unwrap().channel("denoised.R"), a.channel("denoised.R"));
}

/// A FIFO or a folder as input is refused at once with what it is (a FIFO used to hang).
#[test]
fn inputs_that_are_not_files_are_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("pipe.exr");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a valid path; mkfifo only creates the node.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let folder = dir.path().join("folder.exr");
    std::fs::create_dir(&folder).unwrap();
    for (input, says) in [(&fifo, "FIFO"), (&folder, "a folder")] {
        let t = std::time::Instant::now();
        let out = dir.path().join("out.exr");
        for cmd in
            [&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap()][..], &["info", input.to_str().unwrap()]]
        {
            let o = kpcn(cmd);
            assert_eq!(o.status.code(), Some(1), "{cmd:?}: {}", stderr(&o));
            assert!(stderr(&o).contains(says), "{cmd:?}: {}", stderr(&o));
        }
        assert!(t.elapsed().as_secs() < 20, "no hang");
    }
    assert!(FrameReader::open(&fifo).is_err());
}

/// Under an address-space limit the command ends with status 1 and an out-of-memory
/// message that names the fix, never an abort (134) or "corrupt file", and leaves no
/// temporary file, whichever allocation the limit hits first: from the least memory the
/// program starts in at all (its libraries alone take hundreds of MB; below that, the
/// dynamic loader or a library's static initialiser fails before kpcn runs) to enough.
#[test]
fn running_out_of_memory_is_an_error_not_an_abort() {
    let dir = tempfile::tempdir().unwrap();
    // A 1280×768 frame: big enough that its working memory, not the program's, decides.
    let input = dir.path().join("big.exr");
    let o = Command::new("oiiotool").arg(EXAMPLE).args(["--resize", "1280x768", "-o"]).arg(&input).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = dir.path().join("out.exr");
    let limited = |mb: usize, args: &str| {
        let script = format!("ulimit -v {}; exec {} {args}", mb * 1024, env!("CARGO_BIN_EXE_kpcn"));
        Command::new("sh").arg("-c").arg(&script).output().unwrap()
    };
    let start = (200..4000).step_by(10).find(|&mb| limited(mb, "--version").status.success()).expect("kpcn starts");
    let mut reported = 0;
    // The top is enough for the frame's one band (its working memory is checked as address
    // space, with every decoding and encoding thread's stack and heap on top).
    for mb in [0, 10, 30, 60, 120, 250, 500, 800, 1400, 2200].map(|extra| start + extra) {
        let o = limited(mb, &format!("denoise {} -o {} -q", input.display(), out.display()));
        let err = stderr(&o);
        assert!(matches!(o.status.code(), Some(0 | 1)), "{mb} MB (starts in {start}): {:?} {err}", o.status);
        if o.status.code() == Some(1) {
            assert!(
                err.contains("out of memory") && err.contains("memory limit") || err.contains("--max-memory"),
                "{mb} MB: {err}"
            );
            assert!(!err.contains("corrupt"), "{mb} MB: {err}");
            reported += 1;
        }
        let stray: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.contains(".tmp"))
            .collect();
        assert!(stray.is_empty(), "{mb} MB left {stray:?}");
    }
    assert!(reported > 0, "some limit was too small: the test exercised the error");
    assert!(out.exists(), "the largest limit was enough: the test exercised success");
}

/// A DWA-compressed render is written back losslessly (zip) unless `--compression` asks,
/// so its kept channels are not re-encoded lossily; a lossless input keeps its codec.
#[test]
fn lossy_inputs_are_not_recompressed_lossily() {
    let dir = tempfile::tempdir().unwrap();
    let compression_of =
        |p: &Path| FrameReader::open(p).unwrap().header().attribute("compression").unwrap().to_string();
    for (codec, extra, want) in
        [("dwaa", &[][..], "zip"), ("piz", &[][..], "piz"), ("dwaa", &["--compression", "dwab"][..], "dwab")]
    {
        let input = dir.path().join(format!("{codec}.exr"));
        let o =
            Command::new("oiiotool").arg(EXAMPLE).args(["--compression", codec, "-o"]).arg(&input).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(compression_of(&input), codec);
        let out = dir.path().join("out.exr");
        let o = kpcn(&[&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"][..], extra].concat());
        assert!(o.status.success(), "{}", stderr(&o));
        assert_eq!(compression_of(&out), want, "{codec} {extra:?}");
    }
    let o = kpcn(&["denoise", EXAMPLE, "-o", "x.exr", "--compression", "jpeg"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}

/// Negative frames are named as printf writes them (`%04d` of −1 is `-001`), found on disk
/// and denoised like the others.
#[test]
fn negative_frames_are_found_as_printf_writes_them() {
    let dir = tempfile::tempdir().unwrap();
    for f in ["-002", "-001", "0000", "0001"] {
        std::fs::copy(EXAMPLE, dir.path().join(format!("n.{f}.exr"))).unwrap();
    }
    let (i, o) = (dir.path().join("n.%04d.exr"), dir.path().join("d.####.exr"));
    let out = kpcn(&["denoise", i.to_str().unwrap(), "-o", o.to_str().unwrap(), "-q"]);
    assert!(out.status.success(), "{}", stderr(&out));
    for f in ["-002", "-001", "0000", "0001"] {
        assert!(dir.path().join(format!("d.{f}.exr")).is_file(), "frame {f} denoised");
    }
    let out = kpcn(&["denoise", i.to_str().unwrap(), "-o", o.to_str().unwrap(), "--frames=-2--1", "-n"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("n.-002.exr"));
}

/// Negative and absurd (1e30) variances are clamped into [0, 1e15] and said so; a valid
/// TIFF opens (the subimage count no longer trips the reader).
#[test]
fn hostile_variances_are_repaired_and_reported_and_tiffs_open() {
    let dir = tempfile::tempdir().unwrap();
    let input = edited(dir.path(), "var.exr", |fb| {
        let mut v = fb.channel("colorVariance.Z").unwrap().to_vec();
        v[..10].iter_mut().for_each(|x| *x = -1.0);
        v[10..15].iter_mut().for_each(|x| *x = 1e30);
        fb.insert("colorVariance.Z", SampleFormat::Float, v).unwrap();
    });
    let out = dir.path().join("out.exr");
    let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("colorVariance: 15 samples outside [0, 1e15] clamped"), "{}", stderr(&o));
    let tiff = dir.path().join("frame.tif");
    let o =
        Command::new("oiiotool").arg(EXAMPLE).args(["--ch", "R,G,B", "-d", "float", "-o"]).arg(&tiff).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = FrameReader::open(&tiff).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.channel_names().count(), 3);
}

/// Host buffers (the C ABI's and the Python module's path): a colour that holds emission
/// beyond diffuse + specular keeps it in the output, and the parts still add up.
#[test]
fn in_memory_frames_keep_what_the_beauty_holds_beyond_its_components() {
    use kpcn::denoise::{Denoiser, Options};
    let fb = FrameBuffers::read(Path::new(EXAMPLE)).unwrap();
    let mapping = kpcn::io::layout::Mapping::for_frame(&fb, None);
    let plain = mapping.extract(&fb).unwrap();
    let mut emitting = plain.clone();
    let w = plain.width;
    for c in 0..3 {
        for i in (20 * w..40 * w).filter(|i| (30..60).contains(&(i % w))) {
            emitting.color[c][i] += 5.0;
        }
    }
    let d = Denoiser::new(kpcn::model::Model::embedded_default().unwrap(), Options::default()).unwrap();
    let (a, b) = (d.denoise(&plain, &|_| true).unwrap(), d.denoise(&emitting, &|_| true).unwrap());
    let i = 30 * w + 45;
    assert!((b.color[0][i] - a.color[0][i] - 5.0).abs() < 0.1, "{} vs {}", b.color[0][i], a.color[0][i]);
    for c in 0..3 {
        for (k, x) in b.color[c].iter().enumerate() {
            assert!((x - (b.diffuse[c][k] + b.specular[c][k])).abs() <= 1e-5 * x.abs().max(1.0));
        }
    }
}

/// The command decodes lossless scanline EXRs with OpenEXRCore (`io::exr_core`, its
/// chunk buffers its own), the library with the classic reader: the same bits either way,
/// for every lossless compression and float, half and uint channels, across chunk
/// boundaries (zip 16 rows, piz 32); lossy files keep the classic reader.
#[test]
fn the_commands_openexr_core_reads_give_the_classic_readers_bits() {
    use kpcn::denoise::{Denoiser, FileJob, FileOptions, Options};
    use kpcn::model::Model;
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (23, 37);
    let mut fb = crate::util::native_frame(w, h, 11, &[]);
    let ids: Vec<f32> = (0..(w * h) as u32).map(|i| f32::from_bits(i.wrapping_mul(2654435761) | 1)).collect();
    fb.insert("objectId.id", SampleFormat::Uint, ids).unwrap();
    let half: Vec<f32> = (0..w * h).map(|i| half::f16::from_bits(i as u16 * 71).to_f32()).collect();
    fb.insert("mask.A", SampleFormat::Half, half.into_iter().map(|v| if v.is_nan() { 0.5 } else { v }).collect())
        .unwrap();
    let d = Denoiser::new(Model::resolve("balanced").unwrap(), Options::default()).unwrap();
    for (compression, core) in kpcn::io::LOSSLESS_COMPRESSIONS.iter().map(|c| (*c, true)).chain([("dwaa", false)]) {
        let input = dir.path().join(format!("{compression}.exr"));
        fb.write(&input, &WriteOptions { compression: Some(compression.into()), ..Default::default() }).unwrap();
        let (cli, lib) =
            (dir.path().join(format!("{compression}-cli.exr")), dir.path().join(format!("{compression}-lib.exr")));
        let o = kpcn(&["denoise", input.to_str().unwrap(), "-o", cli.to_str().unwrap(), "--model", "balanced", "-v"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let said = String::from_utf8_lossy(&o.stdout).contains("(OpenEXRCore)");
        assert_eq!(said, core, "{compression}: {}", String::from_utf8_lossy(&o.stdout));
        let report = FileJob::open(&input, None).unwrap().run(&d, &lib, &FileOptions::default(), &|_| true).unwrap();
        assert!(!report.openexr_core, "the library reads classically unless asked");
        let (a, b) = (FrameBuffers::read(&cli).unwrap(), FrameBuffers::read(&lib).unwrap());
        assert_eq!(a.channel_names().collect::<Vec<_>>(), b.channel_names().collect::<Vec<_>>(), "{compression}");
        for name in b.channel_names() {
            let (x, y) = (a.channel(name).unwrap(), b.channel(name).unwrap());
            assert!(x.iter().zip(y).all(|(x, y)| x.to_bits() == y.to_bits()), "{compression}: {name} differs");
        }
        // What was copied is the input's, bit for bit (the lossy file's are its decoded bits).
        let back = FrameBuffers::read(&input).unwrap();
        for p in back.planes() {
            assert!(
                a.channel(&p.name).unwrap().iter().zip(&p.data).all(|(x, y)| x.to_bits() == y.to_bits()),
                "{compression}: {}",
                p.name
            );
        }
    }
}
