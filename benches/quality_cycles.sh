#!/usr/bin/env bash
# Quality on the team's Blender Cycles dev set: denoise every noisy frame with MODEL and
# print relMSE / PSNR / 1−SSIM beside the noisy input and OIDN (from baseline.csv, same
# files, same metric conventions — `kpcn eval` reproduces that file's numbers), kpcn's
# relMSE as a multiple of OIDN's, and per sample count the geometric mean of that ratio
# over the scenes (issue 15's target: ≤ 1.25, no frame above 2).
#
#   benches/quality_cycles.sh [MODEL] [DEV_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
model=${1:-default}
dev=${2:-../shared/data/cycles-dev}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet
kpcn=target/release/kpcn

row() { # relmse psnr one_minus_ssim → "0.01234 / 33.21 / 0.1234"
    awk -F, '{printf "%.5f / %.2f / %.4f", $1, $2, $3}' <<<"$1"
}
baseline() { # scene spp method → relmse,psnr,1-ssim
    grep "^$1,$2,$3," "$dev/baseline.csv" | awk -F, '{printf "%s,%s,%s", $4, $5, 1 - $6}'
}
printf '%-9s %4s | %-28s | %-28s | %-28s | %7s | %s\n' scene spp "noisy relMSE/PSNR/1-SSIM" \
    "OIDN relMSE/PSNR/1-SSIM" "kpcn relMSE/PSNR/1-SSIM" "× OIDN" "kpcn s"
ratios=$work/ratios
for scene in interior spheres; do
    for spp in 4 16 64; do
        f=$(printf '%s/%s-%05dspp.exr' "$dev" "$scene" "$spp")
        start=$(date +%s%N)
        $kpcn denoise "$f" -o "$work/den.exr" --model "$model" -q --threads 2
        ms=$((($(date +%s%N) - start) / 1000000))
        k=$($kpcn eval -r "$dev/$scene-ref.exr" "$work/den.exr" --format csv | tail -1 | cut -d, -f3,4,5)
        ratio=$(awk -v k="${k%%,*}" -v o="$(baseline $scene $spp oidn | cut -d, -f1)" 'BEGIN {printf "%.2f", k / o}')
        echo "$spp $ratio" >>"$ratios"
        printf '%-9s %4s | %-28s | %-28s | %-28s | %7s | %s\n' "$scene" "$spp" "$(row "$(baseline $scene $spp noisy)")" \
            "$(row "$(baseline $scene $spp oidn)")" "$(row "$k")" "$ratio" "$((ms / 1000)).$(printf '%03d' $((ms % 1000)))"
    done
done
# Geometric mean of kpcn ÷ OIDN per sample count, and the worst frame.
awk '{l[$1] += log($2); n[$1]++; if ($2 > w[$1]) w[$1] = $2}
    END {for (s in n) printf "%s spp: relMSE %.2f× OIDN (geometric mean over %d scenes), worst frame %.2f×\n", s, exp(l[s] / n[s]), n[s], w[s]}' \
    "$ratios" | sort -n
