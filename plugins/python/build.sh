#!/usr/bin/env bash
# Builds the `kpcn` Python wheel (one abi3 wheel for CPython >= 3.9) into target/wheels:
#
#   plugins/python/build.sh              # release build
#   plugins/python/build.sh --profile dev   # what the tests use: shares the test build's deps
#
# maturin comes from PyPI, pinned, into its own virtual environment under ~/.cache/kpcn.
# Prints the wheel's path. Install it with `pip install target/wheels/kpcn-*.whl`.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
maturin_version=1.9.6
venv=${XDG_CACHE_HOME:-$HOME/.cache}/kpcn/maturin
if ! "$venv/bin/maturin" --version 2>/dev/null | grep -qx "maturin $maturin_version"; then
    echo "kpcn: installing maturin $maturin_version into $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet --disable-pip-version-check "maturin==$maturin_version"
fi
args=("$@")
[ ${#args[@]} -gt 0 ] || args=(--release)
rm -f "$root"/target/wheels/kpcn-*.whl
# The wheel links Debian's OpenImageIO from the system (no manylinux claim): --compatibility linux.
"$venv/bin/maturin" build --quiet --locked --manifest-path "$here/Cargo.toml" --interpreter python3 \
    --compatibility linux --out "$root/target/wheels" "${args[@]}" >&2
ls "$root"/target/wheels/kpcn-*.whl
