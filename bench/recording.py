"""What recording and storing a cycle costs: .rrd size (MB) and the time added to a cycle (ms).

A realistic cycle: the eight 1280x1024 mono images the simulated station renders of a random
vehicle (simulators/world.py; a synthetic textured frame if the renderer is unavailable), eight
detected ellipses of ~2000 points with their edge points, four wheels of ~3000 rim points, the car
frame, a result with every angle, a few sequencer events; then the cycle is stored in a history
database (WAL, synchronous=FULL). Each cycle is written to a fresh .rrd and timed per phase.

    .venv/bin/python bench/recording.py [--cycles 5] [--quality 90] [--dir DIR]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from station.config import load_config  # noqa: E402
from station.records.history import History  # noqa: E402
from station.records.recording import CycleRecorder, read_recording_summary  # noqa: E402
from calibration.station_frame import WHEELS  # noqa: E402



def station_images(config, seed: int):
    """(cameras, images, source) of one simulated cycle (renders are cached in the temp folder:
    rendering eight frames takes minutes on a busy machine)."""
    try:
        from simulators import image_cache
        from simulators.world import SimWorld
        world = SimWorld.from_config(config)
        cache = Path(tempfile.gettempdir()) / f"bench-recording-render-seed{seed}.npz"
        images = image_cache.load(cache, world)
        if images is not None:
            return world.cameras, images, "simulator render (cached)"
        world.set_scene(world.vehicle_scene(seed))
        images = world.render_all()
        image_cache.save(cache, images, world)
        return world.cameras, images, "simulator render"
    except Exception as e:  # noqa: BLE001 - the bench still runs without the renderer
        print(f"(renderer unavailable: {type(e).__name__}: {e}; using synthetic frames)")
        from calibration.camera_model import CameraModel, look_at
        rng = np.random.default_rng(seed)
        cams, imgs = {}, {}
        v, u = np.mgrid[0:1024, 0:1280]
        for i, (cam_id, c) in enumerate(config.cameras.items()):
            R, t = look_at(np.array(c.nominal.position_m), np.array(c.nominal.look_at_m))
            K = np.array([[c.nominal.focal_px, 0, 640], [0, c.nominal.focal_px, 512], [0, 0, 1]])
            cams[cam_id] = CameraModel(cam_id, 1280, 1024, K, R_cam_station=R, t_cam_station=t)
            r = np.hypot(u - 640, v - 512)
            img = np.where(r < 330, 150 + 40 * np.cos(np.arctan2(v - 512, u - 640) * 5), 40.0)
            imgs[cam_id] = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
        return cams, imgs, "synthetic frames"


def cycle_payload(config, seed: int):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    detections = {}
    for cam_id in config.cameras:
        ell = np.c_[640 + 330 * np.cos(t), 512 + 300 * np.sin(t)]
        detections[cam_id] = (ell, ell + rng.normal(0, 0.4, ell.shape))
    wheels = {}
    for w in WHEELS:
        sx = 1 if w in ("FR", "RR") else -1
        c = np.array([sx * 0.78, 1.35 if w[0] == "F" else -1.35, 0.33])
        ax = np.array([sx, 0.002, -0.003])
        ang = rng.uniform(0, 2 * np.pi, 3000)
        rim = c + 0.2159 * np.c_[np.zeros_like(ang), np.cos(ang), np.sin(ang)] + rng.normal(0, 3e-4, (3000, 3))
        wheels[w] = (rim, c, ax / np.linalg.norm(ax), 0.2159)
    return detections, wheels


def result_for(seed: int, cycle: int, recording: str) -> dict:
    rng = np.random.default_rng(seed)
    toe = {w: float(rng.normal(0.05, 0.1)) for w in WHEELS}
    camber = {w: float(rng.normal(0.0, 0.3)) for w in WHEELS}
    return {
        "schema_version": 1, "cycle_id": f"bench-{cycle:04d}", "time_utc": "2026-11-22T22:00:00.000Z",
        "station": "bench", "software_version": "0.1.0", "calibration_id": "cal-bench", "job_id": "BENCH",
        "vehicle_spec": None, "valid": True, "failure": None, "warnings": [],
        "wheels": {w: {"toe_deg": toe[w], "toe_std_deg": 0.004, "camber_deg": camber[w],
                       "camber_std_deg": 0.005, "center_station_m": [0, 0, 0], "axis_station": [1, 0, 0],
                       "rim_radius_m": 0.2159} for w in WHEELS},
        "axles": {"front": {"total_toe_deg": toe["FL"] + toe["FR"]}, "rear": {"total_toe_deg": toe["RL"] + toe["RR"]}},
        "thrust_deg": (toe["RL"] - toe["RR"]) / 2, "recording": recording,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=5)
    ap.add_argument("--quality", type=int, default=90, help="JPEG quality")
    ap.add_argument("--dir", help="where to write (default: a temporary folder)")
    args = ap.parse_args(argv)
    config = load_config()
    cams, images, source = station_images(config, seed=3)
    detections, wheels = cycle_payload(config, seed=3)
    raw_mb = sum(im.nbytes for im in images.values()) / 1e6
    work = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="bench-recording-"))
    work.mkdir(parents=True, exist_ok=True)
    phases = ("cameras", "images", "detections", "wheels", "result+events", "close (write+fsync)",
              "history.store", "total")
    times: dict[str, list[float]] = {p: [] for p in phases}
    sizes = []
    with History(work / "history.sqlite") as history:
        for i in range(args.cycles + 1):  # cycle 0 warms up (imports, JIT of the encoder)
            path = work / f"bench-{i:04d}.rrd"
            t = [time.perf_counter()]
            rec = CycleRecorder(path, jpeg_quality=args.quality, recording_id="bench")
            rec.log_event("cycle start")
            rec.log_cameras(cams)
            t.append(time.perf_counter())
            rec.log_images(images)
            t.append(time.perf_counter())
            for cam_id, (ell, edges) in detections.items():
                rec.log_detection(cam_id, ell, edges)
            t.append(time.perf_counter())
            rec.log_car_frame([0, 0, 0.33], np.eye(3))
            for w, (rim, c, ax, r) in wheels.items():
                rec.log_wheel(w, rim, c, ax, r)
            t.append(time.perf_counter())
            result = result_for(i, i, str(path))
            rec.log_result(result)
            rec.log_event("cycle done")
            t.append(time.perf_counter())
            rec.close()
            t.append(time.perf_counter())
            history.store(result)
            t.append(time.perf_counter())
            if i == 0:
                continue
            for p, a, b in zip(phases[:-1], t[:-1], t[1:]):
                times[p].append((b - a) * 1e3)
            times["total"].append((t[-1] - t[0]) * 1e3)
            sizes.append(path.stat().st_size / 1e6)
    summary = read_recording_summary(work / f"bench-{args.cycles:04d}.rrd")
    print(f"images: {source}, 8 x 1280x1024 mono = {raw_mb:.1f} MB raw; JPEG quality {args.quality}; "
          f"{args.cycles} cycles (after one warm-up) in {work}")
    print(f"recording per cycle: {statistics.median(sizes):.2f} MB "
          f"(images {summary['image_bytes'] / 1e6:.2f} MB, {summary['images']} images, "
          f"{len(summary['entities'])} entities)")
    print(f"\n{'phase':<22} {'median ms':>10} {'max ms':>8}")
    for p in phases:
        print(f"{p:<22} {statistics.median(times[p]):>10.1f} {max(times[p]):>8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
