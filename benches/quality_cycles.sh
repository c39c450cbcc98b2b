#!/usr/bin/env bash
# Quality on the team's Blender Cycles dev set: denoises every noisy frame of every scene in
# DEV_DIR (each `SCENE-ref.exr` with its `SCENE-NNNNNspp.exr`) with MODEL and prints, per
# frame, relMSE / PSNR / 1−SSIM beside the noisy input and OIDN (from baseline.csv, same
# files, same metric conventions — `kpcn eval` reproduces that file's numbers), kpcn's
# relMSE as a multiple of OIDN's, and the same ratio with each method's own worst 0.1 % and
# 1 % of pixels dropped (kpcn eval on the folder's `*.oidn.exr`): outliers and bulk apart,
# and each method's brightness (its mean over the reference's, `kpcn eval`), which relMSE
# forgives. Then per sample count the geometric means of the three ratios and of each
# brightness over the scenes, the worst frame, the frames whose brightness is more than 5 %
# off, and the scenes whose relMSE does not fall from one sample count to the next.
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
scores() { # ref image → relmse,psnr,1-ssim,drop0.1,drop1,brightness
    $kpcn eval -r "$1" "$2" --format csv | tail -1 | cut -d, -f3-8
}
scenes=$(find "$dev" -maxdepth 1 -name '*-ref.exr' -printf '%f\n' | sed 's/-ref\.exr$//' | sort)
[ -n "$scenes" ] || { echo "quality_cycles: no SCENE-ref.exr in $dev" >&2; exit 1; }
printf '%-9s %4s | %-28s | %-28s | %-28s | %7s | %9s | %9s | %-16s | %s\n' scene spp "noisy relMSE/PSNR/1-SSIM" \
    "OIDN relMSE/PSNR/1-SSIM" "kpcn relMSE/PSNR/1-SSIM" "× OIDN" "−0.1% ×" "−1% ×" "bright OIDN/kpcn" "kpcn s"
ratios=$work/ratios
for scene in $scenes; do
    for f in "$dev/$scene"-*spp.exr; do
        spp=$(sed -n 's/.*-0*\([0-9][0-9]*\)spp\.exr$/\1/p' <<<"$f")
        start=$(date +%s%N)
        $kpcn denoise "$f" -o "$work/den.exr" --model "$model" -q --threads 2
        ms=$((($(date +%s%N) - start) / 1000000))
        k=$(scores "$dev/$scene-ref.exr" "$work/den.exr")
        o=$(scores "$dev/$scene-ref.exr" "${f%.exr}.oidn.exr")
        # × OIDN on the full relMSE uses baseline.csv (the published numbers); the trimmed
        # ratios use the OIDN image scored here.
        r=$(awk -F, -v k="$k" -v o="$o" -v b="$(baseline "$scene" "$spp" oidn | cut -d, -f1)" 'BEGIN {
            split(k, K, ","); split(o, O, ",");
            printf "%.2f %.2f %.2f %.3f %.3f", K[1] / b, K[4] / O[4], K[5] / O[5], O[6], K[6] }')
        read -r full drop01 drop1 bright_oidn bright_kpcn <<<"$r"
        echo "$spp $full $drop01 $drop1 $scene $(cut -d, -f1 <<<"$k") $bright_oidn $bright_kpcn" >>"$ratios"
        printf '%-9s %4s | %-28s | %-28s | %-28s | %7s | %9s | %9s | %-16s | %s\n' "$scene" "$spp" \
            "$(row "$(baseline "$scene" "$spp" noisy)")" "$(row "$(baseline "$scene" "$spp" oidn)")" \
            "$(row "$k")" "$full" "$drop01" "$drop1" "$bright_oidn / $bright_kpcn" "$((ms / 1000)).$(printf '%03d' $((ms % 1000)))"
    done
done
# Geometric means of kpcn ÷ OIDN per sample count (full, worst 0.1 % and 1 % dropped), the
# worst frame, and every scene whose relMSE does not fall as the sample count grows.
awk '{l[$1] += log($2); t[$1] += log($3); u[$1] += log($4); n[$1]++; if ($2 > w[$1]) { w[$1] = $2; ws[$1] = $5 }
        bo[$1] += log($7); bk[$1] += log($8); oo[$1] += ($7 > 1.05 || $7 < 0.95); ok[$1] += ($8 > 1.05 || $8 < 0.95) }
    END {for (s in n) printf "%s spp: relMSE %.2f× OIDN (geometric mean over %d scenes; worst 0.1%% dropped %.2f×, worst 1%% dropped %.2f×), worst scene %s %.2f×; brightness (mean ÷ reference'"'"'s) OIDN %.3f, kpcn %.3f, frames more than 5 %% off OIDN %d, kpcn %d\n",
        s, exp(l[s] / n[s]), n[s], exp(t[s] / n[s]), exp(u[s] / n[s]), ws[s], w[s], exp(bo[s] / n[s]), exp(bk[s] / n[s]), oo[s], ok[s]}' "$ratios" | sort -n
sort -k5,5 -k1,1n "$ratios" | awk '{ if ($5 == scene && $6 >= last) printf "%s: relMSE grows from %s to %s spp (%.5f → %.5f)\n", $5, lspp, $1, last, $6;
    scene = $5; last = $6; lspp = $1 }'
