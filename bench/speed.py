"""Speed of the station against the peers an engineer would otherwise use (issue 7).

    .venv/bin/python bench/speed.py --cache /tmp/station-speed            # everything
    .venv/bin/python bench/speed.py --skip-peers --scales 1.0              # our cycle only

On the same simulated images (the station's eight cameras, vehicle --seed, rendered once with
supersample 8 and cached under --cache; re-runs only measure):

1. Rim detection, per image: ours (``station.rim.detect_rim``, no camera model, so every method
   works in the same original pixels) against OpenCV-contrib's ``cv2.ximgproc.findEllipses``
   and scikit-image's ``hough_ellipse``. Each peer runs in ITS OWN virtual environment, which
   this script creates under --peers-dir (they must never share one with our OpenCV); the
   scripts in bench/peers/ get image paths as JSON and answer JSON. A peer returns many
   ellipses; we take the one closest to the truth (centre distance + |da| + |db|), which is
   generous to it. scikit-image gets even more help (a crop around the true rim, downscaled,
   size bounds from the truth, a time cap) because on a full crop it takes minutes.
   Truth: the true rim circle projected (with distortion) by the true camera, 2000 points,
   direct ellipse fit. Errors: centre distance and the larger semi-axis error (px).
2. Our calibration refinement against ``cv2.calibrateCamera`` on the same points (one camera).
3. A full measurement cycle (eight images -> angles; capture excluded), per stage, with the
   true cameras as calibration, at 0.33, 1.3 and 5.2 megapixels (scale 0.5, 1, 2 of the
   configured 1280x1024 resolution and focal length), and its growth against pixel count.

Times are wall-clock medians (rim: best of --repeat) on this shared 2-core machine: compare
the ratios, not the absolute figures.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from station.errors import StationError  # noqa: E402

PEERS = {"opencv-contrib": ["opencv-contrib-python-headless"], "skimage": ["scikit-image"]}
WHEEL_OF = {"cam1": "FR", "cam2": "FR", "cam3": "FL", "cam4": "FL",
            "cam5": "RL", "cam6": "RL", "cam7": "RR", "cam8": "RR"}


# --- images ---------------------------------------------------------------------------------
def station_at(scale: float, cache: Path, seed: int):
    """(config, world, scene, images) at ``scale`` of the configured resolution; cached."""
    from simulators import image_cache
    from simulators.world import SimWorld
    from tests.station_fixtures import small_station_config

    d = cache / f"scale-{scale:g}"
    d.mkdir(parents=True, exist_ok=True)
    config = small_station_config(d, scale=scale)
    world = SimWorld.from_config(config, supersample=8)
    scene = world.vehicle_scene(seed)
    world.set_scene(scene)
    path = d / f"images-seed{seed}.npz"
    images = image_cache.load(path, world)  # None: not rendered yet, or for another station
    if images is None:
        images = {}
        for i, c in enumerate(world.cameras):
            print(f"  rendering {c} at {config.cameras[c].width}x{config.cameras[c].height} "
                  f"({i + 1}/8, once; cached in {d})", flush=True)
            images[c] = world.render(c, np.random.default_rng([seed, i]))
        image_cache.save(path, images, world)
    return config, world, scene, images


def true_ellipse_px(world, scene, cam_id: str) -> np.ndarray:
    """[cx, cy, a, b] of the true rim as imaged (original, distorted pixels)."""
    from station.rim.ellipse_fit import fit_direct

    v, cam = scene.vehicle, world.cameras[cam_id]
    c, Rw = v.wheel_frame_station(WHEEL_OF[cam_id])
    ang = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    circle = c + v.wheel.rim_radius_m * (np.cos(ang)[:, None] * Rw[:, 0] + np.sin(ang)[:, None] * Rw[:, 1])
    e = fit_direct(cam.project(circle))
    return np.array([*e.center_px, *e.axes_px])


def errors(found, truth) -> tuple[float, float]:
    if found is None:
        return float("nan"), float("nan")
    f = np.asarray(found[:4], float)
    return float(np.hypot(*(f[:2] - truth[:2]))), float(np.max(np.abs(np.sort(f[2:4])[::-1] - truth[2:4])))


# --- peers in their own venvs ---------------------------------------------------------------
def peer_python(name: str, peers_dir: Path) -> Path:
    """The venv of peer ``name`` (created, with its package, on first use)."""
    venv = peers_dir / name
    py = venv / "bin" / "python"
    if not py.exists():
        print(f"  creating the {name} peer environment in {venv} (once)", flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        subprocess.run([str(py), "-m", "pip", "install", "-q", *PEERS[name]], check=True)
    return py


def rim_table(world, scene, images, args) -> list[dict]:
    from station.rim import detect_rim

    tmp = Path(tempfile.mkdtemp(prefix="speed-rim-"))
    import cv2
    rows = []
    for cid, img in images.items():
        path = tmp / f"{cid}.png"
        cv2.imwrite(str(path), img)
        truth = true_ellipse_px(world, scene, cid)
        best, det = float("inf"), None
        for _ in range(args.repeat):
            t = time.perf_counter()
            try:
                det = detect_rim(img, camera_id=cid)
            except StationError:
                det = None
            best = min(best, time.perf_counter() - t)
        ours = None if det is None else [*det.ellipse.center_px, *det.ellipse.axes_px]
        rows.append({"cam": cid, "path": str(path), "truth": truth.tolist(), "ours_t": best,
                     "ours_err": errors(ours, truth)})
    if not args.skip_peers:
        py = peer_python("opencv-contrib", args.peers_dir)
        req = {"images": [{"path": r["path"], "truth": r["truth"]} for r in rows], "repeat": args.repeat}
        out = subprocess.run([str(py), str(ROOT / "bench/peers/findellipses.py")], input=json.dumps(req),
                             capture_output=True, text=True, check=True)
        for r, p in zip(rows, json.loads(out.stdout)):
            r["fe_t"], r["fe_n"], r["fe_err"] = p["time_s"], p["n_candidates"], errors(p["chosen"], np.array(r["truth"]))
        py = peer_python("skimage", args.peers_dir)
        for r in rows[:args.skimage_images]:
            cx, cy, a, b = r["truth"]
            try:
                out = subprocess.run([str(py), str(ROOT / "bench/peers/hough_ellipse.py"), r["path"],
                                      *map(str, (cx, cy, a, b, args.skimage_side))],
                                     capture_output=True, text=True, timeout=args.skimage_cap_s, check=True)
                p = json.loads(out.stdout)
                r["sk_t"], r["sk_err"] = p["time_s"], errors(p["chosen"], np.array(r["truth"]))
            except subprocess.TimeoutExpired:
                r["sk_t"], r["sk_err"] = float("inf"), (float("nan"), float("nan"))
    return rows


def print_rim(rows: list[dict], args) -> None:
    print(f"\n## Rim detection, {len(rows)} images 1280x1024 (time: best of {args.repeat}; error vs truth, px)\n")
    print("| camera | ours ms | ours centre / axis err | findEllipses ms | its centre / axis err (of N) "
          "| hough_ellipse s (crop) | its centre / axis err |")
    print("|---|---|---|---|---|---|---|")
    fmt = lambda e: f"{e[0]:.2f} / {e[1]:.2f}"  # noqa: E731
    for r in rows:
        fe = f"{r['fe_t'] * 1e3:.0f} | {fmt(r['fe_err'])} ({r['fe_n']})" if "fe_t" in r else "- | -"
        sk = f"{r['sk_t']:.1f} | {fmt(r['sk_err'])}" if "sk_t" in r else "not run | -"
        print(f"| {r['cam']} | {r['ours_t'] * 1e3:.0f} | {fmt(r['ours_err'])} | {fe} | {sk} |")
    med = lambda k: float(np.median([r[k] for r in rows if k in r]))  # noqa: E731
    medv = lambda k, i: float(np.nanmedian([r[k][i] for r in rows if k in r]))  # noqa: E731
    print(f"\nmedian: ours {med('ours_t') * 1e3:.0f} ms, centre err {medv('ours_err', 0):.2f} px, "
          f"axis err {medv('ours_err', 1):.2f} px")
    if any("fe_t" in r for r in rows):
        ratio = med("ours_t") / med("fe_t")
        print(f"findEllipses: {med('fe_t') * 1e3:.0f} ms, centre err {medv('fe_err', 0):.2f} px, axis err "
              f"{medv('fe_err', 1):.2f} px;  time ours/findEllipses = {ratio:.2f} "
              f"(target <= 0.5: {'MET' if ratio <= 0.5 else 'NOT MET'}); more accurate: "
              f"{'YES' if medv('ours_err', 0) < medv('fe_err', 0) and medv('ours_err', 1) < medv('fe_err', 1) else 'NO'}")
    sk = [r for r in rows if "sk_t" in r]
    if sk:
        t = float(np.median([r["sk_t"] for r in sk]))
        print(f"hough_ellipse ({len(sk)} images, truth crop downscaled to {args.skimage_side} px, cap "
              f"{args.skimage_cap_s:.0f} s): {t:.1f} s, time ours/hough_ellipse = {med('ours_t') / t:.4f}")


# --- calibration refinement vs cv2.calibrateCamera -------------------------------------------
def calib_row(world, args) -> dict:
    """One camera's intrinsics from --calib-views views of a planar 11 x 8 grid (40 mm), the TRUE
    camera's projection + 0.1 px Gaussian noise. Both methods start from the same guess (K from
    the nominal focal length and the image centre, no distortion, poses by solvePnP with it):
    ours is calibration/refine.py's BundleProblem (every view pose free, camera at the origin),
    OpenCV's is cv2.calibrateCamera with CALIB_USE_INTRINSIC_GUESS and the 5-term model."""
    import cv2

    from calibration.camera_model import rodrigues_to_matrix
    from calibration.refine import BundleProblem, Observation

    cam = world.cameras["cam3"]
    rng = np.random.default_rng(args.seed)
    g = np.stack(np.meshgrid(np.arange(11), np.arange(8)), -1).reshape(-1, 2) * 0.04
    board = np.c_[g - g.mean(0), np.zeros(len(g))]                       # (88,3) board frame, m
    obj, img = [], []
    for _ in range(args.calib_views):
        R = rodrigues_to_matrix(np.radians(rng.uniform(-30, 30, 3)))
        t = np.array([rng.uniform(-0.25, 0.25), rng.uniform(-0.2, 0.2), rng.uniform(1.0, 1.6)])
        xc = board @ R.T + t
        uv = cam.project_cam(xc) + rng.normal(0, 0.1, (len(board), 2))
        obj.append(board.astype(np.float32))
        img.append(uv.astype(np.float32))
    f0 = float(world.config.cameras["cam3"].nominal.focal_px)
    K0 = np.array([[f0, 0, (cam.width - 1) / 2], [0, f0, (cam.height - 1) / 2], [0, 0, 1.0]])
    poses = [cv2.solvePnP(o, i, K0, None)[1:] for o, i in zip(obj, img)]
    truth = np.r_[cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], cam.dist]

    def err(x):
        return {"f_pct": 100 * float(np.max(np.abs(x[:2] / truth[:2] - 1))),
                "c_px": float(np.max(np.abs(x[2:4] - truth[2:4]))), "k1": float(abs(x[4] - truth[4]))}

    t = time.perf_counter()
    prob = BundleProblem(np.r_[f0, f0, K0[0, 2], K0[1, 2], np.zeros(5)][None], np.zeros((1, 3)), np.zeros((1, 3)),
                         np.array([p[0].ravel() for p in poses]), np.array([p[1].ravel() for p in poses]),
                         [Observation(0, v, obj[v].astype(float), img[v].astype(float)) for v in range(len(obj))],
                         free_cam_pose=[False])
    res = prob.solve()
    ours_t = time.perf_counter() - t
    t = time.perf_counter()
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, (cam.width, cam.height), K0.copy(), np.zeros(5),
                                             flags=cv2.CALIB_USE_INTRINSIC_GUESS)
    cv_t = time.perf_counter() - t
    return {"views": len(obj), "points": len(obj) * len(board), "ours_t": ours_t, "cv_t": cv_t,
            "ours": {**err(res.intrinsics[0]), "rms": float(res.rms_px[0])},
            "cv": {**err(np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist.ravel()[:5]]), "rms": float(rms)}}


