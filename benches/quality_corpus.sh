#!/usr/bin/env bash
# Quality on our own Cycles renders (scripts/cycles-corpus.sh), the validation set that
# models are chosen by (never the team's dev set): denoises every noisy frame listed in
# DIR/manifest.csv (the corpus, or the snapshot scripts/train-cycles.sh trains on) with each
# MODEL and prints, per sample count, the geometric mean over scenes of relMSE, and of
# relMSE with the worst 0.1 % and 1 % of pixels dropped, each also as a multiple of the
# first model's. SPLIT=validation (default) scores the scenes training leaves out (every
# 5th by name, as `kpcn train --holdout 5`); SPLIT=all scores every scene, for models
# trained on none of them. CHANNELS=LAYER scores that layer of the output instead of
# `denoised` (files as Blender writes them, corpus/raw/: CHANNELS=ViewLayer.Denoised).
# ONLY=REGEX scores only the split's scenes whose name matches (an awk regular expression:
# ONLY='^cyc-' for the Cycles scenes of a snapshot that mixes in simulator scenes).
# MAX_FLOOR=F leaves out the scenes whose reference is itself noisier than relMSE F
# (`reference_relmse_floor`, below), as scripts/train-cycles.sh's KPCN_MAX_FLOOR leaves
# them out of training: scenes no model trained on, scored alike, are
# `SPLIT=all ONLY='^cyc-000(4[6-9]|[5-7][0-9]|8[0-5])$' MAX_FLOOR=0.06` on the corpus.
# PER_SCENE=1 also prints each frame's relMSE, and the other models' multiples of it.
# "light kept" is the denoised frame's mean over the noisy input's (geometric mean over the
# frames; the input is the root R,G,B, or LAYER.Combined beside LAYER.Denoised), and
# "off > 5 %" counts the frames whose ratio is more than 5 % from 1; "÷ reference mean" is
# the denoised mean over the reference's (geometric mean), for frames lit by a few hits,
# whose noisy mean is itself several per cent off: brightness, which
# relMSE forgives (light missing from a bright pixel costs less than light in a dark one;
# python3 with numpy and OpenEXR reads the means, as for benches/quality_blender.sh).
# "× floor" is relMSE over the reference's own expected error (`reference_relmse_floor` in
# the corpus's corpus.jsonl, beside the references' folders; geometric mean over the frames
# that have one): near 1, a frame's score is mostly the reference's noise, and cannot tell
# better models apart.
#
#   benches/quality_corpus.sh DIR MODEL [MODEL...]
set -euo pipefail
cd "$(dirname "$0")/.."
corpus=${1:?usage: benches/quality_corpus.sh CORPUS_DIR MODEL [MODEL...]}
shift
[ $# -gt 0 ] || { echo "quality_corpus: name at least one model" >&2; exit 2; }
split=${SPLIT:-validation}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release --quiet
kpcn=target/release/kpcn
# manifest.csv: scene,family,seed,sample_seed,spp,file,reference,render_seconds
held=$(tail -n +2 "$corpus/manifest.csv" | cut -d, -f1 | sort -u | awk 'NR % 5 == 0' | tr '\n' ' ')
rows=$(tail -n +2 "$corpus/manifest.csv" | awk -F, -v which="$split" -v held="$held" -v only="${ONLY:-.}" '
    BEGIN { split(held, l, " "); for (i in l) h[l[i]] = 1 } (which == "all" || ($1 in h)) && $1 ~ only')
[ -n "$rows" ] || { echo "quality_corpus: no $split scenes in $corpus/manifest.csv" >&2; exit 1; }
# Each scene's reference floor (`reference_relmse_floor`), from the corpus.jsonl beside the
# references' folders, where there is one.
echo "$rows" >"$work/rows"
python3 - "$corpus" "$work/rows" >"$work/floors" <<'PY'
import json, os, sys
seen = set()
for row in open(sys.argv[2]):
    reference = os.path.join(sys.argv[1], row.rstrip("\n").split(",")[6])
    jsonl = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(reference))), "corpus.jsonl")
    if jsonl in seen or not os.path.exists(jsonl):
        continue
    seen.add(jsonl)
    for line in open(jsonl):
        d = json.loads(line)
        print(d["scene"], d.get("reference_relmse_floor", 0.0))
PY
if [ -n "${MAX_FLOOR:-}" ]; then
    rows=$(awk -F, -v max="$MAX_FLOOR" 'NR == FNR { split($0, a, " "); f[a[1]] = a[2]; next } !($1 in f) || f[$1] <= max' \
        "$work/floors" - <<<"$rows")
    [ -n "$rows" ] || { echo "quality_corpus: every $split scene's reference is noisier than $MAX_FLOOR" >&2; exit 1; }
