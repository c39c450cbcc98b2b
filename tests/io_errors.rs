//! Bad inputs give errors that name the file, never crashes.

use crate::util::{garbage, mismatched_parts, native_frame, write};
use kpcn::io::{FrameBuffers, IoError};
use std::path::Path;

fn read_err(path: &Path) -> IoError {
    match FrameBuffers::read(path) {
        Ok(_) => panic!("{} read without error", path.display()),
        Err(e) => e,
    }
}

#[test]
fn a_nonexistent_file_is_an_open_error_naming_it() {
    let e = read_err(Path::new("/no/such/dir/frame.0001.exr"));
    assert!(matches!(e, IoError::Open { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.starts_with("/no/such/dir/frame.0001.exr: cannot open"), "{msg}");
    assert!(msg.contains(" — "), "says what to do: {msg}");
}

#[test]
fn a_truncated_exr_is_an_error_at_every_offset() {
    let dir = tempfile::tempdir().unwrap();
    let good = write(&native_frame(64, 48, 9, &[]), dir.path(), "good.exr");
    let bytes = std::fs::read(&good).unwrap();
    let n = bytes.len();
    let offsets = [0, 1, 4, 8, 64, 300, n / 8, n / 4, n / 2, 3 * n / 4, n - 100, n - 8, n - 1];
    for cut in offsets {
        let path = dir.path().join(format!("cut{cut}.exr"));
        std::fs::write(&path, &bytes[..cut]).unwrap();
        let e = read_err(&path);
        assert!(matches!(e, IoError::Open { .. } | IoError::Read { .. } | IoError::Empty { .. }), "cut at {cut}: {e}");
        assert!(e.to_string().contains(&format!("cut{cut}.exr")), "{e}");
    }
}

#[test]
fn corrupt_files_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good = write(&native_frame(32, 32, 10, &[]), dir.path(), "good.exr");
    let bytes = std::fs::read(&good).unwrap();

    let noise = dir.path().join("garbage.exr");
    garbage(&noise);
    read_err(&noise);

    let magic_only = dir.path().join("magic.exr");
    let mut m = bytes[..8].to_vec();
    m.extend(std::iter::repeat_n(0xAB, 2000));
    std::fs::write(&magic_only, m).unwrap();
    read_err(&magic_only);

    // Scramble the pixel data (the header and offset table stay intact).
    let scrambled = dir.path().join("scrambled.exr");
    let mut s = bytes.clone();
    let start = s.len() / 3;
    for b in &mut s[start..] {
        *b = b.wrapping_mul(31).wrapping_add(7);
    }
    std::fs::write(&scrambled, s).unwrap();
    let e = read_err(&scrambled);
    assert!(matches!(e, IoError::Read { .. } | IoError::Open { .. }), "{e}");

    let empty = dir.path().join("empty.exr");
    std::fs::write(&empty, b"").unwrap();
    read_err(&empty);
}

#[test]
fn parts_of_different_sizes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mismatch.exr");
    mismatched_parts(&path);
    let e = read_err(&path);
    assert!(matches!(e, IoError::PartSizeMismatch { subimage: 1, .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("8x4") && msg.contains("16x8") && msg.contains("half"), "{msg}");
}
