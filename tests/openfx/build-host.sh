#!/usr/bin/env bash
# Builds tests/openfx/ofx_host.cpp with the HostSupport library (from openfx-sys's sources,
# plugins/openfx/sources.sh) into OUT/ofx_host. HostSupport predates C++17 (dynamic
# exception specifications), hence C++14; expat comes from Debian (libexpat1-dev).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=$1
ofx=$("$here/../../plugins/openfx/sources.sh")
mkdir -p "$out/objects"
flags=(-std=c++14 -O1 -w -I"$ofx/include" -I"$ofx/HostSupport/include")
for f in "$ofx"/HostSupport/src/*.cpp; do
    g++ "${flags[@]}" -c "$f" -o "$out/objects/$(basename "$f" .cpp).o" &
done
wait
g++ "${flags[@]}" "$here/ofx_host.cpp" "$out"/objects/*.o -lexpat -ldl -o "$out/ofx_host"
echo "$out/ofx_host"
