//! The one home of atomic file replacement: every output kpcn writes (EXR frames, model
//! files, manifests, logs) is written to a hidden temporary file beside its target, synced,
//! and moved into place, so an error, a crash or a cancel never leaves a truncated file.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A temporary file that becomes `target` on [`commit`](AtomicFile::commit) and is removed
/// when dropped uncommitted.
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    temp: Option<PathBuf>,
    no_clobber: bool,
}

impl AtomicFile {
    /// A temporary path for `target` in the same folder (so the final rename is atomic):
    /// `.NAME.kpcn-PID-N.tmp.EXT`, hidden, ending in `target`'s extension so writers that
    /// choose a format by extension accept it. With `no_clobber`, commit fails rather than
    /// replace a file that exists by then.
    pub fn new(target: &Path, no_clobber: bool) -> AtomicFile {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let ext = target.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
        let temp = target.with_file_name(format!(".{name}.kpcn-{}-{n}.tmp{ext}", std::process::id()));
        AtomicFile { target: target.into(), temp: Some(temp), no_clobber }
    }

    /// Where to write the content.
    pub fn temp_path(&self) -> &Path {
        self.temp.as_deref().expect("set until commit")
    }

    /// The final path.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Syncs the temporary file and moves it into place. With `no_clobber`, an existing
    /// target is an [`io::ErrorKind::AlreadyExists`] error, free of races with other
    /// writers (a hard link never replaces).
    pub fn commit(mut self) -> io::Result<()> {
        let temp = self.temp.clone().expect("set until commit");
        fs::File::open(&temp)?.sync_all()?;
        if self.no_clobber {
            fs::hard_link(&temp, &self.target)?;
            // Dropping removes the temporary name; the link keeps the content.
        } else {
            fs::rename(&temp, &self.target)?;
            self.temp = None;
        }
        if let Some(dir) = self.target.parent().filter(|d| !d.as_os_str().is_empty()) {
            // Makes the rename durable; a failure here loses nothing already written.
            let _ = fs::File::open(dir).and_then(|d| d.sync_all());
        }
        Ok(())
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if let Some(p) = self.temp.take() {
            let _ = fs::remove_file(p);
        }
    }
}

/// Writes `bytes` to `path` atomically (replacing it).
pub fn write_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let file = AtomicFile::new(path, false);
    fs::write(file.temp_path(), bytes)?;
    file.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commits_replace_and_drops_clean_up() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("m.safetensors");
        write_atomically(&target, b"one").unwrap();
        write_atomically(&target, b"two").unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"two");
        let abandoned = AtomicFile::new(&target, false);
        fs::write(abandoned.temp_path(), b"half").unwrap();
        assert!(abandoned.temp_path().extension().is_some_and(|e| e == "safetensors"));
        drop(abandoned);
        let kept = AtomicFile::new(&target, true);
        fs::write(kept.temp_path(), b"three").unwrap();
        assert_eq!(kept.commit().unwrap_err().kind(), io::ErrorKind::AlreadyExists);
        assert_eq!(fs::read(&target).unwrap(), b"two");
        let names: Vec<_> = fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, ["m.safetensors"], "no temporary file is left");
    }
}
