#!/usr/bin/env python3
"""The AprilTag 3 reference detector (pupil-apriltags, the same C library as
ours) over a folder of frames, for the throughput bench's side-by-side run.

    apriltag-peer.py DIR OUT.csv [--family tag36h11] [--decimate 2] [--sigma 0] [--threads 2]

Frames are read as the service reads them: JPEG/PNG through Pillow, TIFF
through tifffile with 16-bit bands stretched to 8 bits between their 0.2 and
99.8 percentiles; grey is ITU-R 601 luma of the first three bands. Centres
are written in OpenCV's convention (centre of the top-left pixel at 0,0):
libapriltag's own puts it at 0.5,0.5, so 0.5 is subtracted.
"""
import argparse
import csv
import os
import sys

import numpy as np
from PIL import Image
import tifffile
from pupil_apriltags import Detector


def grey(path):
    if path.lower().endswith((".tif", ".tiff")):
        a = tifffile.imread(path)
        if a.ndim == 3 and a.shape[0] < a.shape[-1] and a.shape[0] <= 8:
            a = np.moveaxis(a, 0, -1)
        a = a.astype(np.float32)
        if a.ndim == 3:
            a = a[..., :3]
        if a.max() > 255:
            step = max(1, int((a.shape[0] * a.shape[1] / 1e6) ** 0.5))
            sample = a[::step, ::step]
            lo, hi = np.percentile(sample, [0.2, 99.8])
            a = np.clip((a - lo) * (255.0 / max(hi - lo, 1e-6)), 0, 255)
        if a.ndim == 3:
            a = a @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
        return np.ascontiguousarray(np.rint(a).astype(np.uint8))
    return np.asarray(Image.open(path).convert("L"))


def main():
    p = argparse.ArgumentParser()
    p.add_argument("dir")
    p.add_argument("out")
    p.add_argument("--family", default="tag36h11")
    p.add_argument("--decimate", type=float, default=2.0)
    p.add_argument("--sigma", type=float, default=0.0)
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args()
    det = Detector(
        families=a.family,
        nthreads=a.threads,
        quad_decimate=a.decimate,
        quad_sigma=a.sigma,
        refine_edges=1,
        decode_sharpening=0.25,
    )
    names = sorted(
        n for n in os.listdir(a.dir)
        if n.lower().endswith((".jpg", ".jpeg", ".png", ".tif", ".tiff"))
    )
    with open(a.out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["image", "marker_type", "marker_id", "px_x", "px_y", "hamming", "decision_margin"])
        for n in names:
            for d in det.detect(grey(os.path.join(a.dir, n))):
                w.writerow([n, "apriltag", d.tag_id, f"{d.center[0] - 0.5:.4f}",
                            f"{d.center[1] - 0.5:.4f}", d.hamming, f"{d.decision_margin:.1f}"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
