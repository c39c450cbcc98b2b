#!/usr/bin/env bash
# Rebuilds the quality ladder's models (models/fast.safetensors, balanced, high) from
# nothing: simulator data at 320x180 (shared by the rungs), then one training run per rung
# from Xavier initialisation. Rerun it after an interruption: the data step is skipped when
# its manifest exists, a finished rung (WORK/RUNG/model.safetensors) is skipped, and an
# unfinished one resumes bit-exactly from its last checkpoint (`--resume`).
#
#   scripts/train-ladder.sh [RUNG...]     # rungs: fast balanced high (default: all three,
#                                         # balanced first)
#   KPCN_WORK=DIR                         # work folder (default ./train-ladder)
#   KPCN_STEPS_<RUNG>=N                   # phase-1 steps of a rung (defaults below)
#   KPCN_VARIANCES=spatial                # train on the 3x3 spatial variance estimates that
#                                         # files without variances get (Blender's): runs
#                                         # go to WORK/RUNG-spatial
#
# Then, to ship (f16 weights; the firefly clamp chosen on our Cycles corpus, models/README.md):
#   kpcn model half WORK/RUNG/model.safetensors -o models/RUNG.safetensors
#   kpcn model clamp models/RUNG.safetensors --clamp fine-pairs-twice -o models/RUNG.safetensors
# (models/balanced-spatial.safetensors: KPCN_VARIANCES=spatial scripts/train-ladder.sh balanced)
# Runs at low priority (nice 19) so builds and tests beside it keep their cores.
set -euo pipefail
cd "$(dirname "$0")/.."
work=${KPCN_WORK:-train-ladder}
rungs=("$@")
[ ${#rungs[@]} -gt 0 ] || rungs=(balanced fast high)
mkdir -p "$work"

variances=${KPCN_VARIANCES:-file}
kpcn=$(scripts/pinned-kpcn.sh "$work")

if [ ! -f "$work/data/manifest.csv" ]; then
    rm -rf "$work/data.partial"
    # The data the shipped models were trained on: the first 8 families, sampled as the
    # simulator first did (box filter, independent samples), before `slit` and the
    # production-like defaults existed.
    nice -n 19 "$kpcn" dataset --count 6 --spp 4,16,64 --reference-spp 512 --resolution 320x180 \
        --families cornell,interior,courtyard,product,glass,dof,firefly,corridor --pixel-filter box \
        --sampler random -o "$work/data.partial" -q
    mv "$work/data.partial" "$work/data"
fi

for rung in "${rungs[@]}"; do
    case $rung in
        fast) default_steps=5000 ;;
        balanced) default_steps=6000 ;;
        high) default_steps=2500 ;;
        *) echo "unknown rung '$rung': use fast, balanced or high" >&2; exit 2 ;;
    esac
    var=KPCN_STEPS_${rung^^}
    steps=${!var:-$default_steps}
    run=$work/$rung
    [ "$variances" = file ] || run=$work/$rung-$variances
    if [ -f "$run/model.safetensors" ]; then
        echo "$rung: done ($run/model.safetensors)"
        continue
    fi
    resume=()
    if [ -f "$run/checkpoint.safetensors" ]; then
        resume=(--resume)
    fi
    # 96-px patches with 16 px of context: 128-px regions, 4×4 at the 5th level.
    nice -n 19 "$kpcn" train --data "$work/data" -o "$run" --preset "$rung" \
        --steps "$steps" --phase2-steps 400 --batch 4 --patch 96 --lr 1e-3 --lr-phase2 1e-4 \
        --schedule cosine --variances "$variances" --checkpoint-every 200 --validate-every 500 -q \
        "${resume[@]}"
    echo "$rung: $run/model.safetensors (log: $run/log.csv)"
done
