#!/usr/bin/env bash
# Installs the Debian packages kpcn builds against. Idempotent: installs only what is
# missing and touches nothing (not even apt's lists) when everything is present.
set -euo pipefail

# fonts-dejavu-core: the text of training and study plots. gcc/g++ (with binutils and the
# sanitizer runtimes) build the C-ABI tests' C99 and C++17 programs. The plugin tests run
# the real hosts: oiiotool/idiff (openimageio-tools) and Blender 3.4 (blender), headless, and
# an OpenFX host built on HostSupport, which parses plugin caches with expat (libexpat1-dev).
# python3-venv holds openjd-cli (below).
packages=(libopenimageio-dev libclang-dev pkg-config gcc g++ fonts-dejavu-core openimageio-tools blender libexpat1-dev
    python3-venv)

# cbindgen generates include/kpcn.h (a test checks it is current). Debian's 0.24 cannot
# parse edition 2024, so it comes from crates.io, pinned.
cbindgen_version=0.29.4
if ! cbindgen --version 2>/dev/null | grep -qx "cbindgen $cbindgen_version"; then
    echo "kpcn setup: installing cbindgen $cbindgen_version (cargo install)" >&2
    cargo install --quiet --locked --version "$cbindgen_version" cbindgen
fi

missing=()
for p in "${packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
if ((${#missing[@]} > 0)); then
    sudo=""
    if [ "$(id -u)" -ne 0 ]; then
        sudo="sudo"
    fi
    echo "kpcn setup: installing ${missing[*]}" >&2
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    echo "kpcn setup: done" >&2
fi

# openjd-cli runs the render-farm job template in its test (plugins/openjd), as a farm
# would: from PyPI, pinned, in its own virtual environment (Debian's Python refuses pip
# installs outside one). tests/farm.rs looks for it there.
"$(dirname "$0")/venv-tool.sh" openjd openjd-cli==0.8.0 "Open Job Description CLI 0.8.0" >/dev/null
