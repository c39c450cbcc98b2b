#!/usr/bin/env bash
# Tests the `kpcn` Python module as a user gets it: builds the wheel (dev profile, sharing
# the test build's dependencies), installs it into a fresh virtual environment with only
# the test tools (pytest, OpenEXR to read files, pinned), and runs tests/ against the
# `kpcn` command (the debug build's, built here if missing).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
cargo build --locked --quiet --manifest-path "$root/Cargo.toml" --bin kpcn
wheel=$("$here/build.sh" --profile dev)
venv=$(mktemp -d -t kpcn-python-XXXXXX)
trap 'rm -rf "$venv"' EXIT
python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check "$wheel" pytest==8.4.2 OpenEXR==3.5.3
kpcn_bin=$(cd "$root" && realpath -m "${CARGO_TARGET_DIR:-target}/debug/kpcn")
cd "$venv" # not the source tree: `import kpcn` must find the installed wheel
KPCN_BIN="$kpcn_bin" "$venv/bin/python" -m pytest -q -p no:cacheprovider "$here/tests"
