#!/usr/bin/env bash
# Quality on held-out simulator scenes: denoise the noisy frames of SCENES in a
# `kpcn dataset` folder with MODEL and print relMSE of noisy and denoised beside each other.
#
#   benches/quality_heldout.sh MODEL DATA_DIR SCENE...
set -euo pipefail
cd "$(dirname "$0")/.."
model=$1 data=$2
shift 2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet
kpcn=target/release/kpcn
printf '%-16s %5s %12s %12s\n' scene spp noisy denoised
for s in "$@"; do
    for f in "$data/$s/$s"-000*spp.exr; do
        spp=$(basename "$f" | sed -E 's/.*-0*([0-9]+)spp.exr/\1/')
        $kpcn denoise "$f" -o "$work/d.exr" --model "$model" -q
        n=$($kpcn eval -r "$data/$s/$s-ref.exr" "$f" --format csv | tail -1 | cut -d, -f3)
        d=$($kpcn eval -r "$data/$s/$s-ref.exr" "$work/d.exr" --format csv | tail -1 | cut -d, -f3)
        printf '%-16s %5s %12.5f %12.5f\n' "$s" "$spp" "$n" "$d"
    done
done | awk '{print; if (NR > 0) {n += $3; d += $4; c++}} END {printf "%-16s %5s %12.5f %12.5f\n", "mean", "", n / c, d / c}'
