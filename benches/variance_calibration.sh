#!/usr/bin/env bash
# Whether the simulator's written variances say how noisy its frames really are: renders
# one permutation of each FAMILY at K sample seeds, 4 / 16 / 64 spp, and prints per family
# and sample count the mean written `colorVariance` over the variance of the pixel means
# measured across the seeds (1 is calibrated), and that measured variance (the noise
# itself, to compare samplers at equal spp). tests/sim.rs checks the same on a small scene.
#
#   benches/variance_calibration.sh [SAMPLER] [K] [FAMILY...]   (needs numpy and OpenEXR)
#   (defaults: sobol, 12 seeds, cornell product interior firefly)
set -euo pipefail
cd "$(dirname "$0")/.."
sampler=${1:-sobol}
k=${2:-12}
shift $(($# < 2 ? $# : 2))
families=${*:-cornell product interior firefly}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet --bin kpcn
for family in $families; do
    for s in $(seq 1 "$k"); do
        target/release/kpcn render --family "$family" --seed 1 --spp 4,16,64 --resolution 48x32 \
            --sampler "$sampler" --sample-seed "$s" -q -o "$work/$family-$s" >/dev/null
    done
done
python3 - "$work" "$sampler" $families <<'PY'
import glob, sys
import numpy as np, OpenEXR
work, sampler, families = sys.argv[1], sys.argv[2], sys.argv[3:]
read = lambda f, name: OpenEXR.File(f).parts[0].channels[name].pixels.astype(np.float64)
print(f"{'family':10} {'sampler':8} {'spp':>4} {'written / real':>15} {'real variance':>14}")
for family in families:
    for spp in (4, 16, 64):
        files = sorted(glob.glob(f"{work}/{family}-*/*-{spp:05d}spp.exr"))
        means = np.stack([read(f, "RGB") for f in files])
        real = means.var(0, ddof=1).mean()
        written = np.mean([read(f, "colorVariance.Z").mean() for f in files])
        print(f"{family:10} {sampler:8} {spp:4} {written / real:15.2f} {real:14.3e}")
PY
