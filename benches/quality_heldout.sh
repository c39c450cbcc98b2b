#!/usr/bin/env bash
# Quality on held-out simulator scenes: denoise the noisy frames of SCENES in a
# `kpcn dataset` folder with MODEL and print relMSE of the noisy input, OIDN 'high' (hdr,
# albedo, normal; benches/oidn_exr.py, when pyoidn is installed) and kpcn beside each
# other, then their means and geometric means.
#
#   benches/quality_heldout.sh MODEL DATA_DIR SCENE...
#
# The ladder's and the default's held-out scenes (every 5th by name of
# scripts/train-ladder.sh's data): cornell-0004 corridor-0003 courtyard-0002 dof-0001
# firefly-0000 firefly-0005 glass-0004 interior-0003 product-0002
set -euo pipefail
cd "$(dirname "$0")/.."
model=$1 data=$2
shift 2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet
kpcn=target/release/kpcn
oidn=$(python3 -c 'import pyoidn, OpenEXR' 2>/dev/null && echo yes || echo no)
score() { $kpcn eval -r "$1" "$2" --format csv | tail -1 | cut -d, -f3; }
printf '%-16s %5s %12s %12s %12s %9s\n' scene spp noisy oidn kpcn "÷ OIDN"
for s in "$@"; do
    for f in "$data/$s/$s"-000*spp.exr; do
        spp=$(basename "$f" | sed -E 's/.*-0*([0-9]+)spp.exr/\1/')
        ref=$data/$s/$s-ref.exr
        $kpcn denoise "$f" -o "$work/d.exr" --model "$model" -q
        o=nan
        if [ "$oidn" = yes ]; then
            python3 benches/oidn_exr.py "$f" "$work/o.exr"
            o=$(score "$ref" "$work/o.exr")
        fi
        printf '%-16s %5s %12.5f %12.5f %12.5f\n' "$s" "$spp" "$(score "$ref" "$f")" "$o" "$(score "$ref" "$work/d.exr")"
    done
done | awk '{printf "%s %9.2f\n", $0, $5 / $4; n += $3; o += $4; d += $5; ln += log($3); lo += log($4); ld += log($5); c++}
    END {printf "%-16s %5s %12.5f %12.5f %12.5f %9.2f\n", "mean", "", n / c, o / c, d / c, d / o;
         printf "%-16s %5s %12.5f %12.5f %12.5f %9.2f\n", "geometric mean", "", exp(ln / c), exp(lo / c), exp(ld / c), exp((ld - lo) / c)}'
