"""Steering geometry on random simulated vehicles (issue 33's benchmark).

Every vehicle's front wheels steer about random kingpins (caster 2-8 deg, SAI 8-15 deg, scrub
radius and trail, an Ackermann share: simulators.vehicle.random_kingpins); the simulated
technician steers through the procedure's plan (station.procedures.steering.STEER_PLAN, --sweep
each way) and the station captures each position (8-frame means, sensor noise sigma 2, square
rims: the included angle takes the measured camber). Each capture is measured with the station's
calibration; the procedure then fits each front wheel's steering axis. Prints, against the
kingpin truth, the error of caster, SAI and included angle from the full pose (the rim's normal
and its face's turn), from the rim normals alone, and the shops' classic caster; the stated
uncertainty against the observed error; the kingpin offset's error; the faces' measured turns
against the truth; refused procedures; the
computing time (the captures' measurements and the fit).

    .venv/bin/python bench/steering.py --n 50 --cache /tmp/steering-cache
    .venv/bin/python bench/steering.py --n 20 --sweep 20 --cache /tmp/steering-cache
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
from simulators.vehicle import Runout  # noqa: E402
from station.config import load_config  # noqa: E402
from station.errors import ProcedureError  # noqa: E402
from station.measure import measure_frames  # noqa: E402
from station.wheel.rim_pattern import ring_basis  # noqa: E402
from station.procedures.steering import DEFAULT_SWEEP_DEG, FRONT, STEER_PLAN, steering_geometry, sweep_poses  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from runout import images_at  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--seed", type=int, default=3300)
    ap.add_argument("--sweep", type=float, default=DEFAULT_SWEEP_DEG, help="how far the wheels are steered each way (deg)")
    ap.add_argument("--frames", type=int, default=None, help="frames averaged per capture (default: the config's)")
    ap.add_argument("--calibration", choices=["file", "truth"], default="file")
    ap.add_argument("--cache", type=Path, default=None)
    args = ap.parse_args()
    config = load_config(None)
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
    rows, failed, seconds, turn_errors = [], [], [], []
    for i in range(args.n):
        seed = args.seed + i
        base = world.vehicle_scene(seed, runout={w: Runout() for w in WHEELS})
        results, captures, scenes = [], [], []
        t_measure = 0.0
        for k, position in enumerate(STEER_PLAN):
            scene = replace(base, vehicle=replace(base.vehicle, steer_deg=position * args.sweep))
            tag = f"steer{position * args.sweep:+.0f}"
            images = images_at(world, scene, seed, k, 0.0, frames, args.cache / tag if args.cache else None)
            t0 = time.perf_counter()
            results.append(measure_frames(images, cams, config, calibration_cov=cov,
                                          refuse_uncertain=k == len(STEER_PLAN) - 1))
            t_measure += time.perf_counter() - t0
            captures.append(images)
            scenes.append(scene)
        truth = world.truth(scene)
        bad = next((k for k, r in enumerate(results) if not r.valid), None)
        if bad is not None:
            failed.append(f"seed {seed}: capture {bad + 1} ({STEER_PLAN[bad] * args.sweep:+.0f} deg) failed: "
                          f"{results[bad].failure.message}")
            print(f"  {failed[-1]}", file=sys.stderr)
            continue
        t0 = time.perf_counter()
        try:
            sweep = sweep_poses(results, captures, cams, config)
        except ProcedureError as e:
            failed.append(f"seed {seed}: {e}")
            print(f"  seed {seed}: REFUSED {e}", file=sys.stderr)
            continue
        steering = steering_geometry(results[-1], sweep, results, args.sweep)
        seconds.append(t_measure + time.perf_counter() - t0)
        for w in FRONT:
            turn_errors.extend(sweep[w].psi_deg[:-1] - _true_turns_deg(scenes, w)[:-1])
            t, r = truth["wheels"][w], steering.wheels[w]
            kingpin = np.asarray(t["kingpin_point_station_m"])
            center = np.asarray(results[-1].wheels[w].center_station_m)
            R_a = np.asarray(results[-1].alignment_frame["R_station_align"])
            true_offset = float((kingpin - np.array([center[0], center[1], 0.0])) @ (-np.sign(center[0]) * R_a[:, 0]))
            rows.append({"caster": r.caster_deg - t["caster_deg"], "sai": r.sai_deg - t["sai_deg"],
                         "included": r.included_angle_deg - t["included_angle_deg"],
                         "caster_std": r.caster_std_deg, "sai_std": r.sai_std_deg,
                         "included_std": r.included_angle_std_deg,
                         "caster_normals": r.caster_from_normals_deg - t["caster_deg"],
                         "sai_normals": r.sai_from_normals_deg - t["sai_deg"],
                         "caster_classic": r.caster_classic_deg - t["caster_deg"],
                         "offset_mm": 1000 * (r.kingpin_offset_m - true_offset)})
        print(f"  vehicle {i + 1}/{args.n} done", file=sys.stderr, flush=True)
    print(f"# Steering geometry: {args.n} vehicles from seed {args.seed}, steered {args.sweep:g} deg each way "
          f"({len(STEER_PLAN)} captures, {frames} frame(s) each), {args.calibration} calibration\n")
    if rows:
        col = {k: np.array([r[k] for r in rows]) for k in rows[0]}
        rms = lambda a: float(np.sqrt(np.mean(a ** 2)))  # noqa: E731
        print("| angle | full pose RMS (deg) | full pose max | stated / RMS | rim normals alone RMS | "
              "normals alone max | classic 1.5x rule RMS | classic max |")
        print("|---|---|---|---|---|---|---|---|")
        for name in ("caster", "sai", "included"):
            e = col[name]
            alone = col.get(f"{name}_normals")
            classic = col.get(f"{name}_classic")
            cells = [f"{rms(e):.4f}", f"{np.max(np.abs(e)):.4f}", f"{rms(col[name + '_std']) / rms(e):.2f}",
                     f"{rms(alone):.4f}" if alone is not None else "-",
                     f"{np.max(np.abs(alone)):.4f}" if alone is not None else "-",
                     f"{rms(classic):.4f}" if classic is not None else "-",
                     f"{np.max(np.abs(classic)):.4f}" if classic is not None else "-"]
            print(f"| {name} | " + " | ".join(cells) + " |")
        print(f"\nkingpin offset (scrub radius) error: RMS {rms(col['offset_mm']):.1f} mm, max "
              f"{np.max(np.abs(col['offset_mm'])):.1f} mm ({len(rows)} wheels)")
    if turn_errors:
        e = np.abs(turn_errors)
        print(f"the faces' turns against the truth: RMS {np.sqrt(np.mean(e ** 2)):.4f} deg, median {np.median(e):.4f}, "
              f"max {e.max():.4f} ({len(e)} captures of front wheels)")
    print(f"refused or failed procedures: {len(failed)} of {args.n}" + "".join(f"\n  - {f}" for f in failed))
    if seconds:
        print(f"procedure's computing time (its {len(STEER_PLAN)} measurements and the fit; capture and operator "
              f"excluded): median {np.median(seconds):.2f} s")
    return 0


def _true_turns_deg(scenes, wheel: str) -> np.ndarray:
    """(K,) how far the wheel's face truly turned about its own axis at each scene since the last
    (deg), measured as the procedure does: from e1 of rim_pattern.ring_basis toward e2."""
    frames = [s.vehicle.wheel_frame_station(wheel)[1] for s in scenes]
    e1_ref = ring_basis(frames[-1][:, 2])[0]
    out = []
    for R in frames:
        f = R @ frames[-1].T @ e1_ref
        e1, e2 = ring_basis(R[:, 2])
        out.append(np.degrees(np.arctan2(f @ e2, f @ e1)))
    return np.array(out)


if __name__ == "__main__":
    sys.exit(main())
