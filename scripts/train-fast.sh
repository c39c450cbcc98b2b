#!/usr/bin/env bash
# Rebuilds `fast` (models/fast.safetensors, `--quality fast`) from nothing: the quality
# ladder's narrowest rung, given `balanced`'s steps after the network and trained on our
# Cycles corpus beside simulator scenes. Each step is skipped when done and resumed when
# interrupted; about 70 min on 2 cores once the corpus is rendered.
#
#   scripts/train-fast.sh CORPUS      # our Cycles corpus (scripts/cycles-corpus.sh) with
#                                     # seeds 0-24, 100000-100015 and 110000-110007
#                                     # rendered (110008-110015 stay out: they test it)
#   KPCN_WORK=DIR                     # work folder (default ./train-fast)
#
# Steps:
#   1. the ladder's `fast` run from Xavier initialisation (scripts/train-ladder.sh fast,
#      WORK/ladder: about 30 min with its data), in f16 (`kpcn model half`);
#   2. `balanced`'s four steps after the network, each metadata only (the weights kept bit
#      for bit): the `significant` firefly clamp, the specular branch bounded to 2 standard
#      errors, the diffuse ceiling at 2 errors and the detail restored over 15x15 windows
#      (WORK/fast-steps.safetensors);
#   3. simulator data: `kpcn dataset --count 1` of seeds 14 and 15 (the 9 families at 4, 16
#      and 64 spp, 512-spp references, 320x180: 18 scenes, WORK/sim14, WORK/sim15);
#   4. three segments of scripts/train-cycles.sh on one snapshot (WORK/cycles/data: the
#      corpus's seeds above whose references are under relMSE 0.06, and the 18 simulator
#      scenes; every 5th scene by name held out), batch 4, 96-px patches, cosine schedules,
#      no phase 2:
#      a. `diffuse-l1`: the diffuse branch alone, --loss l1, 4,000 steps, lr 1e-4 (10 min);
#      b. `specular`: the specular branch afresh (--fresh specular --only specular), --loss
#         relmse-local, 3,000 steps, lr 3e-4 (9 min): the rung's own specular kernels had
#         collapsed to one tap and passed the input through;
#      c. `diffuse-relative`: the diffuse branch alone again, --loss relative (mean-seeking:
#         the l1 segment's pull towards the median darkened sparse light), 4,000 steps,
#         lr 1e-4 (10 min);
#   5. f16 (`kpcn model half`): WORK/fast.safetensors; copy it to models/fast.safetensors.
# Score it against `balanced` on the held-out scenes with
#   benches/quality_corpus.sh WORK/cycles/data balanced WORK/fast.safetensors
set -euo pipefail
cd "$(dirname "$0")/.."
corpus=${1:?usage: scripts/train-fast.sh CORPUS}
work=${KPCN_WORK:-train-fast}
mkdir -p "$work"

kpcn=$(scripts/pinned-kpcn.sh "$work")

KPCN_WORK=$work/ladder scripts/train-ladder.sh fast
steps=$work/fast-steps.safetensors
if [ ! -f "$steps" ]; then
    scripts/steps-after-network.sh "$kpcn" "$work/ladder/fast/model.safetensors" "$steps.partial"
    mv "$steps.partial" "$steps"
fi

for seed in 14 15; do
    [ -f "$work/sim$seed/manifest.csv" ] ||
        nice -n 19 "$kpcn" dataset -o "$work/sim$seed" --count 1 --first-seed "$seed" --spp 4,16,64 \
            --reference-spp 512 --resolution 320x180 -q
done

# One segment of scripts/train-cycles.sh on the shared snapshot: RUN INIT LOSS STEPS LR ARGS.
segment() {
    KPCN_WORK=$work/cycles KPCN_RUN=$1 KPCN_LOSS=$3 KPCN_STEPS=$4 KPCN_PHASE2_STEPS=0 KPCN_LR=$5 \
        KPCN_MAX_FLOOR=0.06 KPCN_SIM="$work/sim14 $work/sim15" KPCN_TRAIN_ARGS=$6 \
        scripts/train-cycles.sh "$corpus" 0-25,100000-100016,110000-110008 "$2"
}
segment diffuse-l1 "$steps" l1 4000 1e-4 "--only diffuse"
segment specular "$work/cycles/diffuse-l1/model.safetensors" relmse-local 3000 3e-4 "--fresh specular --only specular"
segment diffuse-relative "$work/cycles/specular/model.safetensors" relative 4000 1e-4 "--only diffuse"

"$kpcn" model half "$work/cycles/diffuse-relative/model.safetensors" -o "$work/fast.safetensors"
echo "$work/fast.safetensors"
