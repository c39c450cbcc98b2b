#!/usr/bin/env bash
# Quality on multilayer EXRs exactly as Blender 3.4 writes them (no variance passes, no half
# buffers: kpcn estimates variances spatially), from three scenes of our own
# (benches/blender_scenes.py: studio, slit, sunlit). Renders each at 4, 16 and 64 spp plus a
# reference (cached in WORK), then prints, per frame, relMSE against the reference
# (mean of (x − ref)² / (ref² + 0.01), as `kpcn eval`) and the mean brightness relative to
# the noisy input's, for the noisy input, Intel OIDN 2.5 fed Blender's Denoising
# Albedo/Normal (hdr, quality high) and kpcn MODEL; the geometric means, and the frames
# where kpcn is worse than its input or more than 1 % off its brightness.
#
#   apt-get install blender; pip install pyoidn OpenEXR numpy
#   benches/quality_blender.sh [MODEL] [WORK] [REF_SPP]     # MODEL: auto (default), default, spatial, FILE
#   DEV=../shared/data/cycles-dev benches/quality_blender.sh [MODEL] [WORK]
#
# With DEV, the frames are the team's dev set's raw/ renders (SCENE-NNNNNspp-raw.exr, scored
# against DEV/SCENE-ref.exr) instead of our three scenes: measured, never trained on.
# A measuring tool, never training data. Rendering takes most of the time (about 4 minutes
# on 2 cores for all 12 frames, references at 1024 spp), once: frames are kept in WORK.
set -euo pipefail
cd "$(dirname "$0")/.."
model=${1:-auto}
work=${2:-target/blender-bench}
ref_spp=${3:-1024}
mkdir -p "$work"
cargo build --release --quiet
kpcn=target/release/kpcn
render() { # scene spp seed out
    [ -s "$4" ] && return
    blender -b --factory-startup --python benches/blender_scenes.py -- "$1" "$2" "$3" "$4.tmp.exr" >"$4.log" 2>&1 ||
        { tail -20 "$4.log"; exit 1; }
    mv "$4.tmp.exr" "$4"
}
# frames: one line per noisy frame, "NAME NOISY REFERENCE REFERENCE_LAYER DENOISED".
frames=$work/frames.txt
: >"$frames"
if [ -n "${DEV:-}" ]; then
    for f in "$DEV"/raw/*-*spp-raw.exr; do
        name=$(basename "$f" -raw.exr)
        echo "$name $f $DEV/${name%-*spp}-ref.exr - $work/$name.dev.kpcn.exr" >>"$frames"
    done
else
    for scene in studio slit sunlit; do
        render "$scene" "$ref_spp" 4242 "$work/$scene-ref.exr"
        for spp in 4 16 64; do
            f=$(printf '%s/%s-%05dspp.exr' "$work" "$scene" "$spp")
            render "$scene" "$spp" 1 "$f"
            echo "$scene-${spp}spp $f $work/$scene-ref.exr ViewLayer.Combined. ${f%.exr}.kpcn.exr" >>"$frames"
        done
    done
fi
while read -r _ f _ _ out; do
    $kpcn denoise "$f" -o "$out" --model "$model" -q --threads 2
done <"$frames"
python3 - "$frames" <<'EOF'
import math, os, sys
import numpy as np, OpenEXR, pyoidn

def layer(path, name, comps="RGB", prefix="ViewLayer."):
    with OpenEXR.File(path, separate_channels=True) as f:
        ch = f.channels()
        return np.stack([np.asarray(ch[f"{prefix}{name}{c}"].pixels, np.float32) for c in comps], -1)

def relmse(x, ref):
    x = np.where(np.isfinite(x), x, 0).astype(np.float64)
    return float(np.mean((x - ref) ** 2 / (ref.astype(np.float64) ** 2 + 0.01)))

logs, worse, off = {"noisy": [], "oidn": [], "kpcn": []}, [], []
print(f"{'frame':<22} {'noisy relMSE':>12} {'OIDN relMSE':>12} {'kpcn relMSE':>12} {'kpcn/OIDN':>9}"
      f" {'OIDN mean':>9} {'kpcn mean':>9}")
for line in open(sys.argv[1]):
    name, f, ref_path, ref_layer, out = line.split()
    ref = layer(ref_path, "", prefix="" if ref_layer == "-" else ref_layer)
    noisy = layer(f, "Combined.")
    albedo, normal = layer(f, "Denoising Albedo."), layer(f, "Denoising Normal.", "XYZ")
    oidn = pyoidn.denoise(np.ascontiguousarray(noisy), np.ascontiguousarray(albedo),
                          np.ascontiguousarray(normal), hdr=True, quality="high")
    ours = layer(out, "Denoised.")
    e = {k: relmse(v, ref) for k, v in (("noisy", noisy), ("oidn", oidn), ("kpcn", ours))}
    for k in e:
        logs[k].append(math.log(e[k]))
    m = noisy.astype(np.float64).mean()
    mean = ours.astype(np.float64).mean() / m
    worse += [name] if e["kpcn"] > e["noisy"] else []
    off += [f"{name} {mean:.3f}"] if abs(mean - 1) > 0.01 else []
    print(f"{name:<22} {e['noisy']:12.5f} {e['oidn']:12.5f}"
          f" {e['kpcn']:12.5f} {e['kpcn'] / e['oidn']:9.2f} {oidn.mean() / m:9.3f} {mean:9.3f}")
g = {k: math.exp(sum(v) / len(v)) for k, v in logs.items()}
print(f"{'geometric mean':<22} {g['noisy']:12.5f} {g['oidn']:12.5f} {g['kpcn']:12.5f} {g['kpcn'] / g['oidn']:9.2f}")
print(f"worse than the noisy input: {', '.join(worse) or 'none'}")
print(f"mean more than 1 % off the input's: {', '.join(off) or 'none'}")
EOF
