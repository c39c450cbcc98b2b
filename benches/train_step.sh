#!/usr/bin/env bash
# Training speed of the default preset, our kernels against candle's stock ops, in one run:
# the same small simulator dataset, batch 6 of 64² patches (plus their context), the same
# seed, phase 1 and phase 2 steps, with and without `--stock-candle`. Prints each run's
# median patches per second per phase and the ratio. The losses of both runs are printed
# too: the network is the same, so they agree to float rounding.
#
#   benches/train_step.sh [STEPS] [THREADS]
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-20}
threads=${2:-2}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet
kpcn=target/release/kpcn
$kpcn dataset --count 1 --families cornell,interior,product,corridor --spp 4,16 --reference-spp 64 \
    --resolution 192x108 -o "$work/data" -q
median() { sort -g | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
declare -A rate
for mode in kpcn stock; do
    flag=""
    [ "$mode" = stock ] && flag="--stock-candle"
    $kpcn train --data "$work/data" -o "$work/$mode" --preset multiscale --patch 64 --batch 6 \
        --steps "$steps" --phase2-steps "$((steps / 2))" --holdout 1 --validate-every 100000 \
        --checkpoint-every 100000 --threads "$threads" -q $flag >/dev/null
    for phase in 1 2; do
        # Column 7 is patches per second; the first two steps warm up.
        rate[$mode$phase]=$(awk -F, -v p=$phase 'NR > 3 && $2 == p {print $7}' "$work/$mode/log.csv" | median)
    done
    echo "$mode: last losses $(tail -1 "$work/$mode/log.csv" | cut -d, -f5)"
done
printf '%-8s %14s %14s %8s\n' phase "kpcn patch/s" "stock patch/s" ratio
for phase in 1 2; do
    printf '%-8s %14s %14s %8s\n' $phase "${rate[kpcn$phase]}" "${rate[stock$phase]}" \
        "$(awk -v a="${rate[kpcn$phase]}" -v b="${rate[stock$phase]}" 'BEGIN {printf "%.2f", a / b}')"
done