def print_calib(r: dict) -> None:
    print(f"\n## Calibration refinement: one camera, {r['views']} views, {r['points']} points (true projection "
          "+ 0.1 px noise)\n")
    print("| method | time ms | focal err % | principal point err px | k1 err | reprojection RMS px |")
    print("|---|---|---|---|---|---|")
    for name, key, tk in (("ours (calibration/refine.py BundleProblem)", "ours", "ours_t"),
                          ("cv2.calibrateCamera", "cv", "cv_t")):
        e = r[key]
        print(f"| {name} | {r[tk] * 1e3:.0f} | {e['f_pct']:.3f} | {e['c_px']:.2f} | {e['k1']:.4f} | {e['rms']:.3f} |")
    print(f"\ntime ours/calibrateCamera = {r['ours_t'] / r['cv_t']:.2f}")


# --- the full cycle ---------------------------------------------------------------------------
def cycle_row(scale: float, args, workers) -> dict:
    """Median timings of ``args.cycles`` cycles (after one warm-up cycle: each worker builds its
    per-camera tables once, as a station does at its first cycle)."""
    from station.measure import measure_frames

    config, world, scene, images = station_at(scale, args.cache, args.seed)
    measure_frames(images, world.cameras, config, workers=workers)
    runs = []
    for _ in range(args.cycles):
        r = measure_frames(images, world.cameras, config, workers=workers)
        if not r.valid:
            print(f"  scale {scale}: cycle failed: {r.failure.message}")
        runs.append(r.timing_s)
    m = {k: float(np.median([t.get(k, np.nan) for t in runs]))
         for k in ("wheels", "detect", "reconstruct", "angles", "total")}
    w, h = config.cameras["cam1"].width, config.cameras["cam1"].height
    return {"scale": scale, "w": w, "h": h, "mpx": w * h / 1e6, **m, "valid": r.valid}


