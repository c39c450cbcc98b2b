#!/usr/bin/env python3
"""How noisy each scene's reference is, in relMSE and scale-free.

    python3 benches/reference_noise.py SNAPSHOT [LIMIT]   # SNAPSHOT: as benches/quality_corpus.sh

For every Cycles scene of SNAPSHOT/manifest.csv, from its highest-spp noisy frame (n spp)
and its reference (m spp, `kpcn:spp`): the reference's expected error is the frame's,
times n / (n + m) (scripts/corpus/assemble.py's `reference_share`, as it writes
`reference_relmse_floor`). Prints,
noisiest first, the reference's mean, that floor in relMSE ((x - ref)^2 / (ref^2 + 0.01),
which scores dim pixels by absolute error) and scale-free (the expected MSE over the
squared mean: above 1, the reference's per-pixel noise outweighs the light it measures),
then how many scenes pass 1, 0.3 and 0.1. Needs numpy and OpenEXR.
"""
import csv
import math
import os
import sys

import numpy as np
import OpenEXR

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(HERE, "..", "scripts", "corpus")]
from assemble import reference_share  # noqa: E402  (one home for the floor)
from light_study import read as read_channels, relmse as relmse_of, rgb as layer  # noqa: E402


def read(path):
    """The root R,G,B of `path` and its `kpcn:spp` (None without one)."""
    spp = OpenEXR.InputFile(path).header().get("kpcn:spp")
    spp = int(spp.decode() if isinstance(spp, bytes) else spp) if spp is not None else None
    return read_channels(path, layer("")), spp


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    snapshot = sys.argv[1]
    limit = int(sys.argv[2]) if len(sys.argv) == 3 else 30
    rows = [r for r in csv.DictReader(open(os.path.join(snapshot, "manifest.csv"))) if r["scene"].startswith("cyc-")]
    top = {}
    for r in rows:
        if r["scene"] not in top or int(r["spp"]) > int(top[r["scene"]]["spp"]):
            top[r["scene"]] = r
    out = []
    for scene, r in sorted(top.items()):
        x, _ = read(os.path.join(snapshot, r["file"]))
        ref, m = read(os.path.join(snapshot, r["reference"]))
        n = int(r["spp"])
        if m is None:
            sys.exit(f"{r['reference']}: no kpcn:spp: the reference's sample count is needed")
        share = reference_share(n, m)
        relmse = relmse_of(x, ref) * share
        mean = float(ref.mean())
        scale_free = float(np.mean((x - ref) ** 2)) * share / mean**2 if mean > 0 else math.inf
        out.append((scale_free, scene, mean, relmse))
    out.sort(reverse=True)
    print(f"{'scene':<12} {'mean':>8} {'floor relMSE':>12} {'floor scale-free':>16}")
    for scale_free, scene, mean, relmse in out[:limit]:
        print(f"{scene:<12} {mean:8.4f} {relmse:12.5f} {scale_free:16.3f}")
    v = np.array([o[0] for o in out])
    print(f"{len(v)} scenes; scale-free floor above 1: {int((v > 1).sum())}, above 0.3: {int((v > 0.3).sum())}, "
          f"above 0.1: {int((v > 0.1).sum())}")


if __name__ == "__main__":
    main()
