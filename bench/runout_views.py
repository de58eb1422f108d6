"""How much a rim's measured plane moves when the car is moved, or the wheel turned, alone.

Runout compensation (bench/runout.py) reads every change of a rim's measured normal over the
roll as runout turning with the wheel. Rolling both moves the car (the cameras see the rim from
another angle) and turns the wheel. This bench separates the two on random vehicles whose rims
run out U(0, 0.3) deg: the car moved 15 cm back and forward with its wheels not turned
("moved"), and the wheels turned as far as that roll would turn them with the car in place
("turned"). It prints, against each rim's true plane at each position (the simulator's true
cameras, so calibration plays no part), the RMS of the linear change over the roll (half the
difference between the ends) and of its curvature (the ends' mean less the middle), toe-wise
and camber-wise. ``--bulge 0`` renders tyres whose sidewalls do not stand out before the flange.

    .venv/bin/python bench/runout_views.py --n 12 --cache /tmp/runout-views
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from calibration.station_frame import SIDE, WHEELS  # noqa: E402
from simulators.vehicle import random_runout  # noqa: E402
from station.config import load_config  # noqa: E402
from station.measure import measure_frames  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from runout import images_at  # noqa: E402

OFFSETS_M = (-0.15, 0.0, 0.15)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--seed", type=int, default=3200)
    ap.add_argument("--bulge", type=float, default=None, help="tyre sidewall bulge (m) for every vehicle")
    ap.add_argument("--cache", type=Path, default=None)
    args = ap.parse_args()
    from simulators.world import SimWorld

    config = load_config(None)
    world = SimWorld.from_config(config)
    change = {"moved": [], "turned": []}
    for seed in range(args.seed, args.seed + args.n):
        over = {} if args.bulge is None else {"sidewall_bulge_m": args.bulge}
        base = world.vehicle_scene(seed, **over)
        v = replace(base.vehicle, runout=random_runout(np.random.default_rng([seed, 32]), 0.3))
        forward = v.forward_station()
        for kind in change:
            errors = []
            for j, d in enumerate(OFFSETS_M):
                if kind == "moved":
                    moved = replace(v, position_m=(v.position_m[0] + d * forward[0], v.position_m[1] + d * forward[1]))
                else:
                    moved = replace(v, spin_phase_deg={w: v.spin_phase_deg[w] - np.degrees(SIDE[w] * d / v.wheel.tyre_radius_m)
                                                       for w in WHEELS})
                scene = replace(base, vehicle=moved)
                cache = args.cache / kind if args.cache else None
                if cache:
                    cache.mkdir(parents=True, exist_ok=True)
                images = images_at(world, scene, seed, 100 + j + (10 if kind == "turned" else 0), d, 8, cache)
                result = measure_frames(images, world.cameras, config)
                truth = world.truth(scene)
                R = np.asarray(result.alignment_frame["R_station_align"])
                errors.append([np.degrees(R.T @ (np.asarray(result.observations[w].circle.axis_station)
                                                 - np.asarray(truth["wheels"][w]["axis_station"])))[1:] for w in WHEELS])
            e = np.array(errors)                                     # (3 offsets, 4 wheels, toe/camber)
            change[kind] += list(zip((e[2] - e[0]) / 2, (e[0] + e[2]) / 2 - e[1]))
        print(f"  vehicle {seed - args.seed + 1}/{args.n} done", file=sys.stderr, flush=True)
    print(f"# A rim's measured normal over a 15 cm roll, split: {args.n} vehicles from seed {args.seed}"
          + (f", tyre bulge {args.bulge * 1000:.0f} mm" if args.bulge is not None else "") + ", true cameras\n")
    print("| change | linear toe-wise | linear camber-wise | curvature toe-wise | curvature camber-wise |")
    print("|---|---|---|---|---|")
    for kind, rows in change.items():
        lin = np.sqrt(np.mean(np.square([r[0] for r in rows]), axis=0))
        curv = np.sqrt(np.mean(np.square([r[1] for r in rows]), axis=0))
        print(f"| {kind} | {lin[0]:.4f} | {lin[1]:.4f} | {curv[0]:.4f} | {curv[1]:.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
