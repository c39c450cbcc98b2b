#!/usr/bin/env bash
# Fine-tunes a shipped model on our Cycles corpus (scripts/cycles-corpus.sh): the domain
# the team measures on, instead of the simulator alone. Every 5th scene of the snapshot by
# name is held out for validation, as benches/quality_corpus.sh scores it; the team's dev
# set is never read.
#
#   scripts/train-cycles.sh CORPUS SCENES [MODEL]   # SCENES: N, the corpus's first N
#                                                   # scenes, or A-B, seeds A to B−1, or
#                                                   # several ranges joined by commas
#                                                   # (0-126,100000-100016); default
#                                                   # model: balanced. CORPUS/raw trains
#                                                   # on the files as Blender writes them
#                                                   # (scripts/train-spatial.sh)
#   KPCN_WORK=DIR                                   # work folder (default ./train-cycles/ft)
#   KPCN_RUN=NAME                                   # the segment's folder in it (default
#                                                   # run): a further segment on the same
#                                                   # data snapshot and frame cache
#   KPCN_STEPS=N KPCN_PHASE2_STEPS=M                # segment length (default 3000 + 500)
#   KPCN_LR=R KPCN_LR2=R2                           # learning rates (default 5e-5, 2e-5)
#   KPCN_MAX_FLOOR=F                                # leave out scenes whose reference is
#                                                   # noisier than relMSE F (default 0.03)
#   KPCN_LOSS=L                                     # kpcn train --loss (default relative)
#   KPCN_TRAIN_ARGS="..."                           # more `kpcn train` options, e.g.
#                                                   # --fireflies
#   KPCN_SIM="DIR..."                               # also train on simulator datasets
#                                                   # (`kpcn dataset -o DIR`): the families
#                                                   # the corpus lacks (light through a
#                                                   # slit) keep their brightness
#
# Steps, each skipped when done and resumed when interrupted:
#   1. a frozen snapshot of the corpus's manifest (its SCENES, less those whose
#      512-spp reference is itself noisy: corpus.jsonl's reference_relmse_floor above
#      KPCN_MAX_FLOOR, night scenes lit by tiny lights, where a reference firefly would be
#      taught as light), and KPCN_SIM's scenes, so that a corpus still rendering does not
#      change the data under a resumed run; every 5th of its scenes by name is validation
#      (`--holdout 5`);
#   2. one segment from MODEL's weights: --loss relative (KPCN_LOSS) --augment, batch 4, 96-px patches,
#      lr 5e-5 / 2e-5 cosine (KPCN_LR, KPCN_LR2), validation every 250 steps (the learning
#      curve in log.csv).
# Then benches/quality_corpus.sh WORK/data MODEL WORK/run/model.safetensors scores it against
# MODEL on the same held-out scenes. Runs at low priority (nice 19).
set -euo pipefail
cd "$(dirname "$0")/.."
corpus=${1:?usage: scripts/train-cycles.sh CORPUS SCENES [MODEL]}
scenes=${2:?usage: scripts/train-cycles.sh CORPUS SCENES [MODEL]}
model=${3:-balanced}
# ranges: "A B" lines, seeds A to B−1, one per comma-separated range.
ranges=$(tr ',' '\n' <<<"$scenes" | awk -F- 'NF == 2 { print $1, $2; next } NF == 1 { print 0, $1; next } { exit 1 }') ||
    { echo "train-cycles: SCENES is N, A-B or A-B,C-D…, not $scenes" >&2; exit 1; }
work=${KPCN_WORK:-train-cycles/ft}
mkdir -p "$work"

kpcn=$(scripts/pinned-kpcn.sh "$work")

data=$work/data
if [ ! -f "$data/manifest.csv" ]; then
    mkdir -p "$data"
    # manifest.csv: scene,family,seed,sample_seed,spp,file,reference,render_seconds; paths
    # relative to the snapshot's folder.
    rel=$(realpath --relative-to="$data" "$corpus")
    # The raw files' folder (CORPUS/raw) lists its scenes beside the corpus's own record.
    jsonl=$corpus/corpus.jsonl
    [ -f "$jsonl" ] || jsonl=$corpus/../corpus.jsonl
    noisy=$(python3 -c '
import json, sys
for line in open(sys.argv[1]):
    d = json.loads(line)
    if d.get("reference_relmse_floor", 0) > float(sys.argv[2]):
        print(d["scene"])' "$jsonl" "${KPCN_MAX_FLOOR:-0.03}" | tr '\n' ' ')
    while read -r first end; do
        found=$(tail -n +2 "$corpus/manifest.csv" | awk -F, -v a="$first" -v b="$end" '$3 >= a && $3 < b' | cut -d, -f1 | sort -u | wc -l)
        [ "$found" -eq $((end - first)) ] || { echo "train-cycles: $corpus has $found of the scenes $first to $((end - 1))" >&2; exit 1; }
    done <<<"$ranges"
    {
        head -1 "$corpus/manifest.csv"
        tail -n +2 "$corpus/manifest.csv" | awk -F, -v ranges="$ranges" -v rel="$rel" -v noisy="$noisy" '
            BEGIN { OFS = ","; split(noisy, l, " "); for (i in l) skip[l[i]] = 1
                    n = split(ranges, r, "\n"); for (i = 1; i <= n; i++) { split(r[i], ab, " "); lo[i] = ab[1]; hi[i] = ab[2] } }
            { inside = 0; for (i = 1; i <= n; i++) if ($3 >= lo[i] && $3 < hi[i]) inside = 1 }
            inside && !($1 in skip) { $6 = rel "/" $6; $7 = rel "/" $7; print }'
        for dir in ${KPCN_SIM:-}; do
            sim=$(realpath --relative-to="$data" "$dir")
            tail -n +2 "$dir/manifest.csv" | awk -F, -v rel="$sim" 'BEGIN { OFS = "," } { $6 = rel "/" $6; $7 = rel "/" $7; print }'
        done
    } >"$data/manifest.partial"
    echo "train-cycles: left out for noisy references: ${noisy:-none}"
    mv "$data/manifest.partial" "$data/manifest.csv"
fi

run=$work/${KPCN_RUN:-run}
if [ -f "$run/model.safetensors" ]; then
    echo "$run: done"
    exit 0
fi
start=(--init "$(
    case $model in
        *.safetensors) echo "$model" ;;
        *) "$kpcn" model half "$model" -o "$work/init.safetensors" >/dev/null && echo "$work/init.safetensors" ;;
    esac
)")
# --init stays (options such as --fresh require it); --resume reads the checkpoint instead.
[ -f "$run/checkpoint.safetensors" ] && start+=(--resume)
nice -n 19 "$kpcn" train --data "$data" -o "$run" "${start[@]}" --holdout 5 \
    --steps "${KPCN_STEPS:-3000}" --phase2-steps "${KPCN_PHASE2_STEPS:-500}" --batch 4 --patch 96 \
    --lr "${KPCN_LR:-5e-5}" --lr-phase2 "${KPCN_LR2:-2e-5}" --schedule cosine --loss "${KPCN_LOSS:-relative}" --augment \
    --checkpoint-every 200 --validate-every 250 -q ${KPCN_TRAIN_ARGS:-}
echo "$run/model.safetensors (log: $run/log.csv)"
