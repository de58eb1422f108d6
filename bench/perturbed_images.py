"""What the station reports when one camera's image is damaged (simulators/image_damage.py).

For N simulated sigma-2 vehicles and every kind of damage, one camera per cycle (cam1, cam2,
... in turn) gets the damage and the cycle is measured with the simulator's true cameras. The
damaged camera's wheel is then one of:

- refused: the cycle is not valid, and its message says why;
- warned: valid, with a warning naming the wheel or the camera;
- right: valid, unwarned, and its toe and camber within max(0.1 deg, 3 stated std) of the truth;
- SILENT: valid, unwarned, and off by more: a number a technician would trust wrongly.

"others silent" counts the undamaged wheels of valid cycles that are off that way (a wrong
wheel centre turns the car frame and so every toe; a pair's calibration-drift warning says
so and covers them). Prints one row per kind.

    .venv/bin/python bench/perturbed_images.py --n 20 --cache /tmp/acc-cache
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.accuracy import _images  # noqa: E402
from simulators.image_damage import KINDS, damage  # noqa: E402
from calibration.station_frame import WHEELS  # noqa: E402
from station.config import load_config
from station.measure import measure_frames  # noqa: E402
from station.result import Measurement  # noqa: E402

WRONG_DEG = 0.1       # an error beyond this and beyond WRONG_STATED stated std is wrong
WRONG_STATED = 3.0


def _wheel_off(result: Measurement, wheel: str) -> tuple[float, bool]:
    """(larger of |toe| and |camber| error, deg; whether that is beyond what the wheel states)."""
    e, w = result.errors[wheel], result.wheels[wheel]
    err = max(abs(e["toe_error_deg"]), abs(e["camber_error_deg"]))
    stated = max(w.toe_std_deg, w.camber_std_deg)
    return err, err > max(WRONG_DEG, WRONG_STATED * stated)


def _names(warning: str) -> set[str]:
    """The wheels and cameras a warning names before its first colon ("RL cam6: ...",
    "FR: toe ...", "pair FR (cam1, cam2): ...")."""
    return set(re.findall(r"\b(?:[FR][LR]|cam\w+)\b", warning.split(":")[0]))


def classify(result: Measurement, wheel: str, cam: str) -> tuple[str, float | None, int]:
    """(class of the damaged camera's wheel, its error if reported unwarned, others silent)."""
    if not result.valid:
        return "refused", None, 0
    named = set().union(*map(_names, result.warnings)) if result.warnings else set()
    named |= {f.wheel for f in result.warning_flags if f.wheel}
    if result.has_flag("drift"):  # its warning puts the whole cycle in doubt
        named |= set(WHEELS)
    others = sum(_wheel_off(result, w)[1] and w not in named for w in WHEELS if w != wheel)
    if wheel in named or cam in named:
        return "warned", None, others
    err, wrong = _wheel_off(result, wheel)
    return ("SILENT" if wrong else "right"), err, others


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--config", default=None)
    ap.add_argument("--kinds", default=",".join(["none", *KINDS]))
    ap.add_argument("--cache", type=Path, default=None, help="rendered sigma-2 images (as bench/accuracy.py keeps them)")
    args = ap.parse_args()
    kinds = args.kinds.split(",")
    unknown = [k for k in kinds if k != "none" and k not in KINDS]
    if unknown:
        print(f"unknown kinds: {', '.join(unknown)} (expected none, {', '.join(KINDS)})", file=sys.stderr)
        return 2
    from simulators.world import SimWorld

    config = load_config(args.config)
    world = SimWorld.from_config(config)
    cam_ids = list(config.cameras)
    rows = {k: {"refused": 0, "warned": 0, "right": 0, "SILENT": 0, "others": 0, "err": []} for k in kinds}
    print(f"# Damaged images: {args.n} sigma-2 vehicles from seed {args.seed}, one camera damaged per cycle, "
          f"true cameras", flush=True)
    for i, seed in enumerate(range(args.seed, args.seed + args.n)):
        scene = world.vehicle_scene(seed)
        world.set_scene(scene)
        clean = _images(world, scene, "sigma2", seed, args.cache)
        truth = world.truth(scene)
        cam = cam_ids[i % len(cam_ids)]
        wheel = config.cameras[cam].wheel
        for kind in kinds:
            images = dict(clean)
            if kind != "none":
                images[cam] = damage(clean[cam], kind, np.random.default_rng([seed, len(kind)]))
            result = measure_frames(images, world.cameras, config)
            if result.valid:
                result.add_truth(truth)
            what, err, others = classify(result, wheel, cam)
            r = rows[kind]
            r[what] += 1
            r["others"] += others
            if err is not None:
                r["err"].append(err)
        print(f"  vehicle {i + 1}/{args.n} done ({cam} damaged)", file=sys.stderr, flush=True)
    print()
    print("| damage | what it stands for | refused | warned | right | SILENT | others silent | "
          "RMS error of the unwarned (deg) |")
    print("|---|---|---|---|---|---|---|---|")
    for kind in kinds:
        r = rows[kind]
        what = "nothing (the clean images)" if kind == "none" else KINDS[kind][0]
        rms = f"{np.sqrt(np.mean(np.square(r['err']))):.3f}" if r["err"] else "-"
        print(f"| {kind} | {what} | {r['refused']} | {r['warned']} | {r['right']} | {r['SILENT']} | "
              f"{r['others']} | {rms} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
