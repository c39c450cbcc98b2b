"""Turns one scene's 1-sample Cycles renders and its reference render into kpcn's layered-EXR
layout (the dev set's: ../shared/data/cycles-dev/README.md, "Channel layout"): per sample
count n, the mean of the first n renders, the half buffer "A" (mean of the first n/2) and the
variance of the mean (unbiased sample variance / n, averaged over R, G, B for colours).

    python3 scripts/corpus/assemble.py NOISY_DIR REF.exr OUT_DIR SCENE SPP[,SPP...]

Per-sample quantities, from the passes Blender 3.4 writes:
    color    = Combined
    diffuse  = (DiffDir + DiffInd) × DiffCol
    specular = color − diffuse   (glossy, transmission, emission, environment)
    albedo   = DiffCol
    normal   = Normal (world space, 0 at misses)
    depth    = Mist × 10000 (distance to the first hit; Mist is exactly 1 at a miss → 0)

Prints one JSON line: relMSE of the largest n against the reference, the reference's own
expected relMSE (relMSE(n, ref) × n / (N_ref + n), which is the floor every score on this
scene carries) and the calibration MSE(color) / mean(colorVariance) per n (1 is ideal).
A measuring and corpus tool (pip install numpy OpenEXR), never a kpcn dependency.
"""
import json
import os
import sys

import numpy as np
import OpenEXR

MIST_SCALE = 10000.0


def read(path):
    with OpenEXR.File(path, separate_channels=True) as f:
        ch = f.channels()
        return {k: np.asarray(v.pixels, np.float32) for k, v in ch.items()}


def rgb(ch, name, comps="RGB"):
    return np.stack([ch[f"ViewLayer.{name}.{c}"] for c in comps], -1).astype(np.float64)


def quantities(ch):
    """The per-sample quantities of one render, float64 (H, W, C)."""
    color = rgb(ch, "Combined")
    diff_col = rgb(ch, "DiffCol")
    diffuse = (rgb(ch, "DiffDir") + rgb(ch, "DiffInd")) * diff_col
    mist = ch["ViewLayer.Mist.Z"].astype(np.float64)
    depth = np.where(mist < 1.0, mist * MIST_SCALE, 0.0)[..., None]
    return {
        "color": color,
        "diffuse": diffuse,
        "specular": color - diffuse,
        "albedo": diff_col,
        "normal": rgb(ch, "Normal", "XYZ"),
        "depth": depth,
    }


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref**2 + 0.01)))


def reference_share(n, n_ref):
    """The share of an n-spp frame's expected error (against an n_ref-spp reference) that the
    reference's own noise carries: both are means of independent samples, so the expected
    squared difference is the sum of their variances, n_ref : n apart."""
    return n / (n_ref + n)


def channels_of(name, value):
    """kpcn's channel names for a quantity: colour is bare R,G,B, depth a lone .Z."""
    if value.shape[-1] == 1:
        return {f"{name}.Z": value[..., 0]}
    if name == "color":
        return {c: value[..., i] for i, c in enumerate("RGB")}
    return {f"{name}.{c}": value[..., i] for i, c in enumerate("RGB")}


def write(path, planes, attributes):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **attributes}
    planes = {k: np.ascontiguousarray(v, np.float32) for k, v in planes.items()}
    tmp = path + ".tmp.exr"
    OpenEXR.File(header, planes).write(tmp)
    os.replace(tmp, path)


def main():
    noisy_dir, ref_path, out_dir, scene, spps = sys.argv[1:6]
    spps = sorted(int(s) for s in spps.split(","))
    n_max = spps[-1]
    os.makedirs(out_dir, exist_ok=True)
    # Running sums per quantity: of the first n/2 and first n samples, and of squares.
    sums, squares, half_sums, frames = {}, {}, {}, {}
    depth_all = None
    for i in range(n_max):
        q = quantities(read(os.path.join(noisy_dir, f"s{i:04d}.exr")))
        for k, v in q.items():
            sums[k] = sums.get(k, 0) + v
            squares[k] = squares.get(k, 0) + v * v
        depth_all = q["depth"] if depth_all is None else depth_all + q["depth"]
        n = i + 1
        for s in spps:
            if n == s // 2:
                half_sums[s] = {k: v.copy() for k, v in sums.items()}
        if n in spps:
            planes = {}
            for k in q:
                mean = sums[k] / n
                var = np.maximum(squares[k] / n - mean * mean, 0.0) * n / (n - 1) / n
                planes.update(channels_of(k, mean))
                planes.update(channels_of(k + "A", half_sums[n][k] / (n // 2)))
                planes[f"{k}Variance.Z"] = var.mean(-1)
            frames[n] = planes
            write(os.path.join(out_dir, f"{scene}-{n:05d}spp.exr"), planes, {
                "kpcn:source": f"Blender Cycles 3.4.1, 1-spp renders, seeds 0..{n - 1}",
                "kpcn:spp": n,
                "kpcn:scene": scene,
                "kpcn:depth": "distance camera->first hit from the Mist pass (0 at misses)",
            })
    ref_log = json.load(open(ref_path + ".json"))
    n_ref = ref_log["samples"]
    r = quantities(read(ref_path))
    r["depth"] = depth_all / n_max
    ref_planes = {}
    for k, v in r.items():
        ref_planes.update(channels_of(k, v))
    write(os.path.join(out_dir, f"{scene}-ref.exr"), ref_planes, {
        "kpcn:source": f"Blender Cycles 3.4.1, reference render, {n_ref} spp, seed {ref_log['seed']}",
        "kpcn:spp": n_ref,
        "kpcn:scene": scene,
        "kpcn:depth": f"mean of the {n_max} one-sample depths of the noisy renders; 0 at misses",
    })
    ref_rgb = r["color"]
    report = {"scene": scene, "reference_spp": n_ref, "reference_seconds": round(ref_log["seconds"], 2)}
    for n, planes in frames.items():
        x = np.stack([planes[c] for c in "RGB"], -1).astype(np.float64)
        mse = np.mean((x - ref_rgb) ** 2)
        report[f"relmse_{n}"] = relmse(x, ref_rgb)
        report[f"calibration_{n}"] = float(mse / max(np.mean(planes["colorVariance.Z"]), 1e-30))
    report["reference_relmse_floor"] = report[f"relmse_{n_max}"] * reference_share(n_max, n_ref)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
