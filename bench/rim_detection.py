"""Rim detection accuracy and time: simulated station images and synthetic wheels.

    .venv/bin/python bench/rim_detection.py --seeds 0 1 2 --synthetic 20

For every image it compares, against the truth,
* the paper's pipeline (global histogram equalisation, Canny, Hough, ellipse of the edge
  pixels: the Hough candidate, no sub-pixel stage) and
* ours (detect_rim: CLAHE, polarity Hough, step-and-kink sub-pixel edges, consensus +
  robust geometric fit), with the true camera model (distortion corrected on the points).
Truth on simulated images: the true rim circle projected by the true camera (ideal pinhole
pixels, an exact ellipse). Times are CPU seconds of this process (the machine is shared).
Rendered images are cached in $RIM_BENCH_CACHE (default /tmp/rim_bench_cache).
"""

from __future__ import annotations

import argparse
import os
import sys

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one core, as specified
    os.environ.setdefault(_var, "1")
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from station.errors import StationError  # noqa: E402
from station.rim import detect_rim  # noqa: E402
from station.rim import hough  # noqa: E402
from station.rim.choice import choose  # noqa: E402
from station.rim.detector import _Scene  # noqa: E402
from station.rim.ellipse import Ellipse  # noqa: E402
from station.rim.ellipse_fit import fit_direct  # noqa: E402
from station.rim.preprocess import PixelMap, to_grey  # noqa: E402
from tests.synthetic_wheel import random_spec, render_wheel  # noqa: E402

WHEEL_OF = {"cam1": "FR", "cam2": "FR", "cam3": "FL", "cam4": "FL",
            "cam5": "RL", "cam6": "RL", "cam7": "RR", "cam8": "RR"}


def true_ellipse(world, scene, cam_id: str) -> Ellipse:
    """The true rim circle in ideal pinhole pixels of the true camera."""
    v, cam = scene.vehicle, world.cameras[cam_id]
    c, Rw = v.wheel_frame_station(WHEEL_OF[cam_id])
    ang = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    circ = c + v.wheel.rim_radius_m * (np.cos(ang)[:, None] * Rw[:, 0] + np.sin(ang)[:, None] * Rw[:, 1])
    xc = cam.station_to_cam(circ)
    xy = xc[:, :2] / xc[:, 2:]
    K = cam.K
    return fit_direct(xy * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]])


def paper_pipeline(grey: np.ndarray, camera) -> Ellipse:
    """Global equalisation, Canny, Hough (our vote), the ellipse of the Canny pixels."""
    sc = _Scene(grey, PixelMap(camera), "global")
    hd, wd = sc.coarse.shape
    cands = hough.find_candidates(sc.edges, max(12.0, 0.05 * min(hd, wd)), 0.7 * max(hd, wd))
    best, _ = choose(sc, cands, "paper")
    return best.ellipse.scaled(sc.s)


def measure(img, truth: Ellipse, camera, ideal_of) -> dict:
    out = {}
    grey = to_grey(img)
    t = time.process_time()
    try:
        e = paper_pipeline(grey, camera)
        out["paper"] = (np.linalg.norm(e.center_px - truth.center_px), np.abs(e.axes_px - truth.axes_px).max(), np.nan)
    except StationError:
        out["paper"] = None
    out["paper_t"] = time.process_time() - t
    t = time.process_time()
    try:
        det = detect_rim(img, camera=camera)
        d, _ = truth.distance(ideal_of(det))
        out["ours"] = (np.linalg.norm(det.ellipse.center_px - truth.center_px),
                       np.abs(det.ellipse.axes_px - truth.axes_px).max(), float(np.sqrt(np.mean(d**2))))
        out["score"] = det.score
    except StationError as ex:
        out["ours"] = None
        out["error"] = str(ex)
    out["ours_t"] = time.process_time() - t
    return out


def table(title: str, rows: list[dict]) -> None:
    print(f"\n{title}: {len(rows)} images")
    print(f"{'method':<8} {'fail':>4} {'centre mean':>11} {'centre max':>10} {'axes mean':>9} {'axes max':>8} "
          f"{'pts rms':>7} {'cpu ms mean':>11} {'cpu ms min':>10}")
    for m in ("paper", "ours"):
        ok = np.array([r[m] for r in rows if r[m] is not None], float).reshape(-1, 3)
        ts = np.array([r[m + "_t"] for r in rows]) * 1e3
        fail = sum(r[m] is None for r in rows)
        if len(ok):
            print(f"{m:<8} {fail:>4} {ok[:, 0].mean():>11.3f} {ok[:, 0].max():>10.3f} {ok[:, 1].mean():>9.3f} "
                  f"{ok[:, 1].max():>8.3f} {np.nanmean(ok[:, 2]) if m == 'ours' else float('nan'):>7.3f} "
                  f"{ts.mean():>11.1f} {ts.min():>10.1f}")
        else:
            print(f"{m:<8} {fail:>4}")
    for r in rows:
        if r.get("error"):
            print("   failed:", r["error"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2], help="simulated vehicles")
    ap.add_argument("--cameras", nargs="*", default=list(WHEEL_OF))
    ap.add_argument("--synthetic", type=int, default=20, help="synthetic wheels (noise sigma 2)")
    ap.add_argument("--per-image", action="store_true")
    args = ap.parse_args()
    cv2.setNumThreads(1)

    rows = []
    for seed in range(args.synthetic):
        img, truth = render_wheel(random_spec(np.random.default_rng(1000 + seed)), seed=1000 + seed)
        rows.append(measure(img, truth, None, lambda det: det.points_px))
    if rows:
        table("synthetic wheels (tests.synthetic_wheel, 1280x1024, noise sigma 2)", rows)

    if args.seeds:
        from simulators.world import SimWorld
        from station.config import load_config

        world = SimWorld.from_config(load_config())
        cache = Path(os.environ.get("RIM_BENCH_CACHE", "/tmp/rim_bench_cache"))
        cache.mkdir(parents=True, exist_ok=True)
        by_role = {"precision": [], "reference": []}
        for seed in args.seeds:
            scene = world.vehicle_scene(seed)
            world.set_scene(scene)
            for cam_id in args.cameras:
                path = cache / f"s{seed}_{cam_id}.png"
                img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.exists() else None
                if img is None:
                    img = world.render(cam_id)
                    cv2.imwrite(str(path), img)
                cam = world.cameras[cam_id]
                K = cam.K
                r = measure(img, true_ellipse(world, scene, cam_id), cam,
                            lambda det: det.points_norm * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]])
                if args.per_image:
                    print(seed, cam_id, {k: (np.round(v, 3) if isinstance(v, tuple) else v) for k, v in r.items()})
                role = "precision" if int(cam_id[3:]) % 2 else "reference"
                by_role[role].append(r)
        for role, rr in by_role.items():
            if rr:
                table(f"simulated station, {role} cameras, seeds {args.seeds}", rr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
