#!/usr/bin/env bash
# kpcn's Cycles training corpus: procedural scenes (scripts/corpus/scene.py) rendered by
# Debian's Blender 3.4 headless, in both forms users have:
#   (a) kpcn's layout with variances and half buffers, from 64 independent 1-sample renders
#       (scripts/corpus/assemble.py), 4/16/64 spp, beside a reference: DIR/SCENE/*.exr,
#       listed in DIR/manifest.csv (what `kpcn train --data DIR` reads);
#   (b) raw multilayer EXRs exactly as Blender writes them (no variances) at 4/16/64 spp:
#       DIR/raw/SCENE-NNNNNspp-raw.exr, listed with the same references in
#       DIR/raw/manifest.csv (for `spatial`).
# DIR/corpus.jsonl gets one line per scene: what was drawn, render seconds, the reference's
# cost and its own expected error (its floor), and the variance calibration.
#
#   scripts/cycles-corpus.sh DIR FIRST_SEED COUNT        # e.g. target/cycles-corpus 0 200
#   scripts/cycles-corpus.sh DIR 100000 16               # the sun-patch series (scene.py)
#   scripts/cycles-corpus.sh DIR 110000 16               # the aimed sun-patch series
#   REF_SPP=512 SPPS=4,16,64 NICE=10 scripts/cycles-corpus.sh …
#
# Resumable: a scene is done when its line is in corpus.jsonl; an interrupted scene is
# redone from the start. Runs for hours: start it with nohup. The data stays out of git.
# Never renders the dev set's scenes: every scene is drawn from its seed.
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${1:?usage: scripts/cycles-corpus.sh DIR FIRST_SEED COUNT}
first=${2:?FIRST_SEED}
count=${3:?COUNT}
ref_spp=${REF_SPP:-512}
spps=${SPPS:-4,16,64}
nice_level=${NICE:-10}
n_max=${spps##*,}
python=${PYTHON:-python3}

command -v blender >/dev/null || { echo "cycles-corpus: blender is missing: apt-get install blender" >&2; exit 1; }
"$python" -c 'import numpy, OpenEXR' 2>/dev/null ||
    { echo "cycles-corpus: $python lacks numpy/OpenEXR: pip install numpy OpenEXR" >&2; exit 1; }
mkdir -p "$dir/raw" "$dir/tmp"
touch "$dir/corpus.jsonl"
header="scene,family,seed,sample_seed,spp,file,reference,render_seconds"

blend() { # SEED MODE OUT [ARG]
    nice -n "$nice_level" blender -b --factory-startup --python scripts/corpus/scene.py -- "$@" \
        >"$dir/tmp/blender.log" 2>&1 || { tail -30 "$dir/tmp/blender.log" >&2; return 1; }
}

# Appends rows to a manifest atomically (an interrupted run keeps a valid one).
append() { # MANIFEST ROWS…
    local m=$1
    shift
    { [ -s "$m" ] && cat "$m" || echo "$header"; printf '%s\n' "$@"; } >"$m.tmp"
    mv "$m.tmp" "$m"
}

for ((seed = first; seed < first + count; seed++)); do
    scene=$(printf 'cyc-%05d' "$seed")
    grep -q "\"scene\": \"$scene\"" "$dir/corpus.jsonl" && continue
    start=$(date +%s)
    rm -rf "${dir:?}/$scene" "$dir/tmp/$scene"
    mkdir -p "$dir/$scene"
    blend "$seed" noisy "$dir/tmp/$scene" "$n_max"
    noisy_s=$(($(date +%s) - start))
    family=cycles-$("$python" -c 'import json,sys; print(json.load(open(sys.argv[1]))["scene"]["stage"])' "$dir/tmp/$scene/log.json")
    blend "$seed" ref "$dir/tmp/$scene/ref.exr" "$ref_spp"
    report=$(nice -n "$nice_level" "$python" scripts/corpus/assemble.py "$dir/tmp/$scene" "$dir/tmp/$scene/ref.exr" \
        "$dir/$scene" "$scene" "$spps")
    rows=() raw_rows=()
    for spp in ${spps//,/ }; do
        raw=$(printf '%s-%05dspp-raw.exr' "$scene" "$spp")
        blend "$seed" raw "$dir/raw/$raw" "$spp"
        rows+=("$scene,$family,$seed,0,$spp,$scene/$(printf '%s-%05dspp.exr' "$scene" "$spp"),$scene/$scene-ref.exr,$noisy_s")
        raw_rows+=("$scene,$family-raw,$seed,$((1000 + spp)),$spp,$raw,../$scene/$scene-ref.exr,0")
    done
    append "$dir/manifest.csv" "${rows[@]}"
    append "$dir/raw/manifest.csv" "${raw_rows[@]}"
    "$python" - "$dir/tmp/$scene/log.json" "$dir/tmp/$scene/ref.exr.json" "$report" "$noisy_s" "$(($(date +%s) - start))" \
        >>"$dir/corpus.jsonl" <<'EOF'
import json, sys
noisy, ref, report = json.load(open(sys.argv[1])), json.load(open(sys.argv[2])), json.loads(sys.argv[3])
line = {"scene": report["scene"], "drawn": noisy["scene"], "noisy_seconds": int(sys.argv[4]),
        "scene_seconds": int(sys.argv[5]), **report}
print(json.dumps(line))
EOF
    rm -rf "${dir:?}/tmp/$scene"
    echo "cycles-corpus: $scene done in $(($(date +%s) - start)) s: $(tail -1 "$dir/corpus.jsonl" | cut -c1-200)" >&2
done
