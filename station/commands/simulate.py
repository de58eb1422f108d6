"""`station simulate`: render the configured station with a random vehicle into a replay set."""

from __future__ import annotations

import time
from pathlib import Path

from drivers.errors import FrameError
from station.errors import ConfigError

HELP = "render the simulated station with a random vehicle and save it as a replay set (+ truth)"


def add_arguments(parser):
    parser.add_argument("--seed", type=int, required=True, metavar="N",
                        help="vehicle/lighting seed: the same seed gives the same images")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="directory to create for the replay set (must not exist)")
    parser.add_argument("--noise", type=float, default=None, metavar="SIGMA",
                        help="sensor noise in grey levels (default: simulation.noise_sigma of the config)")


def run(args) -> int:
    import numpy as np

    from drivers.base import Frame
    from drivers.frame_store import save_cycle
    from simulators.world import SimWorld
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
    world = SimWorld.from_config(config, noise_sigma=args.noise)
    scene = world.vehicle_scene(args.seed)
    world.set_scene(scene)
    start = time.perf_counter()
    images = world.render_all(np.random.default_rng([args.seed, 1]))
    seconds = time.perf_counter() - start
    now = time.monotonic_ns()
    frames = {cam_id: Frame(cam_id, image, now, 0, {"simulated": True}) for cam_id, image in images.items()}
    extra = {"source": "station simulate", "seed": int(args.seed), "noise_sigma": world.noise_sigma,
             "config": str(config.path), "render_seconds": round(seconds, 2)}
    try:
        save_cycle(out, frames, extra=extra, truth=world.truth(scene))
    except OSError as e:
        raise FrameError(f"{out}: cannot write the replay set ({e.strerror or e})",
                         hint="check that the parent directory exists and is writable") from None
    v = scene.vehicle
    print(f"wrote {out}: {len(frames)} images ({', '.join(f'{k}.png' for k in frames)}), "
          f"cycle.json, truth.json; rendered in {seconds:.1f} s")
    print(f"vehicle seed {args.seed}: rim {v.wheel.rim_radius_m * 1000:.1f} mm, "
          + ", ".join(f"{w} toe {v.toe_deg[w]:+.2f} camber {v.camber_deg[w]:+.2f} deg" for w in ("FL", "FR", "RL", "RR")))
    return 0
