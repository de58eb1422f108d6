"""Peer: scikit-image's hough_ellipse, run INSIDE its own venv, one image per call.

It takes minutes on a full wheel crop, so it gets help no station would have: a crop around
the TRUE rim (1.25 x its bounding box) downscaled so the crop's long side is ``side`` px, and
min/max sizes bracketing the true semi-major axis (0.8..1.2). Edges: skimage Canny (sigma 2).
argv: PNG cx cy a b side
stdout: JSON {"time_s", "n_candidates", "chosen": [cx, cy, a, b, angle_rad] in full-image px or null}
Chosen: the accumulator entry closest to the truth (centre + |a - a_true| + |b - b_true|).
"""
import json
import sys
import time

import numpy as np
from skimage import feature, io, transform

path, cx, cy, a, b, side = sys.argv[1], *map(float, sys.argv[2:7])
img = io.imread(path, as_gray=True).astype(float)
img = img / img.max() if img.max() > 1 else img
r = 1.25 * a
x0, y0 = int(max(cx - r, 0)), int(max(cy - r, 0))
crop = img[y0:int(cy + r), x0:int(cx + r)]
s = side / max(crop.shape)
t = time.perf_counter()
small = transform.rescale(crop, s, anti_aliasing=True)
edges = feature.canny(small, sigma=2.0)
res = transform.hough_ellipse(edges, accuracy=4, threshold=20, min_size=int(0.8 * a * s),
                              max_size=int(1.2 * a * s))
elapsed = time.perf_counter() - t
chosen = None
if len(res):
    yc, xc = res["yc"] / s + y0, res["xc"] / s + x0
    A = np.maximum(res["a"], res["b"]) / s
    B = np.minimum(res["a"], res["b"]) / s
    cost = np.hypot(xc - cx, yc - cy) + np.abs(A - a) + np.abs(B - b)
    i = int(np.argmin(cost))
    chosen = [float(xc[i]), float(yc[i]), float(A[i]), float(B[i]), float(res["orientation"][i])]
json.dump({"time_s": elapsed, "n_candidates": int(len(res)), "chosen": chosen}, sys.stdout)
