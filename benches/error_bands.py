"""Where in frequency kpcn's error sits against OIDN's (diagnosis only): for each corpus
scene, denoises its noisy frame with kpcn (MODEL) and OIDN 'high' (benches/oidn_exr.py, a
measuring peer), takes the relMSE-weighted error field (x − ref) / √(mean(ref)² + 0.01),
splits it into bands (a Gaussian of σ 4 px; σ 1 to 4; what is finer than σ 1) and prints,
per scene and as geometric means, kpcn's mean square over OIDN's, whole and per band.

    python3 benches/error_bands.py CORPUS MODEL SPP SCENE...   # e.g. train-cycles/corpus balanced 4 cyc-00050
"""
import os
import subprocess
import sys
import tempfile

import numpy as np
import OpenEXR

corpus, model, spp, scenes = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4:]
here = os.path.dirname(os.path.abspath(__file__))
kpcn = os.path.join(here, "..", "target", "release", "kpcn")


def rgb(path, prefix=""):
    ch = OpenEXR.File(path, separate_channels=True).channels()
    return np.stack([np.asarray(ch[prefix + c].pixels, np.float64) for c in "RGB"], -1)


def blur(x, sigma):
    r = int(3 * sigma)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    p = np.pad(x, ((r, r), (r, r), (0, 0)), mode="reflect")
    p = np.apply_along_axis(lambda v: np.convolve(v, k, "valid"), 0, p)
    return np.apply_along_axis(lambda v: np.convolve(v, k, "valid"), 1, p)


def bands(e):
    lo, fine = blur(e, 4.0), blur(e, 1.0)
    return [float((b**2).mean()) for b in (e, lo, fine - lo, e - fine)]


ratios = []
with tempfile.TemporaryDirectory() as tmp:
    for s in scenes:
        noisy = os.path.join(corpus, s, f"{s}-{spp:05d}spp.exr")
        ref = rgb(os.path.join(corpus, s, f"{s}-ref.exr"))
        k, o = os.path.join(tmp, "k.exr"), os.path.join(tmp, "o.exr")
        subprocess.run([kpcn, "denoise", noisy, "-o", k, "--model", model, "-q"], check=True)
        subprocess.run([sys.executable, os.path.join(here, "oidn_exr.py"), noisy, o], check=True)
        w = 1 / np.sqrt(ref.mean(-1, keepdims=True) ** 2 + 0.01)
        ours, theirs = bands((rgb(k, "denoised.") - ref) * w), bands((rgb(o) - ref) * w)
        r = [a / b for a, b in zip(ours, theirs)]
        ratios.append(r)
        print(f"{s} {spp} spp: kpcn ÷ OIDN whole {r[0]:.2f}, σ > 4 px {r[1]:.2f}, 1–4 px {r[2]:.2f}, < 1 px {r[3]:.2f}")
g = np.exp(np.log(np.array(ratios)).mean(0))
print(f"geometric mean over {len(scenes)} scenes: whole {g[0]:.2f}, σ > 4 px {g[1]:.2f}, 1–4 px {g[2]:.2f}, < 1 px {g[3]:.2f}")
