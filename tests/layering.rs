//! The direction of data flow in the source (file → buffers → features → network →
//! kernels → buffers → file): a lower module never names a higher one. Checked on the
//! source text, so a new `use` that closes a cycle fails here before review.

use std::path::Path;

/// Every `crate::<module>` a source tree names, with the file and line.
fn references(dir: &str) -> Vec<(String, usize, String)> {
    fn walk(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }
    let mut files = Vec::new();
    walk(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src").join(dir), &mut files);
    let mut refs = Vec::new();
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            for (i, _) in code.match_indices("crate::") {
                let module: String = code[i + 7..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                refs.push((file.display().to_string(), n + 1, module));
            }
        }
    }
    refs
}

fn assert_never_names(dir: &str, forbidden: &[&str]) {
    let bad: Vec<String> = references(dir)
        .into_iter()
        .filter(|(_, _, m)| forbidden.contains(&m.as_str()))
        .map(|(f, n, m)| format!("{f}:{n} names crate::{m}"))
        .collect();
    assert!(bad.is_empty(), "src/{dir} must not depend on {forbidden:?}:\n{}", bad.join("\n"));
}

#[test]
fn kernels_and_tiles_name_nothing_above_them() {
    let above = ["model", "train", "denoise", "eval", "cli", "capi", "sim", "features", "io"];
    assert_never_names("kernel", &above);
    assert_never_names("tile", &above);
}

#[test]
fn the_model_and_inference_never_name_the_trainer() {
    for dir in ["model", "denoise", "features", "io", "capi"] {
        assert_never_names(dir, &["train", "cli", "eval"]);
    }
}

#[test]
fn the_checker_sees_references() {
    // The trainer does use the model: a checker that found nothing would pass vacuously.
    assert!(references("train").iter().any(|(_, _, m)| m == "model"));
}

#[test]
fn the_library_does_not_expose_the_cli() {
    // The CLI is the binary's own module (src/main.rs), so its argument types are no
    // library API: the library root declares no `cli` module and nothing in it names one.
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let lib = std::fs::read_to_string(root.join("lib.rs")).unwrap();
    assert!(
        !lib.lines().any(|l| l.trim_start().starts_with("pub mod cli") || l.trim() == "mod cli;"),
        "src/lib.rs declares the CLI"
    );
    let main = std::fs::read_to_string(root.join("main.rs")).unwrap();
    assert!(main.lines().any(|l| l.trim() == "mod cli;"), "src/main.rs should own the CLI");
    for dir in ["capi", "denoise", "eval", "features", "io", "kernel", "model", "sim", "tile", "train"] {
        assert_never_names(dir, &["cli"]);
    }
}
