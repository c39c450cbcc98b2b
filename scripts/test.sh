#!/usr/bin/env bash
# The whole test suite, as CI runs it: set-up, formatting, lints, docs, tests.
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/setup-debian.sh
cargo fmt --all --check
cargo clippy --locked --workspace --all-targets -- -D warnings
RUSTDOCFLAGS="-D warnings" cargo doc --locked --no-deps --quiet --document-private-items
cargo test --locked
# The Python module: its wheel in a fresh virtual environment, with pytest.
plugins/python/test.sh
