"""OIDN 'high' (hdr, with albedo and normal) on a kpcn-layout EXR (R,G,B, albedo.*, normal.*):
writes OUT.exr with R,G,B for `kpcn eval`. A measuring peer only (pip install pyoidn OpenEXR
numpy), never a kpcn dependency.

    python3 benches/oidn_exr.py IN.exr OUT.exr
"""
import sys

import numpy as np
import OpenEXR
import pyoidn

src, dst = sys.argv[1:3]
ch = OpenEXR.File(src, separate_channels=True).channels()


def rgb(prefix):
    return np.ascontiguousarray(np.stack([np.asarray(ch[prefix + c].pixels, np.float32) for c in "RGB"], -1))


out = pyoidn.denoise(rgb(""), rgb("albedo."), rgb("normal."), hdr=True, quality="high")
planes = {c: np.ascontiguousarray(out[..., i], np.float32) for i, c in enumerate("RGB")}
OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, planes).write(dst)
