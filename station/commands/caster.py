"""`station caster`: caster, SAI and included angle of the front wheels from a steering sweep."""

from __future__ import annotations

import argparse
import random
import sys

from station.commands.arguments import job_id, seed
from station.config import load_config


def add_arguments(parser):
    from station.commands.measure import EXIT_STATUS_HELP

    parser.epilog = EXIT_STATUS_HELP
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--sweep", type=float, default=None, metavar="DEG",
                        help="how far to steer each way (default 10: as far as the built-in station's cameras "
                             "follow every rim; 20 gives toe-out on turns where the view allows)")
    parser.add_argument("--seed", type=seed, default=None,
                        help="simulated station only: which random vehicle stands on the lift (default: a new one)")
    parser.add_argument("--vehicle", metavar="NAME", help="vehicle spec from config/vehicles.yaml: adds pass/fail")
    parser.add_argument("--job", metavar="ID", type=job_id,
                        help="job id / VIN stored with the cycle (its kept runout is applied to toe and camber)")
    parser.add_argument("--json", metavar="PATH", help="also write the result as JSON (docs/result-schema.md)")
    parser.add_argument("--no-record", action="store_true", help="do not write a Rerun recording")


def run(args) -> int:
    from station.commands.measure import EXIT_ERROR, print_result, written
    from station.cycle import Station
    from station.procedures.steer_guide import GuidedSteering
    from station.procedures.steering import DEFAULT_SWEEP_DEG, MIN_SWEEP_DEG

    config = load_config(args.config)
    sweep = DEFAULT_SWEEP_DEG if args.sweep is None else args.sweep
    if not MIN_SWEEP_DEG <= sweep <= 30:
        print(f"--sweep {sweep:g}: expected {MIN_SWEEP_DEG:g} to 30 deg each way", file=sys.stderr)
        return EXIT_ERROR
    if args.vehicle:
        from station.records.vehicle_specs import get_spec, load_vehicle_specs
        get_spec(load_vehicle_specs(config.vehicle_specs_path), args.vehicle, config.vehicle_specs_path)
    vehicle_seed = args.seed if args.seed is not None else random.randrange(1_000_000)
    with Station(config, seed=vehicle_seed) as station:
        guide = GuidedSteering(station, mover=station.context.simulation, show=lambda line: print(line, flush=True))
        result = station.caster(guide, sweep_deg=sweep, job_id=args.job, vehicle_spec=args.vehicle,
                                record=not args.no_record)
    if result.truth is not None:
        result.simulation_seed = vehicle_seed
    print_result(result)
    if result.valid and result.steering is not None:
        print_steering(result)
    return written(result, args.json)


def print_steering(result, out=sys.stdout) -> None:
    """The steering table of a result with ``steering`` (with a vehicle spec, each angle's
    ok / OUT / - against it)."""
    from station.commands.measure import verdict_word
    s = result.steering
    p = lambda *a: print(*a, file=out)  # noqa: E731
    errors = result.errors or {}
    p(f"steering geometry (steered {s.sweep_deg:g} deg each way){'':8}{'FL':>18}{'FR':>18}")
    rows = [("caster (deg)", "caster_deg", "caster_std_deg"), ("SAI (deg)", "sai_deg", "sai_std_deg"),
            ("included angle (deg)", "included_angle_deg", "included_angle_std_deg")]
    verdicts = result.verdicts
    for label, key, std in rows:
        name = key.removesuffix("_deg")
        p(f"  {label:<48}" + "".join(f"{getattr(s.wheels[w], key):+9.2f} +/- {getattr(s.wheels[w], std):.2f}"
                                       for w in ("FL", "FR"))
          + ("   " + " ".join(f"{verdict_word(verdicts.get(f'{w}.{name}')):>3}" for w in ("FL", "FR")) if verdicts else "")
          + ("   error " + " ".join(f"{errors[w].get(key.replace('_deg', '_error_deg'), float('nan')):+.3f}"
                                    for w in ("FL", "FR")) if errors else ""))
    p(f"  {'kingpin offset at the runway (mm, + inboard)':<48}"
      + "".join(f"{s.wheels[w].kingpin_offset_m * 1000:+18.1f}" for w in ("FL", "FR")))
    p(f"  {'caster by the shops rule (camber change; deg)':<48}"
      + "".join(f"{s.wheels[w].caster_classic_deg:+18.2f}" for w in ("FL", "FR")))
    p(f"  {'steered left / right (deg)':<48}"
      + "".join(f"{s.wheels[w].steer_left_deg:+9.1f} / {s.wheels[w].steer_right_deg:+.1f}" for w in ("FL", "FR")))
    if not result.runout_compensated:
        p("  the included angle takes the rim plane's camber: compensate runout first (`station measure "
          "--compensate --job ID`, then `station caster --job ID`)")
    for side, t in s.toe_out_on_turns.items():
        outer = "FR" if t["inner_wheel"] == "FL" else "FL"
        p(f"  toe-out on turns, {side} turn: inner {t['inner_wheel']} {t['inner_deg']:.1f} deg, outer {outer} "
          f"{t['outer_deg']:.1f} deg ({t['inner_deg'] - t['outer_deg']:+.1f})")
