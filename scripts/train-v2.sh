#!/usr/bin/env bash
# Further training segments of a ladder rung: fine-tunes scripts/train-ladder.sh's model on
# production-like simulator data with the relative (mean-seeking) loss, then with
# fireflies injected into the inputs.
#
#   scripts/train-v2.sh [RUNG]            # fast, balanced (default) or high
#   scripts/train-v2.sh compact           # `compact`, the 3-level network: one segment (below)
#   scripts/train-v2.sh RUNG --one-segment # that one segment from the rung (WORK/RUNG-one)
#   KPCN_WORK=DIR                         # work folder (default ./train-v2)
#   KPCN_LADDER=DIR                       # the ladder's work folder (default ./train-ladder)
#   KPCN_BASE=DIR                         # scripts/train-compact.sh's (default ./train-compact)
#   KPCN_STEPS=N KPCN_PHASE2_STEPS=M      # segment length (defaults 8000 and 2000)
#   KPCN_DEV=DIR                          # also score a folder of real renders at every
#                                         # validation (monitoring only: never trained on)
#
# Steps, each skipped when its output exists and resumed when interrupted:
#   1. the rung itself, from nothing: scripts/train-ladder.sh RUNG (WORK_LADDER/RUNG);
#   2. data: all 9 families x 8 permutations (seeds 6-13, disjoint from the ladder's 0-5)
#      at 2, 4, 16 and 64 spp with 512-spp references, plus `slit` seeds 0-5 with
#      2048-spp references (light through a slit converges slowly; the relative loss is
#      minimised by the mean, so the noisier 512-spp slit references still pull the right
#      way), all 320x180 and sampled as Cycles samples (Blackman-Harris 1.5 px, scrambled
#      Sobol'): 78 scenes, 312 frames. About 25 min on 2 cores; `kpcn dataset` resumes
#      where it stopped. The shipped models' data came from the sampler before it took
#      four scrambles per pixel (a checkout of 1c20f7d renders it; models/README.md);
#   3. segment 1, from step 1's weights: --loss relative, --augment (8 orientations),
#      8,000 + 2,000 steps, cosine schedule, lr 2e-4 / 5e-5, batch 4, 96-px patches
#      (WORK/RUNG, about 33 min; models/segments/balanced-v2.safetensors);
#   4. segment 2, from segment 1's weights: the same with --fireflies, 2,000 + 1,000 steps,
#      lr 1e-4 / 3e-5 (WORK/RUNG-fireflies);
#   5. segment 3, from segment 1's weights again: auto-exposed inputs (--exposure auto)
#      and rarer, brighter fireflies (at most one a patch, 300-10,000x its mean),
#      6,000 + 2,000 steps, lr 1e-4 / 3e-5 (WORK/RUNG-auto);
#   6. segment 4, the same from segment 1's weights on the spatial variance estimates that
#      files without variances (Blender's) get, with --permute-channels
#      (WORK/RUNG-spatial): the model `--model auto` runs on such files.
# For `compact`, step 1 is scripts/train-compact.sh and one segment follows, from its
# weights (with --one-segment, the same follows the rung's step 1): segment 1's and 3's recipes at once (--loss relative --augment --exposure auto,
# rare bright fireflies), 6,000 + 1,500 steps, lr 2e-4 / 5e-5 (WORK/compact-auto).
# Each segment resumes bit-exactly from its checkpoint.safetensors.
#
# Shipped (models/README.md): `balanced`, also the default, is segment 3
#   kpcn model half WORK/balanced-auto/model.safetensors -o models/balanced.safetensors
# and `compact` is WORK/compact-auto/model.safetensors as it is (f32); then each gets the
# firefly clamp chosen on our Cycles corpus (models/README.md):
#   kpcn model clamp models/balanced.safetensors --clamp significant -o models/balanced.safetensors
#   kpcn model clamp models/compact.safetensors --clamp fine-pairs-twice -o models/compact.safetensors
# Runs at low priority (nice 19) so builds and tests beside it keep their cores.
set -euo pipefail
cd "$(dirname "$0")/.."
rung=${1:-balanced}
work=${KPCN_WORK:-train-v2}
ladder=${KPCN_LADDER:-train-ladder}
mkdir -p "$work"

if [ "$rung" = compact ]; then
    base=${KPCN_BASE:-train-compact}
    scripts/train-compact.sh "$base"
    init=$base/run/model.safetensors
else
    KPCN_WORK=$ladder scripts/train-ladder.sh "$rung"
    init=$ladder/$rung/model.safetensors
fi

kpcn=$(scripts/pinned-kpcn.sh "$work")

data=(--spp 2,4,16,64 --resolution 320x180 -o "$work/data" -q)
nice -n 19 "$kpcn" dataset --count 8 --first-seed 6 --reference-spp 512 "${data[@]}"
nice -n 19 "$kpcn" dataset --families slit --count 6 --reference-spp 2048 "${data[@]}"

dev=()
if [ -n "${KPCN_DEV:-}" ]; then
    dev=(--dev "$KPCN_DEV")
fi
# segment NAME INIT PHASE1 PHASE2 LR LR2 [FLAGS...]: one resumable fine-tuning run.
segment() {
    local run=$work/$1 init=$2 steps=$3 phase2=$4 lr=$5 lr2=$6
    shift 6
    if [ -f "$run/model.safetensors" ]; then
        echo "$run: done"
        return
    fi
    local start=(--init "$init")
    if [ -f "$run/checkpoint.safetensors" ]; then
        start=(--resume)
    fi
    nice -n 19 "$kpcn" train --data "$work/data" -o "$run" "${start[@]}" "${dev[@]}" \
        --steps "$steps" --phase2-steps "$phase2" --batch 4 --patch 96 --lr "$lr" --lr-phase2 "$lr2" \
        --schedule cosine --loss relative --augment --checkpoint-every 200 --validate-every 1000 -q "$@"
    echo "$run/model.safetensors (log: $run/log.csv)"
}
# One segment with segment 1's and 3's recipes at once: `compact`, and a rung
# given --one-segment (WORK/RUNG-one).
if [ "$rung" = compact ] || [ "${2:-}" = --one-segment ]; then
    name=$rung-one
    [ "$rung" = compact ] && name=compact-auto
    segment "$name" "$init" 6000 1500 2e-4 5e-5 \
        --exposure auto --fireflies --firefly-most 1 --firefly-min-gain 300
    exit 0
fi
# Segment 1: the relative loss keeps sparse light's brightness, and fireflies' too.
segment "$rung" "$init" "${KPCN_STEPS:-8000}" "${KPCN_PHASE2_STEPS:-2000}" 2e-4 5e-5
# Segment 2: fireflies added to the inputs (never the references) teach it to drop them.
segment "$rung-fireflies" "$work/$rung/model.safetensors" 2000 1000 1e-4 3e-5 --fireflies
# Segment 3: every frame seen at one exposure (a raw network denoises a 4x brighter
# render worse); segment 2 cost detail on real renders, so outliers only where they are
# surely noise (300x the patch's mean and up, one patch in two), for longer.
segment "$rung-auto" "$work/$rung/model.safetensors" 6000 2000 1e-4 3e-5 \
    --exposure auto --fireflies --firefly-most 1 --firefly-min-gain 300
# Segment 4: the same for files without variances, trained on the estimates they get.
segment "$rung-spatial" "$work/$rung/model.safetensors" 6000 2000 1e-4 3e-5 \
    --variances spatial --exposure auto --fireflies --firefly-most 1 --firefly-min-gain 300 --permute-channels
