#!/usr/bin/env bash
# A frame file to file, as users run it, against the obvious alternative in the same run:
# `kpcn denoise` of a layered EXR (41 channels, a simulator frame resized) against
# `oiiotool in.exr -o copy.exr` plus OIDN 'high' filtering a frame of that size (pyoidn,
# filter only, after a warm-up), at 720p, 1080p and 4K; a 24-frame 720p sequence, per frame;
# a 4K host buffer through the C ABI (benches/capi_host.c), with what it adds to the host's
# peak RSS. Seconds are wall time, the fastest of REPEAT runs (default 3: a shared
# machine's first run after a pause can be a third slower); RSS is GNU time's peak, the
# largest of those runs.
#
#   [REPEAT=N] benches/throughput.sh [THREADS]        (needs pyoidn, numpy and GNU time)
set -euo pipefail
cd "$(dirname "$0")/.."
threads=${1:-$(nproc)}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet --bin kpcn
kpcn=target/release/kpcn
scripts/install.sh "$work/prefix" >/dev/null
PKG_CONFIG_PATH="$work/prefix/lib/pkgconfig" cc -O2 benches/capi_host.c -o "$work/capi_host" \
    $(PKG_CONFIG_PATH="$work/prefix/lib/pkgconfig" pkg-config --cflags --libs kpcn)

$kpcn render --family product --seed 1 --spp 16 --resolution 1280x720 --threads "$threads" -q -o "$work/r" >/dev/null
src=$(ls "$work"/r/*.exr | head -1)

repeat=${REPEAT:-3}
timed() { # OUT_VAR, command... → sets OUT_VAR to "fastest_seconds largest_peak_MB"
    local var=$1 best="" peak=0 s kb
    shift
    for _ in $(seq "$repeat"); do
        /usr/bin/time -f "%e %M" -o "$work/time" "$@" >/dev/null 2>"$work/err" || { cat "$work/err" >&2; exit 1; }
        read -r s kb <"$work/time"
        if [ -z "$best" ] || python3 -c "import sys; sys.exit(not $s < $best)"; then best=$s; fi
        peak=$((kb > peak ? kb : peak))
    done
    printf -v "$var" '%s %s' "$best" "$((peak / 1024))"
}

oidn() { # W H → filter seconds
    python3 - "$1" "$2" "$repeat" <<'PY'
import sys, time, numpy as np, pyoidn
w, h, repeat = map(int, sys.argv[1:4])  # OIDN runs on every core
rng = np.random.default_rng(0)
c, a = rng.random((h, w, 3), dtype=np.float32), rng.random((h, w, 3), dtype=np.float32)
nrm = rng.random((h, w, 3), dtype=np.float32) * 2 - 1
pyoidn.denoise(c, a, nrm, hdr=True, quality="high")
best = float("inf")
for _ in range(repeat):
    t = time.perf_counter()
    pyoidn.denoise(c, a, nrm, hdr=True, quality="high")
    best = min(best, time.perf_counter() - t)
print(f"{best:.3f}")
PY
}

echo "$(nproc) cores, $threads threads; kpcn: default model, defaults otherwise; fastest of $repeat runs"
printf '%-10s %10s %10s %10s %12s %12s %8s\n' frame copy_s oidn_s kpcn_s kpcn_MB copy_MB ratio
for res in 1280x720 1920x1080 3840x2160; do
    w=${res%x*} h=${res#*x}
    f="$work/in-$res.exr"
    [ "$res" = 1280x720 ] && cp "$src" "$f" || oiiotool "$src" --resize "$res" -o "$f"
    timed copy oiiotool "$f" -o "$work/copy.exr"
    o=$(oidn "$w" "$h")
    timed den "$kpcn" denoise "$f" -o "$work/den.exr" --threads "$threads" -q
    [ "$res" = 1280x720 ] && peer720=$(python3 -c "print(${copy%% *} + $o)") && single720=${den%% *}
    python3 -c "
c, cm = '$copy'.split(); d, dm = '$den'.split(); o = $o
print(f'{\"$res\":10} {float(c):10.2f} {o:10.2f} {float(d):10.2f} {dm:>12} {cm:>12} {float(d) / (float(c) + o):7.2f}x')"
done

mkdir -p "$work/seq"
for i in $(seq -f %04g 1 24); do ln -s "$work/in-1280x720.exr" "$work/seq/f.$i.exr"; done
# Against the 1280x720 row's copy + OIDN and single frame (one peer for both lines).
timed seq "$kpcn" denoise "$work/seq/f.####.exr" -o "$work/seq/d.####.exr" --threads "$threads" -q
python3 -c "
s, sm = '$seq'.split(); f = float(s) / 24
print(f'24 frames at 1280x720: {float(s):.1f} s, {f:.2f} s per frame ({f / $single720:.2f}x the single frame), peak {sm} MB; per frame {f / $peer720:.2f}x (copy + OIDN)')"

for mb in 64 512; do
    echo "C ABI, 3840x2160 host buffers, max_memory_mb $mb: $("$work/capi_host" 3840 2160 "$mb" "$threads")"
done
