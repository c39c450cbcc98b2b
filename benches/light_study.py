#!/usr/bin/env python3
"""Where a model's light goes on our own held-out Cycles frames, and what putting it back costs.

    python3 benches/light_study.py SNAPSHOT MODEL     # SNAPSHOT: as benches/quality_corpus.sh

Denoises every held-out Cycles frame of SNAPSHOT/manifest.csv (every 5th scene by name, as
`kpcn train --holdout 5`) with MODEL (`kpcn denoise --aovs`) and prints:

1. per frame, its mean and the light each layer keeps (denoised mean over noisy mean,
   diffuse / specular / both);
2. relMSE and light kept (geometric means per sample count) after corrections applied to
   the output: a gain per block of B x B pixels (the noisy block mean over the denoised
   one, shrunk by k x the block mean's variance over the squared difference; gains
   bilinear between block centres), or per frame; on the whole colour or the specular
   layer alone;
3. the same for an exposure floor: a frame whose mean is under T is multiplied by T / mean
   (radiance by k, variances by k^2, as benches/exposure_cycles.sh scales) before MODEL and
   divided after.

relMSE is `kpcn eval`'s: (x - ref)^2 / (ref^2 + 0.01). Needs numpy, OpenEXR and oiiotool.
"""
import csv
import os
import subprocess
import sys
import tempfile

import Imath
import numpy as np
import OpenEXR

FLOAT = Imath.PixelType(Imath.PixelType.FLOAT)
ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
KPCN = os.path.join(ROOT, "target", "release", "kpcn")


def read(path, names):
    f = OpenEXR.InputFile(path)
    dw = f.header()["dataWindow"]
    w, h = dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1
    return np.stack([np.frombuffer(f.channel(n, FLOAT), np.float32).reshape(h, w).astype(np.float64) for n in names], -1)


def rgb(layer):
    return [f"{layer}.{c}" if layer else c for c in "RGB"]


def relmse(x, r):
    return float(np.mean((x - r) ** 2 / (r**2 + 0.01)))


