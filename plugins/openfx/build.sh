#!/usr/bin/env bash
# Builds the OpenFX bundle DIR/kpcn.ofx.bundle (default DIR: plugins/openfx/build) against
# an installed kpcn (scripts/install.sh PREFIX; pkg-config must find kpcn.pc, e.g.
# PKG_CONFIG_PATH=PREFIX/lib/pkgconfig). Hosts find it on OFX_PLUGIN_PATH=DIR (or in
# /usr/OFX/Plugins).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:-$here/build}
ofx=$("$here/sources.sh")
binary="$out/kpcn.ofx.bundle/Contents/Linux-x86-64"
mkdir -p "$binary"
libdir=$(pkg-config --variable=libdir kpcn)
# shellcheck disable=SC2046 # pkg-config's flags are meant to split
g++ -std=c++17 -O2 -shared -fPIC -fvisibility=hidden -Wall -Wextra -Werror \
    -I"$ofx/include" "$here/kpcn_ofx.cpp" -o "$binary/kpcn.ofx" \
    $(pkg-config --cflags --libs kpcn) -Wl,-rpath,"$libdir"
echo "$out/kpcn.ofx.bundle"