fi
m=0
for model in "$@"; do
    while IFS=, read -r scene _ _ _ spp file reference _; do
        $kpcn denoise "$corpus/$file" -o "$work/den.exr" --model "$model" -q --threads 2
        s=$($kpcn eval -r "$corpus/$reference" "$work/den.exr" --channels "${CHANNELS:-auto}" --format csv | tail -1 | cut -d, -f3,6,7)
        kept=$(python3 - "$work/den.exr" "${CHANNELS:-auto}" "$corpus/$reference" <<'PY'
import sys, numpy as np, OpenEXR, Imath
f = OpenEXR.InputFile(sys.argv[1]); layer = sys.argv[2]
if layer == "auto":
    out, noisy = "denoised.", ""
else:  # Blender's LAYER.Denoised sits beside its noisy LAYER.Combined
    out, noisy = layer + ".", layer.removesuffix("Denoised") + "Combined." if layer.endswith(".Denoised") else ""
mean = lambda f, p: np.mean([np.frombuffer(f.channel(p + c, Imath.PixelType(Imath.PixelType.FLOAT)), np.float32).astype(np.float64).mean() for c in "RGB"])
reference = mean(OpenEXR.InputFile(sys.argv[3]), "")
print(f"{mean(f, out) / max(mean(f, noisy), 1e-12):.6f} {mean(f, out) / max(reference, 1e-12):.6f}")
PY
)
        floor=$(awk -v scene="$scene" -v r="${s%%,*}" '$1 == scene { f = $2 } END { print (f > 0 ? sprintf("%.4f", r / f) : "-") }' "$work/floors")
        echo "$m $spp $scene ${s//,/ } ${kept% *} $floor ${kept#* }" >>"$work/scores"
    done <<<"$rows"
    m=$((m + 1))
done
# Per model and sample count: geometric means, and the same as multiples of model 0's.
awk -v names="$*" 'BEGIN { split(names, N, " ") }
    { k = $1 " " $2; for (i = 4; i <= 7; i++) g[k, i] += log($i); n[k]++; spps[$2] = 1; models = $1 > models ? $1 : models
      off[k] += ($7 > 1.05 || $7 < 0.95); if ($8 != "-") { fl[k] += log($8); nf[k]++ }; truth[k] += log($9) }
    END { for (m = 0; m <= models; m++) for (s in spps) { k = m " " s; b = 0 " " s;
            printf "%-44s %4s %6d | %.5f   %.5f   %.5f   | %.3f / %.3f / %.3f | %.3f %15d | %.3f %11s | %s\n", N[m + 1], s, n[k],
                exp(g[k, 4] / n[k]), exp(g[k, 5] / n[k]), exp(g[k, 6] / n[k]),
                exp((g[k, 4] - g[b, 4]) / n[k]), exp((g[k, 5] - g[b, 5]) / n[k]), exp((g[k, 6] - g[b, 6]) / n[k]),
                exp(g[k, 7] / n[k]), off[k], exp(truth[k] / n[k]), "", nf[k] ? sprintf("%.2f", exp(fl[k] / nf[k])) : "-" } }' "$work/scores" >"$work/table"
printf '%-44s %4s %6s | %-9s %-9s %-9s | %-37s | %-21s | %-17s | %s\n' model spp scenes relMSE "−0.1%" "−1%" "× first model (relMSE / −0.1% / −1%)" "light kept, off > 5 %" "÷ reference mean" "× floor"
# In the order the models were named, then by sample count.
for model in "$@"; do grep "^$model " "$work/table" | sort -k2,2n; done
# PER_SCENE=1: each frame's relMSE under the first model and every other's multiple of it,
# to see which scenes a geometric mean's change comes from.
if [ -n "${PER_SCENE:-}" ]; then
    echo
    awk '{ r[$3, $2, $1] = $4; scene[$3, $2] = $3; spp[$3, $2] = $2; models = $1 > models ? $1 : models }
        END { for (k in scene) { line = sprintf("%-20s %4d %9.5f", scene[k], spp[k], r[k, 0])
                for (m = 1; m <= models; m++) line = line sprintf(" %7.3f", r[k, 0] > 0 ? r[k, m] / r[k, 0] : 0)
                print line } }' "$work/scores" | sort -k1,1 -k2,2n |
        { printf '%-20s %4s %9s %s\n' scene spp relMSE "× first model, each other model in order"; cat; }
fi
