#!/usr/bin/env bash
# The main job on the checked-in example: set-up, release build, then denoise the example
# with the embedded default model into out/ and describe the result.
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/setup-debian.sh
cargo build --locked --release --quiet
mkdir -p out
target/release/kpcn denoise examples/data/spheres-crop-00016spp.exr -o out/spheres-crop-00016spp.denoised.exr --aovs
target/release/kpcn info out/spheres-crop-00016spp.denoised.exr
