#!/usr/bin/env bash
# KPCN vs DPCN on the same data and budget (issue 5, the seed's comparison): trains both
# with the same loop, seed, patches and steps, plots their validation curves with
# `kpcn curves`, and prints relMSE / PSNR / 1 − SSIM of each on every held-out frame.
#
#   benches/kpcn_vs_dpcn.sh DATA_DIR OUT_DIR [STEPS]      (DATA_DIR from `kpcn dataset`)
#
# Both runs use one thread each, side by side, so they share the machine evenly.
set -euo pipefail
cd "$(dirname "$0")/.."
data=$1 out=$2 steps=${3:-600}
cargo build --release --quiet
kpcn=target/release/kpcn
mkdir -p "$out"
common=(--data "$data" --preset small --steps "$steps" --batch 4 --patch 48 --lr 1e-3
        --validate-every 50 --checkpoint-every 50 --threads 1 -q)
# One run builds the preprocessed-frame cache; the other must not race it.
$kpcn train "${common[@]}" --kind kpcn -o "$out/kpcn" &
$kpcn train "${common[@]}" --kind dpcn -o "$out/dpcn" --no-cache &
wait
$kpcn curves "$out/kpcn" "$out/dpcn" -o "$out/kpcn-vs-dpcn.png"
# Held-out scenes: every 5th in name order (kpcn train's default --holdout 5).
held=$(cut -d, -f1 "$data/manifest.csv" | tail -n +2 | sort -u | awk 'NR % 5 == 0')
printf '%-14s %5s  %-26s %-26s\n' scene spp "kpcn relMSE PSNR 1-SSIM" "dpcn relMSE PSNR 1-SSIM"
for s in $held; do
    for f in "$data/$s/$s"-000*spp.exr; do
        spp=$(basename "$f" | sed -E 's/.*-0*([0-9]+)spp.exr/\1/')
        line=$(printf '%-14s %5s ' "$s" "$spp")
        for k in kpcn dpcn; do
            $kpcn denoise "$f" -o "$out/d.exr" --model "$out/$k/model.safetensors" -q
            m=$($kpcn eval -r "$data/$s/$s-ref.exr" "$out/d.exr" --channels denoised --format csv | tail -1)
            line+=$(echo "$m" | awk -F, '{printf " %9.5f %6.2f %7.4f   ", $3, $4, $5}')
        done
        echo "$line"
    done
done
rm -f "$out/d.exr"
