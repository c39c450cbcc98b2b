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
            assert!(stderr(&o).contains("is the input") && stderr(&o).contains("--in-place"), "{}", stderr(&o));
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
    let mut cmd = if unsafe { libc::geteuid() } == 0 {
        let mut c = Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups", env!("CARGO_BIN_EXE_kpcn")]);
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
