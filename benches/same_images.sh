#!/usr/bin/env bash
# Does a change keep the images? Denoises the example frame, a 1280×720 simulator frame and
# every noisy frame of the Cycles dev set with an older kpcn binary and with this tree's,
# and prints the largest relative difference of the denoised layers (|a − b| / max(|a|, |b|,
# 1e-3)) per file. A speed change must stay far below 1e-4 (a changed summation order, a
# vectorised exp); a model change shows up here too.
#
#   git worktree add /tmp/old <commit> && (cd /tmp/old && cargo build --release)
#   pip install OpenEXR numpy
#   benches/same_images.sh /tmp/old/target/release/kpcn [DEV_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
old=${1:?usage: benches/same_images.sh OLD_KPCN [DEV_DIR]}
dev=${2:-../shared/data/cycles-dev}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet
new=target/release/kpcn
$new render --family product --seed 1 --spp 16 --resolution 1280x720 -o "$work" -q
files=(examples/data/spheres-crop-00016spp.exr "$work"/product-0001-00016spp.exr "$dev"/*spp.exr)
for f in "${files[@]}"; do
    n=$(basename "$f" .exr)
    "$old" denoise "$f" -o "$work/$n.old.exr" -q --aovs --threads 2
    "$new" denoise "$f" -o "$work/$n.new.exr" -q --aovs --threads 2
    python3 - "$work/$n.old.exr" "$work/$n.new.exr" "$n" <<'EOF'
import sys
import numpy as np
import OpenEXR

def load(path):
    with OpenEXR.File(path, separate_channels=True) as f:
        return {k: np.asarray(v.pixels, dtype=np.float64) for k, v in f.channels().items() if k.startswith("denoised")}

a, b = load(sys.argv[1]), load(sys.argv[2])
assert a.keys() == b.keys(), (sorted(a), sorted(b))
worst = max((np.abs(a[k] - b[k]) / np.maximum(np.maximum(np.abs(a[k]), np.abs(b[k])), 1e-3)).max() for k in a)
print(f"{sys.argv[3]:<28} {len(a)} channels, max relative difference {worst:.2e}")
EOF
done
