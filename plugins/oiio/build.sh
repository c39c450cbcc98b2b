#!/usr/bin/env bash
# Builds kpcn.imageio.so into DIR (default: plugins/oiio/build) against an installed kpcn
# (scripts/install.sh PREFIX; pkg-config must find kpcn.pc, e.g. PKG_CONFIG_PATH=PREFIX/lib/pkgconfig).
#
#   plugins/oiio/build.sh [DIR]
#   OIIO_LIBRARY_PATH=DIR oiiotool frame.exr.kpcn -o frame.denoised.exr
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:-$here/build}
mkdir -p "$out"
# The plugin finds libkpcn through an rpath to kpcn.pc's libdir; KPCN_PLUGIN_RPATH overrides
# it, and empty means none (a system library: scripts/build-deb.sh).
rpath=${KPCN_PLUGIN_RPATH-$(pkg-config --variable=libdir kpcn)}
# shellcheck disable=SC2046 # pkg-config's flags are meant to split
g++ -std=c++17 -O2 -shared -fPIC -Wall -Wextra -Werror -Wno-deprecated-declarations \
    "$here/kpcn_imageio.cpp" -o "$out/kpcn.imageio.so" \
    $(pkg-config --cflags --libs OpenImageIO kpcn) ${rpath:+-Wl,-rpath,"$rpath"}
echo "$out/kpcn.imageio.so"