def block_sums(a, b):
    h, w = a.shape
    p = np.zeros((-(-h // b) * b, -(-w // b) * b))
    p[:h, :w] = a
    return p.reshape(p.shape[0] // b, b, p.shape[1] // b, b).sum((1, 3))


def bilinear(g, b, h, w):
    """Block values `g` (one per b x b block) interpolated between block centres."""
    gh, gw = g.shape

    def axis(n, m):
        t = (np.arange(n) + 0.5) / b - 0.5
        i0 = np.clip(np.floor(t).astype(int), 0, m - 1)
        f = np.where((t < 0) | (t > m - 1), 0.0, t - np.floor(t))
        return i0, np.clip(i0 + 1, 0, m - 1), f

    y0, y1, fy = axis(h, gh)
    x0, x1, fx = axis(w, gw)
    fy, fx = fy[:, None], fx[None, :]
    top = g[y0][:, x0] * (1 - fx) + g[y0][:, x1] * fx
    bottom = g[y1][:, x0] * (1 - fx) + g[y1][:, x1] * fx
    return top * (1 - fy) + bottom * fy


def gain(noisy, variance, denoised, b, k):
    """`denoised` times the shrunk ratio of block means (b=None: one block, the frame)."""
    ln, ld = noisy.mean(-1), denoised.mean(-1)
    b = b or max(ln.shape)
    sn, sd, sv = block_sums(ln, b), block_sums(ld, b), block_sums(variance, b)
    delta = sn - sd
    trust = np.clip(1 - k * sv / np.maximum(delta**2, 1e-30), 0, 1)
    g = np.where(sd > 1e-9, np.clip((sd + trust * delta) / np.maximum(sd, 1e-12), 0.25, 4.0), 1.0)
    return denoised * bilinear(g, b, *ln.shape)[..., None]


def scale_factors(path, k):
    """oiiotool --mulc factors: k on radiance, k^2 on its variances, 1 elsewhere."""
    info = subprocess.run(["oiiotool", "--info", "-v", path], capture_output=True, text=True, check=True).stdout
    names = next(l for l in info.splitlines() if "channel list:" in l).split("channel list:")[1]
    out = []
    for n in (c.strip() for c in names.split(",")):
        layer = n.split(".")[0]
        if n in ("R", "G", "B") or (layer in ("colorA", "diffuse", "diffuseA", "specular", "specularA") and "." in n):
            out.append(k)
        elif layer in ("colorVariance", "diffuseVariance", "specularVariance"):
            out.append(k * k)
        else:
            out.append(1.0)
    return ",".join(f"{v:.9g}" for v in out)


def denoise(model, noisy, out):
    subprocess.run([KPCN, "denoise", noisy, "-o", out, "--model", model, "-q", "--threads", "2", "--aovs", "--separate"], check=True)
    return read(out, rgb("denoised"))


def geo(v):
    return float(np.exp(np.mean(np.log(np.maximum(v, 1e-30)))))


def table(name, res):
    line = f"{name:<28}"
    for spp in sorted(res, key=int):
        a = np.array(res[spp])
        off = int(np.sum(np.abs(a[:, 1] - 1) > 0.05))
        line += f" | {spp:>2} spp {geo(a[:, 0]):.5f} kept {geo(a[:, 1]):.3f} off {off:2d}"
    print(line)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    snapshot, model = sys.argv[1], sys.argv[2]
    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)
    rows = list(csv.DictReader(open(os.path.join(snapshot, "manifest.csv"))))
    scenes = sorted({r["scene"] for r in rows})
    held = set(scenes[4::5])
    rows = [r for r in rows if r["scene"] in held and r["scene"].startswith("cyc-")]
    corrections = {
        "none": None,
        "frame": ("all", None, 0),
        "64x64 blocks, k 1": ("all", 64, 1),
        "16x16 blocks, k 4": ("all", 16, 4),
        "specular layer, frame": ("specular", None, 0),
    }
    floors = [0.05, 0.15]
    results = {name: {} for name in list(corrections) + [f"exposure floor {t}" for t in floors]}
    print("per frame: scene family spp | mean | light kept diffuse / specular / both")
    with tempfile.TemporaryDirectory() as work:
        den = os.path.join(work, "den.exr")
        for r in rows:
            file, reference = os.path.join(snapshot, r["file"]), os.path.join(snapshot, r["reference"])
            noisy, ref = read(file, rgb("")), read(reference, rgb(""))
            variance = read(file, ["colorVariance.Z"])[..., 0]
            spec_noisy, spec_var = read(file, rgb("specular")), read(file, ["specularVariance.Z"])[..., 0]
            out = denoise(model, file, den)
            layers = {b: read(den, rgb("denoised_" + b)) for b in ("diffuse", "specular")}
            kept = [layers["diffuse"].mean() / max(read(file, rgb("diffuse")).mean(), 1e-12),
                    layers["specular"].mean() / max(spec_noisy.mean(), 1e-12), out.mean() / max(noisy.mean(), 1e-12)]
            print(f"{r['scene']:<11} {r['family']:<16} {r['spp']:>2} | {noisy.mean():.4f} | " + " / ".join(f"{v:.3f}" for v in kept))
            for name, c in corrections.items():
                if c is None:
                    x = out
                elif c[0] == "all":
                    x = gain(noisy, variance, out, c[1], c[2])
                else:
                    x = layers["diffuse"] + gain(spec_noisy, spec_var, layers["specular"], c[1], c[2])
                results[name].setdefault(r["spp"], []).append((relmse(x, ref), x.mean() / noisy.mean()))
            for t in floors:
                k = max(1.0, t / max(noisy.mean(), 1e-12))
                scaled = os.path.join(work, "in.exr")
                subprocess.run(["oiiotool", file, "--mulc", scale_factors(file, k), "-o", scaled], check=True)
                x = denoise(model, scaled, den) / k
                results[f"exposure floor {t}"].setdefault(r["spp"], []).append((relmse(x, ref), x.mean() / noisy.mean()))
    print("\ncorrection                   | relMSE (geometric mean), light kept, frames more than 5 % off")
    for name, res in results.items():
        table(name, res)


if __name__ == "__main__":
    main()
