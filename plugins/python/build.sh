#!/usr/bin/env bash
# Builds the `kpcn` Python wheel (one abi3 wheel for CPython >= 3.9) into target/wheels:
#
#   plugins/python/build.sh              # release build
#   plugins/python/build.sh --profile dev   # what the tests use: shares the test build's deps
#
# maturin comes from PyPI, pinned, into its own virtual environment (scripts/venv-tool.sh).
# Prints the wheel's path. Install it with `pip install target/wheels/kpcn-*.whl`.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
maturin=$("$root/scripts/venv-tool.sh" maturin maturin==1.9.6 "maturin 1.9.6")/maturin
args=("$@")
[ ${#args[@]} -gt 0 ] || args=(--release)
rm -f "$root"/target/wheels/kpcn-*.whl
# The wheel links Debian's OpenImageIO from the system (no manylinux claim): --compatibility linux.
"$maturin" build --quiet --locked --manifest-path "$here/Cargo.toml" --interpreter python3 \
    --compatibility linux --out "$root/target/wheels" "${args[@]}" >&2
ls "$root"/target/wheels/kpcn-*.whl
