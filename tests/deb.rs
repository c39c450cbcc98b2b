//! The Debian package (`scripts/build-deb.sh`): installed into this machine with `dpkg -i`,
//! used as a user would (the command, a C program linked through pkg-config, the man page,
//! the OIIO plugin, the Blender add-on), then removed with nothing left behind.

use super::capi::{EXAMPLE, root, run};
use std::path::{Path, PathBuf};
use std::process::Command;

/// `program args…`, as root (through `sudo -n` when the tests run as another user).
fn as_root(program: &str, args: &[&str]) -> Command {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } == 0 {
        let mut c = Command::new(program);
        c.args(args);
        c
    } else {
        let mut c = Command::new("sudo");
        c.arg("-n").arg(program).args(args);
        c
    }
}

/// Removes the package however the test ends.
struct Installed;

impl Drop for Installed {
    fn drop(&mut self) {
        let _ = as_root("dpkg", &["--purge", "kpcn"]).output();
    }
}

#[test]
fn the_debian_package_installs_links_and_uninstalls_cleanly() {
    let out = run(Command::new(root().join("scripts/build-deb.sh")).env("KPCN_PROFILE", "dev"));
    let deb = root().join(out.lines().find(|l| l.ends_with(".deb")).unwrap_or_else(|| panic!("no package: {out}")));
    // Every file and link of the package (not its folders, which other packages share).
    let files: Vec<PathBuf> = run(Command::new("dpkg-deb").arg("-c").arg(&deb))
        .lines()
        .filter(|l| !l.starts_with('d'))
        .filter_map(|l| l.split_whitespace().nth(5).map(|p| PathBuf::from(p.trim_start_matches('.'))))
        .collect();
    let triplet = run(Command::new("gcc").arg("-print-multiarch")).trim().to_string();
    let lib = PathBuf::from(format!("/usr/lib/{triplet}"));
    for wanted in [
        PathBuf::from("/usr/bin/kpcn"),
        lib.join("libkpcn.so.1"),
        lib.join("libkpcn.a"),
        lib.join("pkgconfig/kpcn.pc"),
        PathBuf::from("/usr/include/kpcn.h"),
        lib.join("kpcn/oiio-plugins/kpcn.imageio.so"),
        PathBuf::from("/usr/share/kpcn/kpcn-blender-addon.zip"),
        PathBuf::from("/usr/share/man/man1/kpcn.1.gz"),
        PathBuf::from("/usr/share/man/man1/kpcn-denoise.1.gz"),
        PathBuf::from("/usr/share/bash-completion/completions/kpcn"),
    ] {
        assert!(files.contains(&wanted), "{} is not in the package", wanted.display());
    }

    let installed = Installed;
    let o = as_root("dpkg", &["-i", deb.to_str().unwrap()]).output().unwrap();
    assert!(
        o.status.success(),
        "dpkg -i: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );

    let version = run(Command::new("/usr/bin/kpcn").arg("--version"));
    assert!(version.starts_with("kpcn "), "{version}");
    // `man kpcn` finds the page (where man-db is installed; the file in any case).
    assert!(Path::new("/usr/share/man/man1/kpcn.1.gz").exists());
    if let Ok(o) = Command::new("man").args(["-w", "kpcn"]).output() {
        assert!(o.status.success() && String::from_utf8_lossy(&o.stdout).contains("kpcn.1"), "man -w kpcn");
    }
    // A C program linked with the system's pkg-config alone (no PKG_CONFIG_PATH, no rpath).
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("app.c");
    std::fs::write(
        &src,
        "#include <kpcn.h>\n#include <stdio.h>\nint main(void) {\n  KpcnOptions o;\n  kpcn_options_init(&o);\n  \
         KpcnDenoiser *d = NULL;\n  if (kpcn_denoiser_new(&o, &d) != KPCN_OK) { puts(kpcn_last_error()); return 1; }\n  \
         printf(\"kpcn %s\\n\", kpcn_version_string());\n  kpcn_denoiser_free(d);\n  return 0;\n}\n",
    )
    .unwrap();
    let flags = run(Command::new("pkg-config").args(["--cflags", "--libs", "kpcn"]).env_remove("PKG_CONFIG_PATH"));
    let app = dir.path().join("app");
    run(Command::new("cc").arg(&src).arg("-o").arg(&app).args(flags.split_whitespace()));
    let said = run(&mut Command::new(&app));
    assert!(said.contains(env!("CARGO_PKG_VERSION")), "{said}");
    // The OIIO plugin loads from its folder and finds the system's library.
    let info = run(Command::new("iinfo")
        .arg(format!("{EXAMPLE}.kpcn"))
        .env("OIIO_LIBRARY_PATH", lib.join("kpcn/oiio-plugins")));
    assert!(info.contains("3 channel, float kpcn"), "{info}");

    let o = as_root("apt-get", &["remove", "-y", "-qq", "kpcn"]).output().unwrap();
    assert!(o.status.success(), "apt-get remove: {}", String::from_utf8_lossy(&o.stderr));
    drop(installed);
    let left: Vec<&PathBuf> = files.iter().filter(|p| p.symlink_metadata().is_ok()).collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    assert!(!lib.join("libkpcn.so.1").exists() && !lib.join("libkpcn.so").exists());
}
