#!/usr/bin/env bash
# How a model's quality depends on the render's exposure, on the team's Cycles dev set:
# every noisy frame of every scene in DEV_DIR is multiplied by K (radiance by K, its
# variances by K²), denoised with MODEL, divided by K again and scored against the unscaled
# reference, so every K is scored on the same pixels with the same metric (`kpcn eval`'s
# relMSE). A denoiser that does not care how bright a frame was rendered prints the same row
# for every K. Needs oiiotool, and python3 with numpy and OpenEXR.
#
#   benches/exposure_cycles.sh [MODEL] [K,K,…] [DEV_DIR]     # default: balanced 0.25,1,4
set -euo pipefail
cd "$(dirname "$0")/.."
model=${1:-balanced}
scales=${2:-0.25,1,4}
dev=${3:-../shared/data/cycles-dev}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet
kpcn=target/release/kpcn

# The multiplier of each channel, in the file's order: K for radiance, K² for its variances
# (benches/light_study.py's, the one home of that rule).
factors() { # file k
    python3 -c 'import sys; sys.path.insert(0, "benches"); from light_study import scale_factors
print(scale_factors(sys.argv[1], float(sys.argv[2])))' "$1" "$2"
}
IFS=, read -ra ks <<<"$scales"
printf '%-9s %4s' scene spp
for k in "${ks[@]}"; do printf ' | relMSE ×%-6s (× OIDN)' "$k"; done
echo
scenes=$(find "$dev" -maxdepth 1 -name '*-ref.exr' -printf '%f\n' | sed 's/-ref\.exr$//' | sort)
[ -n "$scenes" ] || { echo "exposure_cycles: no SCENE-ref.exr in $dev" >&2; exit 1; }
for scene in $scenes; do
    for spp in 4 16 64; do
        f=$(printf '%s/%s-%05dspp.exr' "$dev" "$scene" "$spp")
        oidn=$(grep "^$scene,$spp,oidn," "$dev/baseline.csv" | cut -d, -f4)
        printf '%-9s %4s' "$scene" "$spp"
        for k in "${ks[@]}"; do
            oiiotool "$f" --mulc "$(factors "$f" "$k")" -o "$work/in.exr"
            $kpcn denoise "$work/in.exr" -o "$work/out.exr" --model "$model" -q --threads 2
            oiiotool "$work/out.exr" --ch R=denoised.R,G=denoised.G,B=denoised.B \
                --mulc "$(awk -v k="$k" 'BEGIN {print 1 / k}')" -o "$work/back.exr"
            r=$($kpcn eval -r "$dev/$scene-ref.exr" "$work/back.exr" --format csv | tail -1 | cut -d, -f3)
            printf ' | %.5f (%5.2f)          ' "$r" "$(awk -v a="$r" -v b="$oidn" 'BEGIN {print a / b}')"
        done
        echo
    done
done
