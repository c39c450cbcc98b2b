#!/usr/bin/env bash
# Retrains a shipped multi-scale model's specular branch from nothing, on simulator scenes
# and our Cycles corpus, and keeps its diffuse branch. The ladder's specular branches never
# trained: their kernels collapsed to one tap within the first steps, so specular light
# passed through unfiltered (BENCHMARKS.md, "The specular branch that never trained").
# `--loss relmse-local` trains it: the prediction's denominator (`relative`) and the
# reference's (`relmse`, `relative-smaller`) collapse it again or darken bright regions.
#
#   scripts/train-specular.sh CORPUS SCENES [MODEL]  # SCENES as scripts/train-cycles.sh
#                                                    # takes them (default model: balanced)
#   KPCN_WORK=DIR                                    # work folder (default ./train-specular)
#   KPCN_STEPS=N KPCN_LR=R KPCN_LOSS=L               # length, learning rate and loss
#                                                    # (default 3000, 3e-4, relmse-local)
#   KPCN_FIREFLIES=1                                 # also --fireflies: synthetic single-
#                                                    # pixel outliers in the noisy input only
#                                                    # (BENCHMARKS.md: lr 1e-4 with them)
#
# Steps, each skipped when done and resumed when interrupted:
#   1. simulator data: the 8 families other than `slit` x seeds 20-22 (disjoint from the
#      ladder's and scripts/train-v2.sh's) at 4, 16 and 64 spp with 512-spp references, and
#      `slit` seeds 20-22 with 2048-spp references, 320x180, the default (Cycles-like)
#      sampling: 27 scenes, about 20 min on 2 cores (WORK/sim);
#   2. scripts/train-cycles.sh CORPUS SCENES MODEL with KPCN_SIM=WORK/sim: MODEL's diffuse
#      branch as it is, the specular branch afresh (--fresh specular --only specular),
#      --loss relmse-local (KPCN_LOSS) --augment, KPCN_STEPS steps, lr 3e-4 (KPCN_LR) cosine, no phase 2,
#      every 5th scene held out (WORK/MODEL/run, its learning curve in log.csv); `spatial`
#      on spatial variance estimates with --permute-channels, as it was trained;
#   3. the shipped form: f16 for the ladder's rungs (`kpcn model half`), f32 for `compact`
#      and `spatial`, with the firefly clamp (`kpcn model clamp`: significant for `balanced`,
#      fine-pairs-twice for the others) and the specular branch bounded to 2 standard
#      errors of each pixel's mean (`kpcn model bound`: without it the new branch spreads
#      caustic fireflies into dark neighbours and blurs textures every sample saw), and for
#      `balanced` the diffuse branch's ceiling, 2 standard errors past its similar
#      neighbours' noisy mean (`kpcn model bound --branch diffuse`: light no longer bleeds
#      across edges) and its detail restored over 15x15 windows (`kpcn model detail
#      --radius 7`: the shading of bumps the kernels smoothed flat comes back),
#      WORK/MODEL.safetensors; copy it to models/MODEL.safetensors (`balanced` ships so).
# Score it against MODEL on the held-out scenes with
#   benches/quality_corpus.sh WORK/MODEL/data MODEL WORK/MODEL.safetensors
set -euo pipefail
cd "$(dirname "$0")/.."
corpus=${1:?usage: scripts/train-specular.sh CORPUS SCENES [MODEL]}
scenes=${2:?usage: scripts/train-specular.sh CORPUS SCENES [MODEL]}
model=${3:-balanced}
work=${KPCN_WORK:-train-specular}
mkdir -p "$work"

kpcn=$(scripts/pinned-kpcn.sh "$work")

sim=(--spp 4,16,64 --resolution 320x180 --count 3 --first-seed 20 -o "$work/sim" -q)
nice -n 19 "$kpcn" dataset --families cornell,corridor,courtyard,dof,firefly,glass,interior,product --reference-spp 512 "${sim[@]}"
nice -n 19 "$kpcn" dataset --families slit --reference-spp 2048 "${sim[@]}"

# `spatial` reads the spatial variance estimates files without variances get, and was
# trained with its colour channels permuted: so is its new branch.
extra=""
[ "${KPCN_FIREFLIES:-0}" = 1 ] && extra="--fireflies"
[ "$model" = spatial ] && extra="$extra --variances spatial --permute-channels"
KPCN_WORK=$work/$model KPCN_SIM=$work/sim KPCN_LOSS=${KPCN_LOSS:-relmse-local} KPCN_LR=${KPCN_LR:-3e-4} KPCN_STEPS=${KPCN_STEPS:-3000} \
    KPCN_PHASE2_STEPS=0 KPCN_TRAIN_ARGS="--fresh specular --only specular $extra" \
    scripts/train-cycles.sh "$corpus" "$scenes" "$model"

out=$work/$model.safetensors
if [ "$model" = balanced ]; then
    # `balanced` ships with all of its steps after the network, the diffuse ceiling and
    # detail among them (kept off the other models: not measured on them).
    scripts/steps-after-network.sh "$kpcn" "$work/$model/run/model.safetensors" "$out"
else
    # The ladder's rungs ship in f16; `compact` and `spatial` in f32, as they were.
    case $model in
        fast | high) "$kpcn" model half "$work/$model/run/model.safetensors" -o "$out" ;;
        *) cp "$work/$model/run/model.safetensors" "$out" ;;
    esac
    "$kpcn" model clamp "$out" --clamp fine-pairs-twice -o "$out"
    "$kpcn" model bound "$out" --branch specular --errors 2 -o "$out"
fi
echo "$out"
