#!/usr/bin/env python3
"""Our convolutions against PyTorch's, shape by shape, in one run.

Every convolution shape of a shipped multi-scale model is timed twice in the same run:
by `kpcn speed --layers` (forward at a frame's scales, as `kpcn denoise` runs it, and
forward + backward on a training batch) and by `torch.nn.functional.conv2d` on the same
shapes and thread count. PyTorch is a measuring stick here, never a dependency:

    pip install torch numpy          # the default wheel; its CPU path uses oneDNN
    cargo build --release
    benches/conv_vs_torch.py [--model default] [--threads 2] [--repeat 5]

PyTorch runs in channels-last layout (its fastest CPU convolutions; NCHW was 1.5-2x
slower here). The same run also reports numpy's SGEMM (OpenBLAS) as the machine's
practical peak. Shared machines are noisy: only the ratios of one run mean anything.
"""

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def fastest(fn, repeat):
    fn()
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def torch_seconds(torch, layer, repeat):
    f = torch.nn.functional
    cin, cout, k, b = layer["cin"], layer["cout"], layer["k"], layer["batch"]
    w, h = layer["width"], layer["height"]
    cl = torch.channels_last
    x = torch.rand(b, cin, h, w).to(memory_format=cl)
    wt = (torch.rand(cout, cin, k, k) - 0.5).to(memory_format=cl)
    bias = torch.rand(cout)
    if layer["pass"] == "fwd":
        def run():
            with torch.no_grad():
                torch.relu(f.conv2d(x, wt, bias, padding=k // 2))
        return fastest(run, repeat)
    x.requires_grad_(True)
    wt.requires_grad_(True)
    bias.requires_grad_(True)
    g = torch.rand(b, cout, h, w).to(memory_format=cl)

    def step():
        x.grad = wt.grad = bias.grad = None
        y = torch.relu(f.conv2d(x, wt, bias, padding=k // 2))
        y.backward(g)  # the output gradient g seeds the backward pass, as in kpcn's timing
    return fastest(step, repeat)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="default")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--resolution", default="1280x720")
    ap.add_argument("--kpcn", default=os.path.join(ROOT, "target", "release", "kpcn"))
    args = ap.parse_args()
    try:
        import numpy as np
        import torch
    except ImportError as e:
        sys.exit(f"conv_vs_torch: {e}; pip install torch numpy")
    torch.set_num_threads(args.threads)
    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads))

    out = subprocess.run(
        [args.kpcn, "speed", "--layers", "--format", "json", "--models", args.model,
         "--threads", str(args.threads), "--repeat", str(args.repeat), "--resolution", args.resolution],
        check=True, capture_output=True, text=True).stdout
    ours = json.loads(out)["layers"]

    a = np.random.rand(2048, 2048).astype(np.float32)
    sgemm = 2 * 2048 ** 3 / fastest(lambda: a @ a, args.repeat) / 1e9

    print(f"model {args.model}, {args.threads} threads, fastest of {args.repeat}; "
          f"torch {torch.__version__} (channels-last); numpy SGEMM {sgemm:.1f} GFLOP/s")
    print()
    print("| pass | cin→cout | k | batch×W×H | kpcn GFLOP/s | torch GFLOP/s | kpcn ÷ torch |")
    print("|---|---|---:|---|---:|---:|---:|")
    worst = {}
    for layer in ours:
        secs = torch_seconds(torch, layer, args.repeat)
        flop = layer["gflops"] * layer["seconds"]
        theirs = flop / secs
        ratio = layer["gflops"] / theirs
        p = layer["pass"]
        worst[p] = min(worst.get(p, float("inf")), ratio)
        size = f'{layer["batch"]}×{layer["width"]}×{layer["height"]}'
        print(f'| {p} | {layer["cin"]}→{layer["cout"]} | {layer["k"]} | {size} | '
              f'{layer["gflops"]:.1f} | {theirs:.1f} | {ratio:.2f} |')
    print()
    for p, r in worst.items():
        print(f"lowest ratio, {p}: {r:.2f}")


if __name__ == "__main__":
    main()
