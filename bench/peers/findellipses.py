"""Peer: OpenCV-contrib's cv2.ximgproc.findEllipses (Jia et al. 2017), run INSIDE its own venv.

stdin: JSON {"images": [{"path": PNG, "truth": [cx, cy, a, b]}], "repeat": R}
stdout: JSON [{"time_s": best of R, "n_candidates": N, "chosen": [cx, cy, a, b, angle_rad] or null}]
Chosen (documented rule, generous to the peer): among all returned ellipses, the one closest to
the truth: minimum |centre - true centre| + |a - a_true| + |b - b_true| (px).
Rows of findEllipses are float32 [x, y, a, b, score, angle_rad] (a, b semi-axes).
"""
import json
import sys
import time

import cv2
import numpy as np

req = json.load(sys.stdin)
out = []
for item in req["images"]:
    grey = cv2.imread(item["path"], cv2.IMREAD_GRAYSCALE)
    best_t, found = float("inf"), None
    for _ in range(int(req.get("repeat", 1))):
        t = time.perf_counter()
        found = cv2.ximgproc.findEllipses(grey)
        best_t = min(best_t, time.perf_counter() - t)
    rows = np.zeros((0, 6)) if found is None else np.asarray(found, float).reshape(-1, 6)
    cx, cy, a, b = item["truth"]
    chosen = None
    if len(rows):
        ab = np.sort(rows[:, 2:4], axis=1)[:, ::-1]
        cost = np.hypot(rows[:, 0] - cx, rows[:, 1] - cy) + np.abs(ab[:, 0] - a) + np.abs(ab[:, 1] - b)
        i = int(np.argmin(cost))
        chosen = [rows[i, 0], rows[i, 1], ab[i, 0], ab[i, 1], rows[i, 5]]
    out.append({"time_s": best_t, "n_candidates": int(len(rows)), "chosen": chosen})
json.dump(out, sys.stdout)
