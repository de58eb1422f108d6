"""Does a refused wheel's message name the camera whose edge is off?

A wheel stated beyond the uncertainty limit refuses the cycle (code 404), and the message names
a camera by the largest part of the statement (station.stated_uncertainty.statement_parts):
where the pair's two views see the rim's axis differently, the camera whose edge is likely off
(station.stated_uncertainty._edge_off: a lip at the sensor's white, else arcs whose lip is no
brighter than the tyre beside it, else the fainter edge); where the lip's edge wavers round the
rim beyond its noise, the camera whose own edge-bias part is larger. This bench measures the
simulated vehicles of a scenario (the images of bench/accuracy.py, from its --cache when there)
with the station's calibration, and for every refused wheel so named, one row per reason,
compares the camera(s) named with
the camera whose own rim axis (station/wheel/view_agreement.py: the circle that camera's
edge points alone fit best) lies farther from the true axis, and with the camera whose
detected points lie farther off the true rim (the larger share beyond 0.3 px).

    STATION_DATA_DIR=<station calibrate> .venv/bin/python bench/refusal_naming.py --scenario sun-auto-exposure \\
        --n 20 --seed 7000 --cache /tmp/acc/cache
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench import outside_envelope, rim_scenarios  # noqa: E402
from bench.accuracy import SCENARIOS, _images  # noqa: E402
from calibration.calib_file import load_calibration  # noqa: E402
from calibration.station_frame import WHEELS  # noqa: E402
from station.config import load_config  # noqa: E402
from station.measure import measure_frames  # noqa: E402
from station.rim.ellipse_fit import fit_direct  # noqa: E402
from station.rim.preprocess import PixelMap  # noqa: E402
from tests.wheel_fixtures import angle_deg, rim_points  # noqa: E402

OFF_PX = 0.3           # a detected point farther than this from the true rim is off it
NAMED = re.compile(r"part of the rim \((.*)\)$|wavers round the rim beyond its noise, (?:most )?in (cam\d+(?: and cam\d+)?)")


def how_far_off(world, vehicle, wheel: str, observation) -> tuple[dict[str, float], dict[str, float]]:
    """Per camera of the pair: the share of its detected rim points more than OFF_PX from the
    true rim's image (the true camera's, ideal pixels), and the angle (deg) between its own rim
    axis (``observation.views``) and the true one."""
    _, axis, rim = rim_points(vehicle, wheel, n=4000)
    shares, tilts = {}, {}
    for cid, det, own in zip(observation.cams, observation.detections, observation.views.axes_station):
        cam = world.cameras[cid]
        pmap = PixelMap(cam)
        d, _ = fit_direct(pmap.undistort(cam.project(rim))).distance(pmap.undistort(det.points_px))
        shares[cid] = float(np.mean(np.abs(d) > OFF_PX))
        tilt = float(angle_deg(own, axis))
        tilts[cid] = min(tilt, 180.0 - tilt)
    return shares, tilts


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", choices=list(rim_scenarios.KINDS), required=True)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=7000)
    ap.add_argument("--cache", type=Path, default=None, help="bench/accuracy.py's image cache")
    args = ap.parse_args()
    config = load_config()
    if not config.calibration_file.exists():
        print(f"no calibration at {config.calibration_file}: run `station calibrate` first", file=sys.stderr)
        return 2
    from simulators.world import SimWorld

    calib = load_calibration(config.calibration_file, config)
    cams = {cid: calib.model(cid) for cid in config.cameras}
    world = SimWorld.from_config(config, noise_sigma=SCENARIOS[args.scenario][0])
    measured = outside_envelope.configured(args.scenario, config)
    counts = {reason: dict.fromkeys(("total", "both", "axis_named", "axis_first", "named_right", "first_right"), 0)
              for reason in ("views", "edge")}
    for seed in range(args.seed, args.seed + args.n):
        scene = rim_scenarios.scene_for(world, args.scenario, seed, config.nominal_vehicle)
        world.set_scene(scene)
        images = _images(world, scene, args.scenario, seed, args.cache, frames=config.capture.frames_averaged)
        res = measure_frames(images, cams, measured, calibration_cov=calib.pair_covariance)
        for flag in res.warning_flags:
            m = NAMED.search(flag.text or "") if flag.kind == "uncertain" else None
            if m is None or flag.wheel not in WHEELS:
                continue
            reason = "views" if m.group(1) is not None else "edge"
            named = re.findall(r"cam\d+", m.group(1) or m.group(2))
            o = res.observations[flag.wheel]
            off, tilt = how_far_off(world, scene.vehicle, flag.wheel, o)
            truly, turned = max(off, key=off.get), max(tilt, key=tilt.get)
            c = counts[reason]
            c["total"] += 1
            c["both"] += len(set(named)) > 1
            c["named_right"] += truly in named
            c["first_right"] += bool(named) and named[0] == truly
            c["axis_named"] += turned in named
            c["axis_first"] += bool(named) and named[0] == turned
            print(f"  {seed} {flag.wheel} ({reason}): named {', '.join(named)}; share off the rim "
                  + ", ".join(f"{c} {v:.2f}" for c, v in off.items()) + "; own axis off the true one "
                  + ", ".join(f"{c} {v:.3f} deg" for c, v in tilt.items()), file=sys.stderr)
    print("| scenario | reason | refused wheels | (both named) | axis farther off: named / named first "
          "| points farther off: named / named first |")
    print("|---|---|---|---|---|---|")
    for reason, c in counts.items():
        print(f"| {args.scenario} | {reason} | {c['total']} | ({c['both']}) | {c['axis_named']} / {c['axis_first']} "
              f"| {c['named_right']} / {c['first_right']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
