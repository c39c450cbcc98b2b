//! Builds kpcn's C++ shim over Debian's OpenImageIO 2.4 and generates its Rust binding.
//!
//! A missing dependency stops the build with one sentence naming the Debian packages.

use std::env;
use std::path::PathBuf;
use std::process::exit;

const SHIM_DIR: &str = "src/io/shim";
const SETUP_HINT: &str =
    "run `sudo scripts/setup-debian.sh` (or `apt-get install libopenimageio-dev libclang-dev pkg-config g++`)";

fn die(msg: &str) -> ! {
    eprintln!("error: {msg}; {SETUP_HINT}");
    println!("cargo::warning={msg}; {SETUP_HINT}");
    exit(1);
}

fn main() {
    println!("cargo::rerun-if-changed={SHIM_DIR}/oiio_shim.h");
    println!("cargo::rerun-if-changed={SHIM_DIR}/oiio_shim.cpp");
    println!("cargo::rerun-if-changed=build.rs");
    // The C ABI's version (Cargo.toml's [package.metadata.kpcn] abi): hosts link against
    // libkpcn.so.<abi> (scripts/install.sh makes the links), so libraries of incompatible
    // ABIs sit side by side and a host never loads the wrong one.
    println!("cargo::rerun-if-changed=Cargo.toml");
    let manifest = std::fs::read_to_string("Cargo.toml").unwrap_or_default();
    let abi = manifest
        .lines()
        .skip_while(|l| l.trim() != "[package.metadata.kpcn]")
        .find_map(|l| l.trim().strip_prefix("abi = "))
        .unwrap_or_else(|| die("Cargo.toml lacks [package.metadata.kpcn] abi = N"))
        .to_string();
    println!("cargo::rustc-cdylib-link-arg=-Wl,-soname,libkpcn.so.{abi}");
    println!("cargo::rustc-env=KPCN_ABI={abi}");
    // The command serves zlib's one-shot calls with libdeflate (src/cli/zlib.rs): its
    // definitions must be in the dynamic symbol table for the libraries' calls to bind there.
    println!(
        "cargo::rustc-link-arg-bin=kpcn=-Wl,--export-dynamic-symbol=compress,--export-dynamic-symbol=compress2,--export-dynamic-symbol=uncompress"
    );

    // Probe without emitting link flags yet: the shim's static library must come
    // before OpenImageIO on the link line.
    let oiio = match pkg_config::Config::new().atleast_version("2.4").cargo_metadata(false).probe("OpenImageIO") {
        Ok(lib) => lib,
        Err(e) => {
            let detail = e.to_string();
            let detail = detail.lines().map(str::trim).find(|l| !l.is_empty()).unwrap_or("not found");
            die(&format!("OpenImageIO 2.4+ development files were not found by pkg-config ({detail})"))
        }
    };

    let mut build = cc::Build::new();
    build
        .cpp(true)
        .std("c++17")
        .file(format!("{SHIM_DIR}/oiio_shim.cpp"))
        .flag_if_supported("-Wno-deprecated-declarations");
    for inc in &oiio.include_paths {
        build.include(inc);
    }
    if let Err(e) = build.try_compile("kpcn_oiio_shim") {
        die(&format!("compiling the OpenImageIO shim failed ({e}); is g++ installed?"));
    }

    for dir in &oiio.link_paths {
        println!("cargo::rustc-link-search=native={}", dir.display());
    }
    for lib in &oiio.libs {
        println!("cargo::rustc-link-lib={lib}");
    }

    // bindgen loads libclang at run time and panics when it is absent.
    let header = format!("{SHIM_DIR}/oiio_shim.h");
    let generated = std::panic::catch_unwind(|| {
        bindgen::Builder::default()
            .header(header)
            .allowlist_function("kpcn_.*")
            .allowlist_type("kpcn_.*")
            .allowlist_var("KPCN_.*")
            .default_enum_style(bindgen::EnumVariation::Consts)
            .layout_tests(false)
            .derive_default(true)
            .generate()
    });
    let bindings = match generated {
        Ok(Ok(b)) => b,
        Ok(Err(e)) => die(&format!("bindgen could not read the OpenImageIO shim header ({e})")),
        Err(_) => die("bindgen could not load libclang"),
    };
    let out = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    if let Err(e) = bindings.write_to_file(out.join("oiio_bindings.rs")) {
        die(&format!("writing the generated OpenImageIO binding failed ({e})"));
    }
}
