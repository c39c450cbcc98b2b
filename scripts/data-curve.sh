#!/usr/bin/env bash
# Does more data help? Trains MODEL on a share of a training snapshot's scenes (every N-th
# of the scenes `--holdout 5` trains on, for each N given), with one recipe, so that
# benches/quality_corpus.sh can score every share on the same held-out scenes: the
# snapshot's every 5th scene by name, which no share trains on. A curve that still falls
# from a quarter to a half to all of the scenes says more scenes would help.
#
#   scripts/data-curve.sh SNAPSHOT MODEL WORK N [N...]   # SNAPSHOT: a folder with
#                                                        # manifest.csv and cache/, as
#                                                        # scripts/train-cycles.sh writes
#   KPCN_STEPS=N KPCN_LR=R KPCN_LOSS=L                   # the recipe (default 4000, 5e-5,
#   KPCN_TRAIN_ARGS="..."                                # l1: `spatial`'s Cycles segment)
#
# Writes WORK/share-N/{data,run}; a share already trained is skipped, an interrupted one
# resumed. Then, for instance:
#   CHANNELS=ViewLayer.Denoised SPLIT=validation ONLY='^cyc-' benches/quality_corpus.sh \
#     SNAPSHOT WORK/share-4/run/model.safetensors WORK/share-2/run/model.safetensors FULL
set -euo pipefail
cd "$(dirname "$0")/.."
usage="usage: scripts/data-curve.sh SNAPSHOT MODEL WORK N [N...]"
snapshot=${1:?$usage}
model=${2:?$usage}
work=${3:?$usage}
shift 3
[ $# -gt 0 ] || { echo "data-curve: name at least one share N (every N-th training scene)" >&2; exit 2; }
[ -f "$snapshot/manifest.csv" ] || { echo "data-curve: $snapshot/manifest.csv: no such file" >&2; exit 1; }
scripts/pinned-kpcn.sh "$work" >/dev/null
for n in "$@"; do
    dir=$work/share-$n
    [ -f "$dir/run/model.safetensors" ] && { echo "$dir/run: done"; continue; }
    mkdir -p "$dir/data"
    ln -sfn "$(realpath "$snapshot/cache")" "$dir/data/cache"
    python3 - "$snapshot/manifest.csv" "$dir/data/manifest.csv" "$n" <<'PY'
import csv, os, sys
rows = list(csv.reader(open(sys.argv[1])))
# The manifest's paths are relative to its folder: made relative to the share's.
src, dst = os.path.dirname(os.path.abspath(sys.argv[1])), os.path.dirname(os.path.abspath(sys.argv[2]))
move = lambda p: os.path.relpath(os.path.join(src, p), dst)
scenes = sorted({r[0] for r in rows[1:]})
held = set(scenes[4::5])  # kpcn train --holdout 5, and benches/quality_corpus.sh
keep = set([s for s in scenes if s not in held][::int(sys.argv[3])])
with open(sys.argv[2], "w", newline="") as f:
    w = csv.writer(f)
    w.writerows([rows[0]] + [r[:5] + [move(r[5]), move(r[6])] + r[7:] for r in rows[1:] if r[0] in keep])
print(f"data-curve: share {sys.argv[3]}: {len(keep)} of {len(scenes) - len(held)} training scenes")
PY
    start=(--init "$model")
    [ -f "$dir/run/checkpoint.safetensors" ] && start+=(--resume)
    # Nothing held out inside the share (--holdout above its scene count): the held-out
    # scenes are the snapshot's, scored afterwards.
    nice -n 19 "$work/kpcn" train --data "$dir/data" -o "$dir/run" "${start[@]}" --holdout 100000 \
        --steps "${KPCN_STEPS:-4000}" --phase2-steps 0 --batch 4 --patch 96 --lr "${KPCN_LR:-5e-5}" \
        --schedule cosine --loss "${KPCN_LOSS:-l1}" --augment --checkpoint-every 200 -q ${KPCN_TRAIN_ARGS:-}
    echo "$dir/run/model.safetensors"
done
