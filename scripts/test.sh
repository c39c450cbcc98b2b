#!/usr/bin/env bash
# The whole test suite, as CI runs it: set-up, formatting, lints, docs, tests.
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/setup-debian.sh
cargo fmt --check
cargo clippy --locked --all-targets -- -D warnings
RUSTDOCFLAGS="-D warnings" cargo doc --locked --no-deps --quiet --document-private-items
cargo test --locked
