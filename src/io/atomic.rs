//! The one home of atomic file replacement: every output kpcn writes (EXR frames, model
//! files, manifests, logs) is written to a hidden temporary file beside its target, synced,
//! and moved into place, so an error, a crash or a cancel never leaves a truncated file.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

/// Temporary files being written now, so a signal handler can remove them
/// ([`remove_live_temp_files`]).
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn live() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    LIVE.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Removes every temporary file this process is writing. For a SIGTERM/SIGINT handler
/// (running on an ordinary thread) just before the process exits.
pub fn remove_live_temp_files() {
    for p in live().drain(..) {
        let _ = fs::remove_file(p);
    }
}

/// Removes temporary files in `dir` left by kpcn processes that no longer run (killed with
/// SIGKILL, or a machine that went down): `.NAME.kpcn-PID-N.tmp.EXT` with PID dead.
pub fn remove_stale_temp_files(dir: &Path) {
    let Ok(entries) = fs::read_dir(if dir.as_os_str().is_empty() { Path::new(".") } else { dir }) else { return };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = temp_file_pid(&name) else { continue };
        // SAFETY: kill with signal 0 only checks that the process exists.
        let dead = unsafe { libc::kill(pid, 0) } != 0 && io::Error::last_os_error().raw_os_error() == Some(libc::ESRCH);
        if dead {
            let _ = fs::remove_file(e.path());
        }
    }
}

/// The PID in a temporary file's name, `.NAME.kpcn-PID-N.tmp[.EXT]`.
fn temp_file_pid(name: &str) -> Option<i32> {
    if !name.starts_with('.') || !name.contains(".tmp") {
        return None;
    }
    let rest = &name[name.rfind(".kpcn-")? + 6..];
    let (pid, rest) = rest.split_once('-')?;
    let (n, _) = rest.split_once(".tmp")?;
    n.parse::<u64>().ok()?;
    pid.parse().ok().filter(|&p: &i32| p > 0)
}

/// A temporary file that becomes `target` on [`commit`](AtomicFile::commit) and is removed
/// when dropped uncommitted.
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    temp: Option<PathBuf>,
    /// The temporary name, as registered in [`LIVE`] until dropped.
    registered: PathBuf,
    no_clobber: bool,
}

impl AtomicFile {
    /// A temporary path for `target` in the same folder (so the final rename is atomic):
    /// `.NAME.kpcn-PID-N.tmp.EXT`, hidden, ending in `target`'s extension so writers that
    /// choose a format by extension accept it. With `no_clobber`, commit fails rather than
    /// replace a file that exists by then.
    ///
    /// A symbolic link is written through, as `cp` and oiiotool do: the file it points to
    /// is replaced and the link stays.
    pub fn new(target: &Path, no_clobber: bool) -> AtomicFile {
        let target = &resolve_links(target);
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let ext = target.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
        let temp = target.with_file_name(format!(".{name}.kpcn-{}-{n}.tmp{ext}", std::process::id()));
        remove_stale_temp_files(target.parent().unwrap_or(Path::new("")));
        live().push(temp.clone());
        AtomicFile { target: target.into(), temp: Some(temp.clone()), registered: temp, no_clobber }
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
        // A replaced file keeps its permissions (as with `cp`), not the umask's.
        if let Ok(old) = fs::metadata(&self.target) {
            fs::set_permissions(&temp, old.permissions())?;
        }
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
        live().retain(|l| *l != self.registered);
    }
}

/// `path` with symbolic links followed to the file they name (which may not exist yet).
pub fn resolve_links(path: &Path) -> PathBuf {
    let mut p = path.to_path_buf();
    // A bounded number of hops: a link cycle is left for the write to report.
    for _ in 0..40 {
        match fs::read_link(&p) {
            Ok(to) => p = if to.is_absolute() { to } else { p.parent().unwrap_or(Path::new("")).join(to) },
            Err(_) => break,
        }
    }
    p
}

/// Whether `a` and `b` are the same file (links followed); false when either is missing.
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (fs::metadata(a), fs::metadata(b)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

/// Why `target` cannot be written as an output, checked before any work: it is a folder,
/// its folder is missing, or it exists and this user may not write it (as `cp` refuses).
pub fn check_writable(target: &Path) -> Result<(), String> {
    let target = resolve_links(target);
    if target.is_dir() {
        return Err("is a folder — give a file name (e.g. DIR/frame.exr)".into());
    }
    let dir = target.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !dir.is_dir() {
        return Err(format!("its folder {} does not exist — create it first", dir.display()));
    }
    if target.exists() && !writable(&target) {
        return Err("exists and is not writable by you — change its permissions or choose another name".into());
    }
    if !writable(dir) {
        return Err(format!("its folder {} is not writable by you", dir.display()));
    }
    Ok(())
}

fn writable(p: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt;
    let Ok(c) = std::ffi::CString::new(p.as_os_str().as_bytes()) else { return false };
    // SAFETY: a valid NUL-terminated path; access(2) only reads it.
    unsafe { libc::access(c.as_ptr(), libc::W_OK) == 0 }
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

    #[test]
    fn stale_temp_files_of_dead_processes_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(temp_file_pid(".a.exr.kpcn-123-4.tmp.exr"), Some(123));
        assert_eq!(temp_file_pid("a.exr"), None);
        // PID 0x3FFFFFFF is above Linux's pid_max: never alive.
        let dead = dir.path().join(format!(".f.exr.kpcn-{}-0.tmp.exr", 0x3FFF_FFFF));
        let alive = dir.path().join(format!(".f.exr.kpcn-{}-0.tmp.exr", std::process::id()));
        fs::write(&dead, b"x").unwrap();
        fs::write(&alive, b"x").unwrap();
        let file = AtomicFile::new(&dir.path().join("f.exr"), false);
        assert!(!dead.exists() && alive.exists());
        // Registered for a signal handler (tests/reliability.rs sends the signals), and
        // unregistered when dropped.
        let temp = file.temp_path().to_path_buf();
        assert!(live().contains(&temp));
        drop(file);
        assert!(!live().contains(&temp));
    }

    #[test]
    fn links_are_written_through_and_modes_kept() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let (real, link) = (dir.path().join("real.bin"), dir.path().join("link.bin"));
        fs::write(&real, b"old").unwrap();
        fs::set_permissions(&real, fs::Permissions::from_mode(0o640)).unwrap();
        std::os::unix::fs::symlink("real.bin", &link).unwrap();
        assert!(same_file(&real, &link));
        write_atomically(&link, b"new").unwrap();
        assert!(fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "the link stays a link");
        assert_eq!(fs::read(&real).unwrap(), b"new");
        assert_eq!(fs::metadata(&real).unwrap().permissions().mode() & 0o777, 0o640);
        assert!(check_writable(dir.path()).unwrap_err().contains("is a folder"));
        assert!(check_writable(&dir.path().join("no/such/x.exr")).unwrap_err().contains("does not exist"));
        assert!(check_writable(&link).is_ok());
    }
}
