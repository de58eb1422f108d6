"""Speed of the camera model's exact undistortion (and distortion) on many points.

    .venv/bin/python bench/undistort.py [--points 100000] [--repeat 15] [--terms 5 8 12]

``calibration.camera_model.undistort_normalized`` runs on every rim edge point of every cycle.
The points are pixels drawn uniformly over a 1280x1024 image of the station's lens (f = 1800 px,
k1 = -0.21 ...); 8 and 12 terms add OpenCV's rational (k4 k5 k6) and thin-prism (s1..s4) terms
of a similar lens. Times are the best of --repeat (this is a shared 2-core machine): compare
ratios, not absolute figures. The calibration package is imported from PYTHONPATH when it is
set (to time another checkout against this one), else from this repository; the first line
says which.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path = [p for p in sys.path if Path(p or ".").resolve() != HERE]  # bench/calibration.py is not the package
sys.path.append(str(HERE.parent))  # after PYTHONPATH: see the docstring

import calibration  # noqa: E402
from calibration.camera_model import distort_normalized, undistort_normalized  # noqa: E402

K = np.array([[1812.0, 0, 652.3], [0, 1809.5, 498.7], [0, 0, 1]])
DIST = {5: [-0.21, 0.09, 3e-4, -2e-4, -0.01],
        8: [-0.21, 0.09, 3e-4, -2e-4, -0.01, 0.02, -0.01, 0.005],
        12: [-0.21, 0.09, 3e-4, -2e-4, -0.01, 0.02, -0.01, 0.005, 1e-4, -2e-4, 3e-4, 1e-4]}


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--terms", type=int, nargs="+", default=[5, 8, 12])
    args = ap.parse_args(argv)
    print(f"calibration from {Path(calibration.__file__).parent}")
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [1279, 1023], (args.points, 2))
    xy_d = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]], axis=1)
    print(f"| terms | undistort_normalized, {args.points} points (ms) | distort_normalized (ms) |")
    print("|---|---|---|")
    for n in args.terms:
        dist = np.array(DIST[n], float)
        try:
            xy = undistort_normalized(xy_d, dist)
        except (ValueError, TypeError) as e:  # a checkout whose model has fewer terms
            print(f"| {n} | not supported ({e}) | |")
            continue
        assert np.abs(distort_normalized(xy, dist) - xy_d).max() < 1e-9
        t_u = best_of(lambda: undistort_normalized(xy_d, dist), args.repeat)
        t_d = best_of(lambda: distort_normalized(xy, dist), args.repeat)
        print(f"| {n} | {t_u * 1e3:.1f} | {t_d * 1e3:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
