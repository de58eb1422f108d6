"""Benchmark: the station calibration against the simulator's truth (docs/calibration.md).

For each station seed (the simulated cameras' true mounts and lenses), run the calibration of
all four pairs and compare with the truth: focal length error (%), principal point error (px),
camera position (mm) and orientation (deg) errors, stereo baseline error (mm), reprojection
RMS (px), and the figures that decide toe and camber: the reprojection discrepancy of a grid of
check points filling each wheel's volume (px RMS, estimated vs true camera) and their stereo
triangulation error (mm RMS, station frame, eq. 24 on the true pixels with the estimated pair).
Reported: ``paper-v`` the paper's closed form exactly as published, on the eight vertices
(as found from the face boards; K = median over the views; pose from the fixture view with
all corners), ``paper`` the same closed form on every corner, and ``refined`` the calibration
the station saves (bundle adjustment).

Corner detections: ``--detections rendered`` renders every image with the simulator (noise
sigma from --noise) and detects the box (slow: about a minute per image on our shared
machines); ``--detections projected`` (default) projects the box corners with the true cameras
and adds Gaussian noise whose sigma is MEASURED first by detecting the box in
``--sigma-images`` rendered fixture images at the same noise (printed), so the maths is
benchmarked at the detector's real accuracy without rendering hundreds of images.

    .venv/bin/python bench/calibration.py --seeds 7 8 9 --poses 10
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

# run as a script, bench/ is sys.path[0] and this file would shadow the `calibration` package
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

from calibration.box_detect import BoxDetector  # noqa: E402
from calibration.camera_model import CameraModel  # noqa: E402
from calibration.station_calibration import calibrate_pair, fixture_poses  # noqa: E402
from calibration.stereo import StereoPair  # noqa: E402
from simulators.sim_operator import SimOperator, projected_detection  # noqa: E402
from simulators.world import SimWorld  # noqa: E402
from station.config import load_box, load_config  # noqa: E402


def wheel_grid(config, wheel: str, n=(5, 9, 9)) -> np.ndarray:
    """(M,3) check points filling the wheel's volume: around the fixture position (where the
    nominal wheel stands), +-0.15 m along the axle, +-0.35 m along y, z from 0.0 to 0.68 m."""
    c = np.asarray(config.calibration.fixture[wheel].position_m, float)
    xs = c[0] + np.linspace(-0.15, 0.15, n[0])
    ys = c[1] + np.linspace(-0.35, 0.35, n[1])
    zs = np.linspace(0.0, 0.68, n[2])
    return np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)


def rot_err_deg(Ra, Rb) -> float:
    c = (np.trace(Ra @ Rb.T) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


def measure_sigma(world, box, config, n_images: int, rng) -> float:
    """Per-axis detector error (px) on rendered fixture images at the world's noise."""
    det = BoxDetector(box)
    fixtures = fixture_poses(config)
    errs = []
    for wheel, pair in list(config.pairs.items())[:max(1, (n_images + 1) // 2)]:
        op = SimOperator(world, box, config, seed=0)
        op.place_box_at_fixture(wheel)
        R, t = fixtures[wheel]
        for cam in (pair.precision, pair.reference)[:n_images]:
            d = det.detect(world.render(cam, rng))
            truth = world.cameras[cam].project(d.points_box @ R.T + t)
            errs.append(d.pixels - truth)
    e = np.vstack(errs)
    return float(np.sqrt(np.mean(e ** 2)))


def calibrate_station(config, world, box, n_poses, mode, sigma, seed):
    op = SimOperator(world, box, config, seed=seed)
    det = BoxDetector(box)
    rng = np.random.default_rng(seed)
    fixtures = fixture_poses(config)
    results = {}
    for wheel, pair in config.pairs.items():
        ids = [pair.precision, pair.reference]
        dets = {c: [] for c in ids}

        def observe(R, t):
            for c in ids:
                if mode == "rendered":
                    dets_c = det.detect(world.render(c, rng))
                else:
                    dets_c = projected_detection(box, world.cameras[c], R, t, sigma, rng)
                yield c, dets_c
        for i in range(n_poses):
            op.place_box_for_intrinsics(ids, i)
            for c, d in observe(*op.poses[("intrinsics", wheel, i)]):
                dets[c].append(d)
        op.place_box_at_fixture(wheel)
        fdet = dict(observe(*fixtures[wheel]))
        results[wheel] = calibrate_pair(wheel, *ids, {c: (1280, 1024) for c in ids}, dets, fdet, fixtures[wheel])
    return results


def evaluate(config, world, results):
    rows, pair_rows = [], []
    for wheel, pr in results.items():
        grid = wheel_grid(config, wheel)
        est, lin = {}, {}
        for cam in (pr.left, pr.right):
            true = world.cameras[cam]
            e = pr.cameras[cam].model
            R0, t0 = pr.linear_fixture[cam]
            l = CameraModel(cam, true.width, true.height, pr.linear_K[cam], np.zeros(5), R0, t0)
            est[cam], lin[cam] = e, l
            variants = [("refined", e, pr.cameras[cam].reprojection_rms_px), ("paper", l, np.nan)]
            if cam in pr.vertex_K:
                variants.append(("paper-v", CameraModel(cam, true.width, true.height, pr.vertex_K[cam], np.zeros(5),
                                                        R0, t0), np.nan))
            for name, m, rms in variants:
                d = m.project(grid) - true.project(grid)
                rows.append(dict(
                    seed=config.simulation.station_seed, cam=cam, method=name,
                    focal_pct=100 * (m.K[0, 0] - true.K[0, 0]) / true.K[0, 0],
                    pp_px=float(np.linalg.norm(m.K[:2, 2] - true.K[:2, 2])),
                    pos_mm=1000 * float(np.linalg.norm(m.center_station - true.center_station)),
                    rot_deg=rot_err_deg(m.R_cam_station, true.R_cam_station),
                    rms_px=rms, check_px=float(np.sqrt(np.nanmean(np.sum(d ** 2, axis=1))))))
        true_pair = StereoPair(wheel, world.cameras[pr.left], world.cameras[pr.right])
        uv_l, uv_r = world.cameras[pr.left].project(grid), world.cameras[pr.right].project(grid)
        ok = world.cameras[pr.left].in_image(uv_l) & world.cameras[pr.right].in_image(uv_r)
        for name, cams in (("refined", est), ("paper", lin)):
            p = StereoPair(wheel, cams[pr.left], cams[pr.right])
            X = p.triangulate_station(uv_l[ok], uv_r[ok])
            pair_rows.append(dict(seed=config.simulation.station_seed, wheel=wheel, method=name,
                                  baseline_mm=1000 * (p.baseline_m - true_pair.baseline_m),
                                  tri_mm=1000 * float(np.sqrt(np.mean(np.sum((X - grid[ok]) ** 2, axis=1)))),
                                  n=int(ok.sum())))
    return rows, pair_rows


def evaluate_file(config, world, path) -> None:
    """Compare a saved calibration (e.g. from `station calibrate`, fully rendered) with the truth."""
    from calibration.calib_file import load_calibration  # noqa: E402
    calib = load_calibration(path, config)
    print(f"{path}: calibration {calib.calibration_id} of {calib.created_utc}, against station seed "
          f"{config.simulation.station_seed}")
    print("cam   focal(%)   pp(px)  pos(mm)  rot(deg)  rms(px)  check(px RMS)")
    for cam_id, c in calib.cameras.items():
        m, true = c.model, world.cameras[cam_id]
        grid = wheel_grid(config, config.cameras[cam_id].wheel)
        d = m.project(grid) - true.project(grid)
        print(f"{cam_id:5s} {100 * (m.K[0, 0] - true.K[0, 0]) / true.K[0, 0]:8.4f} "
              f"{np.linalg.norm(m.K[:2, 2] - true.K[:2, 2]):8.3f} "
              f"{1000 * np.linalg.norm(m.center_station - true.center_station):8.3f} "
              f"{rot_err_deg(m.R_cam_station, true.R_cam_station):9.5f} {c.reprojection_rms_px:8.3f} "
              f"{np.sqrt(np.nanmean(np.sum(d ** 2, axis=1))):10.4f}")
    print("wheel baseline(mm)  triangulation(mm RMS)")
    for wheel in calib.pairs:
        p = calib.pair(wheel)
        tp = StereoPair(wheel, world.cameras[p.left.name], world.cameras[p.right.name])
        grid = wheel_grid(config, wheel)
        uv_l, uv_r = tp.left.project(grid), tp.right.project(grid)
        ok = tp.left.in_image(uv_l) & tp.right.in_image(uv_r)
        X = p.triangulate_station(uv_l[ok], uv_r[ok])
        print(f"{wheel:5s} {1000 * (p.baseline_m - tp.baseline_m):11.4f} "
              f"{1000 * np.sqrt(np.mean(np.sum((X - grid[ok]) ** 2, axis=1))):14.4f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8, 9])
    ap.add_argument("--poses", type=int, default=10)
    ap.add_argument("--noise", type=float, default=2.0)
    ap.add_argument("--detections", choices=("projected", "rendered"), default="projected")
    ap.add_argument("--sigma", type=float, default=None, help="corner noise (px per axis) instead of measuring it")
    ap.add_argument("--sigma-images", type=int, default=2)
    ap.add_argument("--evaluate", metavar="FILE", help="only compare this calibration file with the truth "
                    "of the first --seeds value")
    args = ap.parse_args(argv)
    config = load_config()
    box = load_box(config.box_path)
    if args.evaluate:
        config.tree.simulation.station_seed = args.seeds[0]
        evaluate_file(config, SimWorld.from_config(config, noise_sigma=args.noise), args.evaluate)
        return 0
    all_rows, all_pairs = [], []
    sigma = args.sigma
    for seed in args.seeds:
        config.tree.simulation.station_seed = seed
        world = SimWorld.from_config(config, noise_sigma=args.noise)
        if args.detections == "projected" and sigma is None:
            t0 = time.time()
            sigma = measure_sigma(world, box, config, args.sigma_images, np.random.default_rng(seed))
            print(f"detector accuracy on {args.sigma_images} rendered fixture images at noise {args.noise}: "
                  f"{sigma:.4f} px per axis (RMS), {time.time() - t0:.0f} s")
        t0 = time.time()
        results = calibrate_station(config, world, box, args.poses, args.detections, sigma, seed)
        rows, pairs = evaluate(config, world, results)
        print(f"seed {seed}: calibrated in {time.time() - t0:.0f} s")
        all_rows += rows
        all_pairs += pairs
    print(f"\ncameras ({args.detections} detections, noise {args.noise} grey levels, {args.poses} poses per pair)")
    print("seed cam   method   focal(%)   pp(px)  pos(mm)  rot(deg)  rms(px)  check(px RMS)")
    for r in all_rows:
        print(f"{r['seed']:4d} {r['cam']:5s} {r['method']:8s} {r['focal_pct']:8.4f} {r['pp_px']:8.3f} {r['pos_mm']:8.3f} "
              f"{r['rot_deg']:9.5f} {r['rms_px']:8.3f} {r['check_px']:10.4f}")
    print("\npairs\nseed wheel method   baseline(mm)  triangulation(mm RMS)  points")
    for r in all_pairs:
        print(f"{r['seed']:4d} {r['wheel']:5s} {r['method']:8s} {r['baseline_mm']:11.4f} {r['tri_mm']:14.4f} {r['n']:10d}")
    print("\nsummary (worst over seeds and cameras/pairs)")
    for method in ("paper-v", "paper", "refined"):
        cr = [r for r in all_rows if r["method"] == method]
        pr = [r for r in all_pairs if r["method"] == method] or [dict(baseline_mm=np.nan, tri_mm=np.nan)]
        if not cr:
            continue
        print(f"{method:8s} |focal| {max(abs(r['focal_pct']) for r in cr):.4f} %  pp {max(r['pp_px'] for r in cr):.3f} px  "
              f"pos {max(r['pos_mm'] for r in cr):.3f} mm  rot {max(r['rot_deg'] for r in cr):.5f} deg  "
              f"check {max(r['check_px'] for r in cr):.4f} px  |baseline| {max(abs(r['baseline_mm']) for r in pr):.4f} mm  "
              f"triangulation {max(r['tri_mm'] for r in pr):.4f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
