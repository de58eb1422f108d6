"""Time of one synchronised capture of eight cameras; frames lost (target: none).

    .venv/bin/python bench/capture.py [--cycles 100] [--sim-cycles 3] [--skip-gige]

Rows:
- gige: eight Aravis GigE Vision emulators (arv-fake-gv-camera-0.8) at 1280x1024 Mono8,
  software trigger, on 127.0.0.2-9 inside a loopback-only network namespace (this script
  re-runs itself under ``unshare -n``); the full driver path (GVCP trigger, GVSP stream,
  numpy conversion, timestamp checks).
- sim-capture: eight SimCameras at 1280x1024 whose world serves a pre-rendered image plus fresh
  noise: the capture machinery (threads, triggers, deadline, checks) without the renderer.
- sim-render: eight SimCameras on the real simulators.world.SimWorld with a vehicle scene:
  dominated by the renderer, so fewer cycles (``--sim-cycles``).
A cycle counts as lost frames = the cameras that failed it.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))


def run_cycles(cams, cycles: int, timeout_s: float) -> dict:
    from station.capture.sync import capture_cycle
    from station.errors import CODED_ERRORS
    times, lost, failed = [], 0, 0
    for _ in range(cycles):
        t = time.monotonic()
        try:
            capture_cycle(cams, timeout_s)
        except CODED_ERRORS as e:
            failed += 1
            lost += len(getattr(e, "failures", cams))
            continue
        times.append(time.monotonic() - t)
    return {"cycles": cycles, "ok": len(times), "failed": failed, "frames_lost": lost,
            "median_ms": 1e3 * statistics.median(times) if times else None,
            "max_ms": 1e3 * max(times) if times else None}


def bench_gige_inside(cycles: int) -> dict:
    from aravis_probe import FakeCameras, _in_netns_guard, _station_config
    from station.capture.cameras import close_cameras, open_station_cameras
    _in_netns_guard()
    fakes = FakeCameras()
    try:
        for i in range(2, 10):
            fakes.start(f"127.0.0.{i}")
        config = _station_config(Path(tempfile.mkdtemp()), {f"cam{i}": f"aravis://127.0.0.{i + 1}" for i in range(1, 9)})
        cams = open_station_cameras(config)
        try:
            run_cycles(cams, 3, 3.0)  # warm-up: buffers, ARP-free loopback, caches
            return run_cycles(cams, cycles, config.capture.timeout_s)
        finally:
            close_cameras(cams)
    finally:
        fakes.stop_all()


def bench_gige(cycles: int) -> dict:
    from aravis_probe import netns_available, run_in_netns
    reason = netns_available()
    if reason:
        return {"skipped": reason}
    out = run_in_netns(str(Path(__file__).resolve()), ["--inside-gige", str(cycles)], 8, timeout_s=1800)
    return out


class _CachedWorld:
    """SimWorld's interface; one pre-rendered frame per camera, fresh noise per frame."""

    def __init__(self, world, images):
        self.cameras, self.config, self.images = world.cameras, world.config, images

    def render(self, cam_id, rng=None):
        # +-2 grey levels of uniform noise on an image kept away from 0 and 255: no clipping needed
        return self.images[cam_id] + rng.integers(0, 5, self.images[cam_id].shape, dtype=np.uint8) - 2


def bench_sim(cycles: int, real_renderer: bool) -> dict:
    from simulators.sim_station import SimulatedStation
    from simulators.world import SimWorld
    from station.capture.cameras import close_cameras, open_station_cameras
    from station.config import load_config
    config = load_config()
    world = SimWorld.from_config(config)
    world.set_scene(world.vehicle_scene(1))
    if not real_renderer:
        first = np.clip(world.render("cam1", np.random.default_rng(0)), 2, 253).astype(np.uint8)
        world = _CachedWorld(world, {cid: first for cid in world.cameras})
    cams = open_station_cameras(config, SimulatedStation(world).context())
    try:
        return run_cycles(cams, cycles, 600.0 if real_renderer else config.capture.timeout_s)
    finally:
        close_cameras(cams)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cycles", type=int, default=100)
    ap.add_argument("--sim-cycles", type=int, default=3)
    ap.add_argument("--skip-gige", action="store_true")
    ap.add_argument("--skip-render", action="store_true")
    ap.add_argument("--inside-gige", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.inside_gige is not None:
        print("RESULT " + json.dumps(bench_gige_inside(args.inside_gige)), flush=True)
        return 0
    rows = {}
    if not args.skip_gige:
        rows["gige 8x1280x1024"] = bench_gige(args.cycles)
    rows["sim-capture 8x1280x1024"] = bench_sim(args.cycles, real_renderer=False)
    if not args.skip_render:
        rows["sim-render 8x1280x1024"] = bench_sim(args.sim_cycles, real_renderer=True)
    print(f"{'cameras':26s} {'cycles':>6s} {'ok':>4s} {'median ms':>10s} {'max ms':>8s} {'frames lost':>11s}")
    for name, r in rows.items():
        if "skipped" in r:
            print(f"{name:26s} skipped: {r['skipped']}")
            continue
        fmt = lambda v: f"{v:.1f}" if v is not None else "-"  # noqa: E731
        print(f"{name:26s} {r['cycles']:6d} {r['ok']:4d} {fmt(r['median_ms']):>10s} {fmt(r['max_ms']):>8s} {r['frames_lost']:11d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
