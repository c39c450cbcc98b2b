#!/usr/bin/env bash
# Cleaner references for a training snapshot's held-out scenes: at 64 spp our held-out
# scores are mostly the 512-spp references' own noise (BENCHMARKS.md, "Our held-out scores
# at 64 spp are mostly the references' own noise"), so models cannot be told apart there.
# Renders each held-out Cycles scene of SNAPSHOT (every 5th scene by name, as `kpcn train
# --holdout 5`) again with SPP samples (scene.py's reference mode: its seed and sampling
# pattern, so probably the old reference's samples and more), keeps its combined colour as
# OUT/SCENE-ref-SPPspp.exr
# (root R,G,B), and keeps OUT/manifest.csv: SNAPSHOT's held-out rows with that reference,
# for the scenes done so far.
#
#   scripts/corpus/clean-refs.sh SNAPSHOT OUT [SPP]       # SPP default 2048
#   SPLIT=all ONLY='^cyc-' benches/quality_corpus.sh OUT MODEL [MODEL...]
#
# Resumable: a scene whose reference is in OUT is not rendered again, so running it for a
# second snapshot of the same scenes (the raw files' and the layout's) only rewrites
# OUT/manifest.csv. About 3 min a scene at 2,048 spp here, over an hour for 24: start it
# with nohup.
set -euo pipefail
cd "$(dirname "$0")/../.."
usage="usage: scripts/corpus/clean-refs.sh SNAPSHOT OUT [SPP]"
snapshot=${1:?$usage}
out=${2:?$usage}
spp=${3:-2048}
[ -f "$snapshot/manifest.csv" ] || { echo "clean-refs: $snapshot/manifest.csv: no such file" >&2; exit 1; }
command -v blender >/dev/null || { echo "clean-refs: blender is missing: apt-get install blender" >&2; exit 1; }
mkdir -p "$out/tmp"
# manifest.csv: scene,family,seed,sample_seed,spp,file,reference,render_seconds
held=$(tail -n +2 "$snapshot/manifest.csv" | cut -d, -f1 | sort -u | awk 'NR % 5 == 0' | grep '^cyc-' || true)
[ -n "$held" ] || { echo "clean-refs: no held-out Cycles scene in $snapshot/manifest.csv" >&2; exit 1; }
# OUT/manifest.csv: SNAPSHOT's held-out rows whose scene has its new reference so far.
manifest() {
    python3 - "$snapshot" "$out" "$spp" $held <<'PY'
import csv, os, sys
snapshot, out, spp, held = sys.argv[1], sys.argv[2], int(sys.argv[3]), set(sys.argv[4:])
rows = list(csv.reader(open(os.path.join(snapshot, "manifest.csv"))))
move = lambda p: os.path.relpath(os.path.join(snapshot, p), out)
ref = lambda scene: f"{scene}-ref-{spp:05d}spp.exr"
with open(os.path.join(out, "manifest.csv.tmp"), "w", newline="") as f:
    csv.writer(f).writerows([rows[0]] + [r[:5] + [move(r[5]), ref(r[0])] + r[7:] for r in rows[1:]
                                         if r[0] in held and os.path.exists(os.path.join(out, ref(r[0])))])
os.replace(os.path.join(out, "manifest.csv.tmp"), os.path.join(out, "manifest.csv"))
PY
}
manifest
for scene in $held; do
    ref=$out/$scene-ref-$(printf '%05d' "$spp")spp.exr
    [ -f "$ref" ] && continue
    seed=$(grep -m1 "^$scene," "$snapshot/manifest.csv" | cut -d, -f3)
    echo "clean-refs: $scene (seed $seed), $spp spp"
    nice -n "${NICE:-10}" blender -b --factory-startup --python scripts/corpus/scene.py -- \
        "$seed" ref "$out/tmp/$scene.exr" "$spp" >"$out/tmp/blender.log" 2>&1 ||
        { tail -30 "$out/tmp/blender.log" >&2; exit 1; }
    oiiotool "$out/tmp/$scene.exr" --ch R=ViewLayer.Combined.R,G=ViewLayer.Combined.G,B=ViewLayer.Combined.B \
        --attrib kpcn:spp "$spp" --attrib kpcn:scene "$scene" -o "$out/tmp/$scene-ref.exr"
    mv "$out/tmp/$scene-ref.exr" "$ref"
    rm -f "$out/tmp/$scene.exr"
    manifest
done
echo "clean-refs: $out/manifest.csv"