def print_cycle(rows: list[dict]) -> None:
    print("\n## Full measurement cycle (8 images -> angles, capture excluded; median, s)\n")
    print("Four wheels in worker processes (one per core); detect and 3-D are the work summed over")
    print("the wheels, 'wheels' the wall time they took together.\n")
    print("| image | Mpx | work: detect (8 images) | work: 3-D (4 wheels) | wheels (wall) | angles | total | s per Mpx |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['w']}x{r['h']} | {r['mpx']:.2f} | {r['detect']:.3f} | {r['reconstruct']:.3f} | "
              f"{r['wheels']:.3f} | {r['angles']:.4f} | {r['total']:.3f} | {r['total'] / r['mpx']:.3f} |")
    base = next((r for r in rows if r["scale"] == 1.0), None)
    if base:
        print(f"\nfull cycle at 1280x1024: {base['total']:.3f} s (target <= 0.25 s: "
              f"{'MET' if base['total'] <= 0.25 else 'NOT MET'})")
    if len(rows) > 1:
        a, b = rows[0], rows[-1]
        g = np.log(b["total"] / a["total"]) / np.log(b["mpx"] / a["mpx"])
        print(f"growth: cost ~ pixels^{g:.2f} from {a['mpx']:.2f} to {b['mpx']:.2f} Mpx "
              f"(target exponent <= 1: {'MET' if g <= 1.0 else 'NOT MET'})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/station-speed"))
    ap.add_argument("--peers-dir", type=Path, default=Path("/tmp/station-peers"))
    ap.add_argument("--seed", type=int, default=1, help="simulated vehicle")
    ap.add_argument("--scales", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    ap.add_argument("--repeat", type=int, default=3, help="rim timing: best of N")
    ap.add_argument("--cycles", type=int, default=3, help="full cycles per scale (median)")
    ap.add_argument("--skip-peers", action="store_true")
    ap.add_argument("--skip-rim", action="store_true")
    ap.add_argument("--skip-calib", action="store_true")
    ap.add_argument("--calib-views", type=int, default=12)
    ap.add_argument("--skimage-images", type=int, default=2)
    ap.add_argument("--skimage-side", type=int, default=120, help="px of the downscaled crop's long side")
    ap.add_argument("--skimage-cap-s", type=float, default=300.0)
    args = ap.parse_args(argv)
    args.cache.mkdir(parents=True, exist_ok=True)
    from station.compute.blas_threads import single_thread_blas
    import scipy.optimize  # noqa: F401  (load scipy's OpenBLAS before setting it, as station/wheel/circle_fit.py does)
    single_thread_blas()
    print(f"# bench/speed.py  (cpus: {os.cpu_count()}, seed {args.seed}, cache {args.cache})")
    if not args.skip_rim:
        _, world, scene, images = station_at(1.0, args.cache, args.seed)
        print_rim(rim_table(world, scene, images, args), args)
    if not args.skip_calib:
        _, world, _, _ = station_at(1.0, args.cache, args.seed)
        print_calib(calib_row(world, args))
    from station.compute.workers import WorkerPool

    with WorkerPool() as workers:
        rows = [cycle_row(s, args, workers) for s in sorted(args.scales)]
    print_cycle(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
