"""What in the rim edge drives the toe and camber errors: the low harmonics of the edge offset.

For each simulated vehicle (the sigma-2 images of bench/accuracy.py, from its --cache when
there), every camera's detected rim points are compared with the true rim projected by the
true camera (ideal pixels): the signed offset d(phi) (px, + outside) round the rim, phi the
image angle about the rim's centre (0 right, 90 down). Its harmonics up to the second,

    d(phi) ~ mean + c1 cos(phi) + s1 sin(phi) + c2 cos(2 phi) + s2 sin(2 phi),

are what an ellipse fit can take up (size, centre, shape and orientation). Per wheel position,
a linear regression of the wheel's camber (and toe) error on its two cameras' ten harmonics
says how much of the error they explain (leave-one-out R^2) and which harmonic carries it
(degrees per standard deviation of each coefficient).

    .venv/bin/python bench/edge_harmonics.py --n 50 --cache /tmp/acc/cache
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "bench"))

import outside_envelope  # noqa: E402
from accuracy import _images  # noqa: E402

from calibration.station_frame import WHEELS  # noqa: E402
from station.config import load_config
from station.measure import measure_frames  # noqa: E402
from station.rim import detect_rim  # noqa: E402
from station.rim.ellipse_fit import fit_direct  # noqa: E402
from station.rim.preprocess import PixelMap  # noqa: E402

HARMONICS = ("mean", "c1", "s1", "c2", "s2")


def harmonics(phi_deg: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(5,) least-squares harmonics of offsets d (N,) at image angles phi_deg (N,)."""
    p = np.radians(phi_deg)
    A = np.stack([np.ones_like(p), np.cos(p), np.sin(p), np.cos(2 * p), np.sin(2 * p)], axis=1)
    return np.linalg.lstsq(A, d, rcond=None)[0]


def view_offsets(image, cam, vehicle, wheel: str, cam_id: str):
    """(phi_deg (N,), d (N,)) of one camera's detected rim points against the true rim."""
    centre, R_wheel = vehicle.wheel_frame_station(wheel)
    ang = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
    rim = centre + vehicle.wheel.rim_radius_m * (np.cos(ang)[:, None] * R_wheel[:, 0]
                                                 + np.sin(ang)[:, None] * R_wheel[:, 1])
    pmap = PixelMap(cam)
    truth = fit_direct(pmap.undistort(cam.project(rim)))
    pts = pmap.undistort(detect_rim(image, camera=cam, camera_id=cam_id).points_px)
    d, _ = truth.distance(pts)
    phi = np.degrees(np.arctan2(pts[:, 1] - truth.center_px[1], pts[:, 0] - truth.center_px[0])) % 360
    return phi, d


def loo_r2(X: np.ndarray, y: np.ndarray) -> float:
    """Leave-one-out R^2 of the linear model y ~ [1, X]."""
    A = np.c_[np.ones(len(y)), X]
    pred = np.empty_like(y)
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        pred[i] = A[i] @ np.linalg.lstsq(A[keep], y[keep], rcond=None)[0]
    return float(1 - np.mean((y - pred) ** 2) / np.var(y))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--config", default=None)
    ap.add_argument("--cache", type=Path, default=None, help="bench/accuracy.py's image cache")
    args = ap.parse_args()
    from simulators.world import SimWorld

    config = load_config(args.config)
    world = SimWorld.from_config(config, noise_sigma=2.0)
    cams_of = {w: [c for c in config.cameras if config.cameras[c].wheel == w] for w in WHEELS}
    rows = {w: [] for w in WHEELS}  # per wheel: (10 harmonics, camber error, toe error)
    for i in range(args.n):
        seed = args.seed + i
        scene = outside_envelope.scene_for(world, "sigma2", seed, config.nominal_vehicle)
        world.set_scene(scene)
        images = _images(world, scene, "sigma2", seed, args.cache)
        res = measure_frames(images, world.cameras, config, method="circle")
        if not res.valid:
            print(f"  seed {seed}: cycle failed, left out", file=sys.stderr)
            continue
        res.add_truth(world.truth(scene))
        for w in WHEELS:
            h = [harmonics(*view_offsets(images[c], world.cameras[c], scene.vehicle, w, c)) for c in cams_of[w]]
            e = res.errors[w]
            rows[w].append((np.concatenate(h), e["camber_error_deg"], e["toe_error_deg"]))
        print(f"  vehicle {i + 1}/{args.n} done", file=sys.stderr, flush=True)
    names = [f"{k}{c}" for k in ("A.", "B.") for c in HARMONICS]
    print(f"\n## Edge-offset harmonics against toe and camber errors, {args.n} sigma-2 vehicles, true cameras\n")
    print("| wheel | camber RMS | camber LOO R^2 | toe RMS | toe LOO R^2 | harmonics' std (px), cameras A / B |")
    print("|---|---|---|---|---|---|")
    for w in WHEELS:
        X = np.array([r[0] for r in rows[w]])
        cam, toe = np.array([r[1] for r in rows[w]]), np.array([r[2] for r in rows[w]])
        sd = " ".join(f"{n}:{v:.3f}" for n, v in zip(names, X.std(0)))
        print(f"| {w} | {np.sqrt(np.mean(cam ** 2)):.4f} | {loo_r2(X, cam):.2f} | {np.sqrt(np.mean(toe ** 2)):.4f} "
              f"| {loo_r2(X, toe):.2f} | {sd} |")
    print("\ncamber error (deg) per standard deviation of each harmonic, cameras A / B of the wheel:\n")
    for w in WHEELS:
        X = np.array([r[0] for r in rows[w]])
        cam = np.array([r[1] for r in rows[w]])
        Z = (X - X.mean(0)) / X.std(0)
        b = np.linalg.lstsq(np.c_[np.ones(len(cam)), Z], cam, rcond=None)[0][1:]
        print(f"  {w} ({'/'.join(cams_of[w])}): " + " ".join(f"{n}:{v:+.4f}" for n, v in zip(names, b)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
