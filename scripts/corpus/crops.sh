#!/usr/bin/env bash
# The committed Cycles crops of tests/data/cycles-crops/ (tests/cycles_crops.rs): 48×48
# windows of our own corpus scenes (scripts/cycles-corpus.sh, REF_SPP=512) where fireflies
# and caustics gather, at 4/16/64 spp (the channels the default model reads) beside the
# reference's RGB. Never the dev set's scenes.
#
#   scripts/corpus/crops.sh CORPUS_DIR        # e.g. train-cycles/corpus
set -euo pipefail
cd "$(dirname "$0")/../.."
corpus=${1:?usage: scripts/corpus/crops.sh CORPUS_DIR}
out=tests/data/cycles-crops
mkdir -p "$out"
inputs=R,G,B,albedo.R,albedo.G,albedo.B,albedoVariance.Z,colorVariance.Z,depth.Z,depthVariance.Z
inputs+=,diffuse.R,diffuse.G,diffuse.B,diffuseVariance.Z,normal.R,normal.G,normal.B,normalVariance.Z
inputs+=,specular.R,specular.G,specular.B,specularVariance.Z
# Scene, window origin: chosen by the most noisy pixels above 4× the reference's 3×3
# maximum (+0.5): glass spheres and a torus under two area lights (twice), glass under
# three spots at night, glass and metal under a point light at night with defocus.
for crop in "cyc-00052 40 8" "cyc-00052 200 24" "cyc-00059 152 88" "cyc-00075 88 104"; do
    read -r scene x y <<<"$crop"
    for f in 00004spp 00016spp 00064spp ref; do
        channels=$inputs
        [ "$f" = ref ] && channels=R,G,B
        oiiotool "$corpus/$scene/$scene-$f.exr" --cut "48x48+$x+$y" --origin +0+0 --fullpixels --ch "$channels" \
            -o "$out/$scene-x${x}y$y-$f.exr"
    done
done
ls -la "$out"
