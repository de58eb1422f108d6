"""Runout compensation on random simulated vehicles whose rims run out (issue 32's benchmark).

Every vehicle's four rims are tilted against their spin axes by U(0, --runout) deg at a random
phase (simulators.vehicle.random_runout); the car is rolled along the procedure's plan
(station.procedures.runout.ROLL_PLAN, --distance each way) and captured at each position (8-frame
means, sensor noise sigma 2). Each capture is measured with the station's calibration; the
procedure then finds every wheel's spin axis (the lip normals' fit, joined with the face's own
motion where the two agree). Prints, against the spin-axis truth, the error of
toe, camber, total toe and thrust compensated and, on the same vehicles, of the last capture's
rim-plane measurement; the runout's error; stated uncertainty against the observed error; the
refused procedures; the computing time of the procedure (its captures' measurements and the fit).

    .venv/bin/python bench/runout.py --n 50 --cache /tmp/runout-cache
    .venv/bin/python bench/runout.py --n 20 --distance 0.10 --cache /tmp/runout-cache   # a shorter roll
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from calibration.station_frame import WHEELS  # noqa: E402
from simulators import image_cache  # noqa: E402
from simulators.vehicle import random_runout  # noqa: E402
from station.capture.frame_average import mean_image  # noqa: E402
from station.config import load_config  # noqa: E402
from station.errors import ProcedureError  # noqa: E402
from station.measure import measure_frames  # noqa: E402
from station.procedures.runout import ROLL_PLAN, compensated, wheel_rolls  # noqa: E402

GROUPS = {"toe": [f"{w}.toe" for w in WHEELS], "camber": [f"{w}.camber" for w in WHEELS],
          "total toe": ["front.total_toe", "rear.total_toe"], "thrust": ["thrust"]}


def images_at(world, scene, seed: int, position: int, roll_m: float, frames: int, cache: Path | None) -> dict:
    """The eight images (each the mean of ``frames``) of ``scene`` at one roll position, cached."""
    path = cache / f"runout-{seed}-p{position}-{roll_m * 1000:.0f}mm-f{frames}.npz" if cache else None
    images = image_cache.load(path, world) if path else None
    if images is not None:
        return images
    world.set_scene(scene)
    bursts = [world.render_all(np.random.default_rng([20_000 + seed, position, k])) for k in range(frames)]
    images = bursts[0] if frames == 1 else {c: mean_image([b[c] for b in bursts]) for c in bursts[0]}
    if path:
        image_cache.save(path, images, world)
    return images


def errors(result, truth) -> dict[str, float]:
    out = {}
    for w in WHEELS:
        out[f"{w}.toe"] = result.wheels[w].toe_deg - truth["wheels"][w]["toe_deg"]
        out[f"{w}.camber"] = result.wheels[w].camber_deg - truth["wheels"][w]["camber_deg"]
    out["front.total_toe"] = result.axles["front"].total_toe_deg - truth["total_toe_front_deg"]
    out["rear.total_toe"] = result.axles["rear"].total_toe_deg - truth["total_toe_rear_deg"]
    out["thrust"] = result.thrust_deg - truth["thrust_deg"]
    return out


def stated(result) -> dict[str, float]:
    out = {}
    for w in WHEELS:
        out[f"{w}.toe"] = result.wheels[w].toe_std_deg
        out[f"{w}.camber"] = result.wheels[w].camber_std_deg
    out["front.total_toe"] = result.axles["front"].total_toe_std_deg
    out["rear.total_toe"] = result.axles["rear"].total_toe_std_deg
    out["thrust"] = result.thrust_std_deg
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--seed", type=int, default=3200)
    ap.add_argument("--runout", type=float, default=0.3, help="largest rim tilt (deg), U(0, this)")
    ap.add_argument("--distance", type=float, default=0.15, help="how far the car is rolled each way (m)")
    ap.add_argument("--frames", type=int, default=None, help="frames averaged per capture (default: the config's)")
    ap.add_argument("--calibration", choices=["file", "truth"], default="file")
    ap.add_argument("--config", default=None)
    ap.add_argument("--cache", type=Path, default=None)
    args = ap.parse_args()
    config = load_config(args.config)
    from simulators.world import SimWorld

    world = SimWorld.from_config(config)
    if args.calibration == "truth":
        cams, cov = world.cameras, None
    else:
        from calibration.calib_file import load_calibration

        if not config.calibration_file.exists():
            print(f"no calibration at {config.calibration_file}: run `station calibrate` first (or --calibration truth)",
                  file=sys.stderr)
            return 2
        calib = load_calibration(config.calibration_file, config)
        cams, cov = {c: calib.model(c) for c in config.cameras}, calib.pair_covariance
    frames = config.capture.frames_averaged if args.frames is None else args.frames
    comp_err, comp_std, rim_err, runout_err, failed, seconds = [], [], [], [], [], []
    turn_err, face_points = [], []
    for i in range(args.n):
        seed = args.seed + i
        base = world.vehicle_scene(seed)
        vehicle = replace(base.vehicle, runout=random_runout(np.random.default_rng([seed, 32]), args.runout))
        results, captures = [], []
        for k, position in enumerate(ROLL_PLAN):
            scene = replace(base, vehicle=replace(vehicle, roll_m=position * args.distance))
            images = images_at(world, scene, seed, k, position * args.distance, frames, args.cache)
            t0 = time.perf_counter()
            results.append(measure_frames(images, cams, config, calibration_cov=cov, refuse_uncertain=False))
            seconds.append(time.perf_counter() - t0)
            captures.append(images)
        truth = world.truth(scene)
        if not all(r.valid for r in results):
            bad = next(r for r in results if not r.valid)
            failed.append(f"seed {seed}: a capture failed: {bad.failure.message}")
            print(f"  seed {seed}: FAILED {failed[-1]}", file=sys.stderr)
            continue
        t0 = time.perf_counter()
        try:
            rolls = wheel_rolls(results, captures, cams, config)
        except ProcedureError as e:
            failed.append(f"seed {seed}: {e}")
            print(f"  seed {seed}: REFUSED {e}", file=sys.stderr)
            continue
        result = compensated(results[-1], rolls, config)
        seconds[-1] += time.perf_counter() - t0
        if not result.valid:
            failed.append(f"seed {seed}: {result.failure.message}")
            print(f"  seed {seed}: REFUSED {failed[-1]}", file=sys.stderr)
            continue
        comp_err.append(errors(result, truth))
        comp_std.append(stated(result))
        rim_err.append(errors(results[-1], truth))
        runout_err += [rolls[w].spin.runout_deg - truth["wheels"][w]["runout_deg"] for w in WHEELS]
        face_points += [rolls[w].face_points for w in WHEELS]
        truths = [world.truth(replace(base, vehicle=replace(vehicle, roll_m=p * args.distance))) for p in ROLL_PLAN]
        turn_err += [rolls[w].roll_deg[k] - (truths[k]["wheels"][w]["roll_deg"] - truth["wheels"][w]["roll_deg"])
                     for w in WHEELS for k in range(len(ROLL_PLAN) - 1)]
        print(f"  vehicle {i + 1}/{args.n} done", file=sys.stderr, flush=True)
    print(f"# Runout compensation: {args.n} vehicles from seed {args.seed}, runout U(0, {args.runout}) deg, "
          f"rolled {args.distance * 100:.0f} cm each way ({len(ROLL_PLAN)} captures, {frames} frame(s) each), "
          f"{args.calibration} calibration\n")
    print("| angle | compensated RMS (deg) | compensated max | stated / RMS | rim plane RMS | rim plane max |")
    print("|---|---|---|---|---|---|")
    for group, names in GROUPS.items():
        e = np.array([[row[k] for k in names] for row in comp_err]).ravel()
        s = np.array([[row[k] for k in names] for row in comp_std]).ravel()
        r = np.array([[row[k] for k in names] for row in rim_err]).ravel()
        if not len(e):
            continue
        rms = np.sqrt(np.mean(e ** 2))
        print(f"| {group} | {rms:.4f} | {np.max(np.abs(e)):.4f} | {np.sqrt(np.mean(s ** 2)) / rms:.2f} | "
              f"{np.sqrt(np.mean(r ** 2)):.4f} | {np.max(np.abs(r)):.4f} |")
    if runout_err:
        ro = np.array(runout_err)
        print(f"\nrunout amount error: RMS {np.sqrt(np.mean(ro ** 2)):.4f} deg, max {np.max(np.abs(ro)):.4f} deg "
              f"({len(ro)} wheels)")
    if turn_err:
        te = np.abs(turn_err)
        print(f"wheel turns from the face: error median {np.median(te):.4f} deg, RMS {np.sqrt(np.mean(te ** 2)):.4f}, "
              f"max {te.max():.3f} ({len(te)} turns)")
    if face_points:
        fp = np.array(face_points)
        print(f"the face's motion joined the lip's axis on {np.sum(fp > 0)} of {len(fp)} wheels "
              f"(points followed: median {np.median(fp[fp > 0]) if np.any(fp > 0) else 0:.0f})")
    print(f"refused or failed procedures: {len(failed)} of {args.n}" + "".join(f"\n  - {f}" for f in failed))
    per_vehicle = np.sum(np.array(seconds).reshape(-1, len(ROLL_PLAN)), axis=1) if len(seconds) % len(ROLL_PLAN) == 0 else []
    if len(per_vehicle):
        print(f"procedure's computing time (its {len(ROLL_PLAN)} measurements and the fit; capture and operator "
              f"excluded): median {np.median(per_vehicle):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
