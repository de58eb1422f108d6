"""`station simulate`: render the configured station with a random vehicle into a replay set."""

from __future__ import annotations

import time
from pathlib import Path

from calibration.station_frame import WHEELS
from drivers.errors import FrameError
from station.errors import ConfigError


def add_arguments(parser):
    parser.add_argument("--seed", type=int, required=True, metavar="N",
                        help="vehicle/lighting seed: the same seed gives the same images")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="directory to create for the replay set (must not exist)")
    parser.add_argument("--noise", type=float, default=None, metavar="SIGMA",
                        help="sensor noise in grey levels (default: simulation.noise_sigma of the config)")


def run(args) -> int:
    from drivers.base import Frame
    from drivers.frame_store import save_cycle
    from drivers.registry import simulation
    from station.config import load_config

    if args.noise is not None and not 0 <= args.noise <= 50:
        raise ConfigError(f"--noise {args.noise}: expected a sensor noise between 0 and 50 grey levels")
    if args.seed < 0:
        raise ConfigError(f"--seed {args.seed}: expected a non-negative integer")
    out = Path(args.out)
    if out.exists():
        raise FrameError(f"{out}: already exists; a replay set is never overwritten",
                         hint="choose a new --out directory or remove the old one")
    config = load_config(args.config)
    images, truth, info = simulation(config, vehicle_seed=args.seed).replay_set(args.noise)
    now = time.monotonic_ns()
    frames = {cam_id: Frame(cam_id, image, now, 0, {"simulated": True}) for cam_id, image in images.items()}
    extra = {"source": "station simulate", "seed": info["seed"], "noise_sigma": info["noise_sigma"],
             "config": str(config.path), "render_seconds": info["render_seconds"]}
    try:
        save_cycle(out, frames, extra=extra, truth=truth)
    except OSError as e:
        raise FrameError(f"{out}: cannot write the replay set ({e.strerror or e})",
                         hint="check that the parent directory exists and is writable") from None
    wheels = truth["wheels"]
    print(f"wrote {out}: {len(frames)} images ({', '.join(f'{k}.png' for k in frames)}), "
          f"cycle.json, truth.json; rendered in {info['render_seconds']:.1f} s")
    print(f"vehicle seed {args.seed}: rim {wheels['FL']['rim_radius_m'] * 1000:.1f} mm, "
          + ", ".join(f"{w} toe {wheels[w]['toe_deg']:+.2f} camber {wheels[w]['camber_deg']:+.2f} deg"
                      for w in WHEELS))
    return 0
