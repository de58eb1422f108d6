"""Camber against the runways against camber against the plane of the wheel centres.

The signed angles read camber against the runways the wheels stand on: the station frame's z,
as the calibration box on its fixtures defines it (station/alignment.py). The paper's car frame
(section 3.2) takes its z from the plane through the wheel centres instead. The two agree on a
car whose four rim centres lie at one height. A lip seldom sits centred on its hub, though
(``simulation.runout_max_deg`` tilts each lip and moves its centre up to 0.5 mm off the hub),
and a tyre with less air sits lower. Either rolls the plane of the centres.

The vehicles here are those ``station measure`` puts on the built-in simulated lift, runout
included (``SimWorld.vehicle_scene``). Each is measured once; its camber is then read both ways
from the same wheel centres and rim axes, and compared with the rim planes' true camber. The
stated uncertainty is the station's, the same for both readings.

    STATION_DATA_DIR=<after station calibrate> .venv/bin/python bench/camber_reference.py --n 20 --cache /tmp/camber-cache
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "bench"))

from accuracy import _images  # noqa: E402

from calibration.station_frame import WHEELS  # noqa: E402
from station.alignment import paper_car_frame, toe_camber_rad  # noqa: E402
from station.config import load_config  # noqa: E402
from station.measure import measure_frames  # noqa: E402


AS_DRAWN = "as-drawn"  # the cache's name for these vehicles' images (runout kept, unlike sigma2's)


def centre_plane_frame(centers: dict) -> np.ndarray:
    """(3,3) the alignment frame with the paper's z (normal to the plane of the wheel centres)
    and the geometric centreline made perpendicular to it."""
    z = paper_car_frame(centers)[:, 2]
    line = (centers["FL"] + centers["FR"]) / 2 - (centers["RL"] + centers["RR"]) / 2
    y = line - z * (z @ line)
    y /= np.linalg.norm(y)
    return np.stack([np.cross(y, z), y, z], axis=1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--config", default=None)
    ap.add_argument("--calibration", choices=("file", "truth"), default="file")
    ap.add_argument("--cache", type=Path, default=None, help="keep the rendered images here")
    args = ap.parse_args()
    from simulators.world import SimWorld

    config = load_config(args.config)
    world = SimWorld.from_config(config)
    cameras, cov = world.cameras, None
    if args.calibration == "file":
        from calibration.calib_file import load_calibration

        if not config.calibration_file.exists():
            print(f"no calibration at {config.calibration_file}: run `station calibrate` first "
                  "(or --calibration truth)", file=sys.stderr)
            return 2
        calib = load_calibration(config.calibration_file, config)
        cameras, cov = {c: calib.model(c) for c in config.cameras}, calib.pair_covariance
    frames = config.capture.frames_averaged
    err = {"runways": [], "wheel centres": []}
    stated, refused = [], 0
    for i in range(args.n):
        seed = args.seed + i
        scene = world.vehicle_scene(seed)
        world.set_scene(scene)
        images = _images(world, scene, AS_DRAWN, seed, args.cache, frames=frames)  # bench/accuracy.py's rendering
        res = measure_frames(images, cameras, config, method="circle", calibration_cov=cov)
        if not res.valid:
            refused += 1
            print(f"  seed {seed}: refused ({res.failure.code})", file=sys.stderr)
            continue
        truth = world.truth(scene)["wheels"]
        centers = {w: np.asarray(res.wheels[w].center_station_m) for w in WHEELS}
        axes = np.stack([np.asarray(res.wheels[w].axis_station) for w in WHEELS])[None]
        _, camber = toe_camber_rad(centre_plane_frame(centers)[None], axes)
        for k, w in enumerate(WHEELS):
            true = truth[w]["rim_camber_deg"]
            err["runways"].append(res.wheels[w].camber_deg - true)
            err["wheel centres"].append(float(np.degrees(camber[0, k])) - true)
            stated.append(res.wheels[w].camber_std_deg)
        print(f"  vehicle {i + 1}/{args.n} done", file=sys.stderr, flush=True)
    s = np.array(stated)
    print(f"# Camber reference: {args.n} vehicles from seed {args.seed} as `station measure` draws them "
          f"(runout up to {config.simulation.runout_max_deg} deg), {frames}-frame means, "
          f"{args.calibration} calibration; {refused} cycles refused\n")
    print("| camber against | wheels | RMS (deg) | max abs (deg) | mean (deg) | left - right mean (deg) | "
          "stated / RMS | beyond 3 stated |")
    print("|---|---|---|---|---|---|---|---|")
    left = np.tile([w in ("FL", "RL") for w in WHEELS], len(s) // 4)
    for name, e in err.items():
        e = np.array(e)
        if not len(e):
            continue
        rms = np.sqrt(np.mean(e ** 2))
        print(f"| {name} | {len(e)} | {rms:.4f} | {np.max(np.abs(e)):.4f} | {np.mean(e):+.4f} | "
              f"{np.mean(e[left]) - np.mean(e[~left]):+.4f} | {np.sqrt(np.mean(s ** 2)) / rms:.2f} | "
              f"{np.sum(np.abs(e) > 3 * s)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
