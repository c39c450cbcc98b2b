#!/usr/bin/env bash
# The main job on the checked-in example: set-up, release build, then kpcn on the example.
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/setup-debian.sh
cargo build --locked --release --quiet
target/release/kpcn info examples/data/spheres-crop-00016spp.exr
