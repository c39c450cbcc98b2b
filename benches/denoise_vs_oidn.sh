#!/usr/bin/env bash
# Seconds and peak RSS per frame: kpcn's presets vs Intel Open Image Denoise, same run,
# same machine, same thread count. Needs `pip install pyoidn numpy` (a peer for the
# comparison only, never a kpcn dependency) and GNU time (`apt-get install time`).
#
#   benches/denoise_vs_oidn.sh [RESOLUTION] [MODELS...]     e.g. 1280x720 default small-flat paper
set -euo pipefail
cd "$(dirname "$0")/.."
res=${1:-1280x720}
shift || true
models=("${@:-default}")
threads=2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

cargo build --release --quiet
kpcn=target/release/kpcn
$kpcn render --family product --seed 1 --spp 16 --resolution "$res" --threads $threads -q -o "$work" >/dev/null
frame=$(ls "$work"/*.exr | head -1)

measure() { # label, command...
    local label=$1; shift
    /usr/bin/time -f "%e %M" -o "$work/time" "$@" >/dev/null 2>"$work/err" || { cat "$work/err"; exit 1; }
    read -r secs kb <"$work/time"
    printf '%-28s %8.2f s %8.0f MB\n' "$label" "$secs" "$((kb / 1024))"
    echo "$secs" >"$work/$label.secs"
}

echo "frame $res, $threads threads, $(nproc) cores"
measure oidn-high python3 - "$res" $threads <<'PY'
import sys, time, numpy as np, pyoidn
w, h = map(int, sys.argv[1].split("x"))
rng = np.random.default_rng(0)
color = rng.random((h, w, 3), dtype=np.float32)
albedo = rng.random((h, w, 3), dtype=np.float32)
normal = rng.random((h, w, 3), dtype=np.float32) * 2 - 1
pyoidn.denoise(color, albedo, normal, hdr=True, quality="high")  # warm-up: weights, threads
t = time.perf_counter()
pyoidn.denoise(color, albedo, normal, hdr=True, quality="high")
print(f"oidn filter only: {time.perf_counter() - t:.3f} s", file=sys.stderr)
PY
grep "filter only" "$work/err" || true
oidn=$(grep -o "[0-9.]* s" "$work/err" | head -1 | cut -d' ' -f1)
for m in "${models[@]}"; do
    # Timing only: presets (untrained) cost what trained models of their shape cost.
    measure "kpcn-$m" $kpcn denoise "$frame" -o "$work/out-$m.exr" --model "$m" --allow-untrained --threads $threads -q
    secs=$(cat "$work/kpcn-$m.secs")
    python3 -c "print(f'  kpcn-$m / oidn-high (filter only) = {$secs / $oidn:.1f}x (kpcn time includes EXR read + write)')"
done
