#!/usr/bin/env python3
"""Which branch carries a model's error, and how much of it is light misplaced at a coarse scale.

    python3 benches/branch_errors.py DIR MODEL [BLOCK]

DIR is the team's dev set (each SCENE-ref.exr beside its SCENE-NNNNNspp.exr) or a corpus
folder with a manifest.csv (scripts/cycles-corpus.sh; every frame it lists). Denoises every
noisy frame with MODEL (`kpcn denoise --aovs`) and prints per frame, in relMSE (`kpcn eval`'s):

- the model's own;
- "diffuse exact": with the reference's diffuse layer in place of the denoised one (what is
  left is the specular branch's error), and "specular exact" the other way round;
- "diffuse light exact": with the denoised diffuse scaled, per BLOCK x BLOCK block (default
  8) and channel, to the reference's block mean (the gain held within 1/2 and 2, so that a
  reference firefly in a dark block does not light the block): the light is where it
  belongs at that scale, the finer structure is the model's. Near the model's own, the
  error is not the light kept but how it lies within a block.

OTHER=MODEL2 adds two columns that swap in another model's branch: MODEL2's diffuse output
with MODEL's specular ("diffuse from OTHER"), and MODEL's diffuse with MODEL2's specular
("specular from OTHER"), each as a multiple of MODEL's own: which branch makes one model
worse than the other.

ONLY=REGEX scores only the scenes whose name it matches (Python's re.search).
A reference without diffuse and specular layers (the committed crops,
tests/data/cycles-crops) leaves the three "exact" columns out ("-").

Then the geometric mean of each over the frames, per sample count. A diagnosis, not a way to
choose models: the team's dev set is never chosen on. Needs numpy, OpenEXR and a built
`target/release/kpcn`.
"""
import csv
import glob
import os
import re
import sys
import tempfile

import numpy as np
import OpenEXR

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from light_study import denoise, read, relmse, rgb  # noqa: E402  (one home for the formulas)


def frames(folder):
    """(scene, spp, noisy, reference) for every noisy frame in `folder`."""
    manifest = os.path.join(folder, "manifest.csv")
    if os.path.exists(manifest):
        with open(manifest) as f:
            for row in csv.DictReader(f):
                yield row["scene"], int(row["spp"]), os.path.join(folder, row["file"]), os.path.join(folder, row["reference"])
        return
    for ref in sorted(glob.glob(os.path.join(folder, "*-ref.exr"))):
        scene = os.path.basename(ref)[: -len("-ref.exr")]
        for noisy in sorted(glob.glob(os.path.join(folder, f"{scene}-*spp.exr"))):
            m = re.search(r"-0*(\d+)spp\.exr$", noisy)
            if m:
                yield scene, int(m.group(1)), noisy, ref


def block_gain(x, r, b):
    """`x` scaled, per b x b block and channel, to the reference's block mean (gain in [1/2, 2])."""
    h, w, c = x.shape
    hp, wp = -(-h // b) * b, -(-w // b) * b

    def means(a):
        p = np.zeros((hp, wp, c))
        n = np.zeros((hp, wp, 1))
        p[:h, :w], n[:h, :w] = a, 1
        s = p.reshape(hp // b, b, wp // b, b, c).sum((1, 3))
        return s / n.reshape(hp // b, b, wp // b, b, 1).sum((1, 3))

    mx = means(x)
    g = np.clip(means(r) / np.where(mx > 0, mx, 1.0), 0.5, 2.0)
    return x * np.repeat(np.repeat(g, b, 0), b, 1)[:h, :w]


def main():
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    folder, model = sys.argv[1], sys.argv[2]
    b = int(sys.argv[3]) if len(sys.argv) == 4 else 8
    other = os.environ.get("OTHER")
    columns = ["model", "diffuse exact", "specular exact", f"diffuse light exact ({b}x{b})"]
    if other:
        columns += ["diffuse from OTHER", "specular from OTHER"]
    print(f"{'scene':<12} {'spp':>4} | " + " | ".join(f"{c:>26}" for c in columns))
    logs = {}
    with tempfile.TemporaryDirectory() as work:
        out, out2 = os.path.join(work, "den.exr"), os.path.join(work, "other.exr")
        for scene, spp, noisy, ref in frames(folder):
            if not re.search(os.environ.get("ONLY", ""), scene):
                continue
            denoise(model, noisy, out)
            r = read(ref, rgb(""))
            xd, xs = read(out, rgb("denoised_diffuse")), read(out, rgb("denoised_specular"))
            scores = [relmse(xd + xs, r)]
            if "diffuse.R" in OpenEXR.InputFile(ref).header()["channels"]:
                rd, rs = read(ref, rgb("diffuse")), read(ref, rgb("specular"))
                scores += [relmse(rd + xs, r), relmse(xd + rs, r), relmse(block_gain(xd, rd, b) + xs, r)]
            else:  # a reference without diffuse and specular layers (the committed crops)
                scores += [np.nan] * 3
            if other:
                denoise(other, noisy, out2)
                other_d, other_s = read(out2, rgb("denoised_diffuse")), read(out2, rgb("denoised_specular"))
                scores += [relmse(other_d + xs, r), relmse(xd + other_s, r)]
            own = scores[0]
            cells = [f"{scores[0]:.5f}"] + [
                "-" if np.isnan(s) else f"{s:.5f} ({s / own:.2f}x)" if own > 0 else f"{s:.5f}" for s in scores[1:]
            ]
            print(f"{scene:<12} {spp:>4} | " + " | ".join(f"{c:>26}" for c in cells), flush=True)
            logs.setdefault(spp, []).append(np.log(np.maximum(scores, 1e-12)))
    for spp, rows in sorted(logs.items()):
        g = np.exp(np.mean(rows, 0))  # nan for the columns a reference without layers leaves out
        parts = ", ".join(f"{c} {v:.5f} ({v / g[0]:.2f}x)" for c, v in zip(columns[1:], g[1:]) if not np.isnan(v))
        print(f"{spp} spp, geometric means over {len(rows)} frames: model {g[0]:.5f}, {parts}")


if __name__ == "__main__":
    main()
