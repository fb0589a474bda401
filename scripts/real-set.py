#!/usr/bin/env python3
"""Scores a detection CSV against ../shared/real/copr-dev/targets.csv.

Usage: scripts/real-set.py [-v] DETECTIONS.csv [TARGETS.csv]
Prints each missed sighting, then the count found within 3 px, the count of
false detections (no sighting within 3 px; each listed with -v) and the
median centre error of those found.
"""
import csv
import math
import sys

args = [a for a in sys.argv[1:] if a != "-v"]
det_path = args[0]
truth_path = args[1] if len(args) > 1 else "../shared/real/copr-dev/targets.csv"
truth = [(r["image"], float(r["px_x"]), float(r["px_y"])) for r in csv.DictReader(open(truth_path))]
rows = list(csv.DictReader(open(det_path)))
dets = [(r["image"], float(r["px_x"]), float(r["px_y"])) for r in rows]
found, errors = 0, []
for img, x, y in truth:
    d = [math.hypot(x - dx, y - dy) for (di, dx, dy) in dets if di == img]
    if d and min(d) <= 3.0:
        found += 1
        errors.append(min(d))
    else:
        print(f"missed {img} {x:.1f},{y:.1f} nearest {min(d) if d else float('inf'):.1f} px")
false = 0
for img, dx, dy in dets:
    if not any(ti == img and math.hypot(tx - dx, ty - dy) <= 3.0 for ti, tx, ty in truth):
        false += 1
        if "-v" in sys.argv: print(f"false {img} {dx:.1f},{dy:.1f}")
errors.sort()
med = errors[len(errors) // 2] if errors else float("nan")
print(f"found {found} of {len(truth)} within 3 px; {false} false; median error {med:.2f} px")
