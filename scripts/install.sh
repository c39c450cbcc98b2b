#!/usr/bin/env bash
# Installs the C library core (no CLI, simulator or trainer) for C/C++ hosts:
#   PREFIX/lib/libkpcn.so.X.Y.Z (+ libkpcn.so.ABI, libkpcn.so links), PREFIX/lib/libkpcn.a,
#   PREFIX/include/kpcn.h and PREFIX/lib/pkgconfig/kpcn.pc. Programs linked through the
#   .pc file find the library at run time without ldconfig or LD_LIBRARY_PATH: its Libs
#   carry an rpath to PREFIX/lib.
#
#   scripts/install.sh PREFIX              # e.g. /usr/local, or $HOME/.local
#   PKG_CONFIG_PATH=PREFIX/lib/pkgconfig cc app.c $(pkg-config --cflags --libs kpcn)
#
# KPCN_PROFILE=dev installs the debug build (what the tests use; it shares their build).
set -euo pipefail
if [ $# -ne 1 ]; then
    echo "usage: scripts/install.sh PREFIX" >&2
    exit 2
fi
cd "$(dirname "$0")/.."
prefix=$(mkdir -p "$1" && cd "$1" && pwd)
profile=${KPCN_PROFILE:-release}
case "$profile" in
    dev) dir=debug ;;
    *) dir=$profile ;;
esac
target=${CARGO_TARGET_DIR:-target}

scripts/setup-debian.sh
cargo build --locked --quiet --lib --no-default-features --profile "$profile"

version=$(sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n1)
# The C ABI's version, the SONAME's number (Cargo.toml's [package.metadata.kpcn]).
abi=$(sed -n '/^\[package.metadata.kpcn\]/,/^\[/s/^abi = //p' Cargo.toml)
lib="$prefix/lib"
install -d "$lib/pkgconfig" "$prefix/include"
# Debug sections are most of the files' size (the .a holds the Rust standard library too).
install -m 755 "$target/$dir/libkpcn.so" "$lib/libkpcn.so.$version"
strip --strip-debug "$lib/libkpcn.so.$version"
ln -sf "libkpcn.so.$version" "$lib/libkpcn.so.$abi"
ln -sf "libkpcn.so.$abi" "$lib/libkpcn.so"
install -m 644 "$target/$dir/libkpcn.a" "$lib/libkpcn.a"
strip --strip-debug "$lib/libkpcn.a"
install -m 644 include/kpcn.h "$prefix/include/kpcn.h"

# Libs.private: what `rustc --print native-static-libs` lists for the static library,
# besides OpenImageIO (Requires.private).
cat > "$lib/pkgconfig/kpcn.pc" <<PC
prefix=$prefix
libdir=\${prefix}/lib
includedir=\${prefix}/include

Name: kpcn
Description: Kernel-predicting Monte Carlo render denoiser (C API)
Version: $version
Requires.private: OpenImageIO >= 2.4
Libs: -L\${libdir} -Wl,-rpath,\${libdir} -lkpcn
Libs.private: -lstdc++ -lgcc_s -lutil -lrt -lpthread -lm -ldl
Cflags: -I\${includedir}
PC
echo "kpcn $version (C ABI $abi) installed into $prefix" >&2
