"""`station measure`: one measurement cycle, a per-wheel table, optionally JSON."""

from __future__ import annotations

import argparse
import random
import sys

from calibration.station_frame import AXLES, WHEELS
from station.commands.arguments import job_id, seed
from station.config import load_config
from station.errors import StorageError, user_message
from station.result import Measurement

EXIT_MEASURED = 0
EXIT_FAILED = 1  # the cycle failed: no angle is valid
EXIT_ERROR = 2  # as station.cli: an error before or after the cycle (here: the --json file)
EXIT_NOT_KEPT = 4  # measured, printed and --json written; the data disk refused images, recording or history
EXIT_STATUS_HELP = """exit status:
  0  measured; the result is printed (and written to --json) and kept
  1  the measurement failed (no valid angle); the failure is printed (and kept
     unless a warning says the data disk refused it)
  2  an error: nothing measured, or the --json file could not be written
     (the result is still printed above the error)
  4  measured, printed and written to --json, but the data disk refused to keep
     part of the cycle (images, recording or history row: full, read-only):
     the warnings say which"""


def add_arguments(parser):
    parser.epilog = EXIT_STATUS_HELP
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--seed", type=seed, default=None,
                        help="simulated station only: which random vehicle stands on the lift (default: a new one)")
    parser.add_argument("--vehicle", metavar="NAME", help="vehicle spec from config/vehicles.yaml: adds pass/fail")
    parser.add_argument("--job", metavar="ID", type=job_id,
                        help="job id / VIN stored with the cycle (printable characters, no control characters)")
    parser.add_argument("--json", metavar="PATH", help="also write the result as JSON (docs/result-schema.md)")
    parser.add_argument("--method", choices=["circle", "paper"], default="circle",
                        help="3-D wheel: the refined 3-D circle fit (default) or the paper's section 3.2")
    parser.add_argument("--no-record", action="store_true", help="do not write a Rerun recording")
    parser.add_argument("--compensate", action="store_true",
                        help="runout compensation: the car is rolled about 15 cm back and forward while the "
                             "cameras watch; toe and camber are of the wheels' spin axes, and the runout is kept "
                             "with --job for its later measurements (docs/procedures.md)")


def run(args) -> int:
    from station.cycle import Station

    config = load_config(args.config)
    if args.vehicle:  # a typo in the vehicle name is found before the cameras are opened
        from station.records.vehicle_specs import get_spec, load_vehicle_specs
        get_spec(load_vehicle_specs(config.vehicle_specs_path), args.vehicle, config.vehicle_specs_path)
    seed = args.seed if args.seed is not None else random.randrange(1_000_000)
    with Station(config, seed=seed) as station:
        operator = None
        if args.compensate:  # the technician follows a live bar of the roll
            from station.procedures.roll_guide import GuidedRolling
            operator = GuidedRolling(station, mover=station.context.simulation, show=lambda line: print(line, flush=True))
        result = station.measure(job_id=args.job, vehicle_spec=args.vehicle, method=args.method,
                                 record=not args.no_record, compensate=operator)
    if result.truth is not None:
        result.simulation_seed = seed
    print_result(result)
    return written(result, args.json)


def written(result: Measurement, json_path: str | None) -> int:
    """The exit status of a cycle whose result was printed, after writing it to ``json_path``
    when given (EXIT_ERROR, the result still printed, when that file cannot be written)."""
    from station.cycle import write_json

    if json_path:
        try:
            write_json(result, json_path)
        except StorageError as e:
            print(user_message(e) + "\n  the result is printed above", file=sys.stderr)
            return EXIT_ERROR
        print(f"result written to {json_path}")
    return exit_status(result)


def exit_status(result: Measurement) -> int:
    """The exit status of a cycle whose result was printed (EXIT_STATUS_HELP)."""
    if not result.valid:
        return EXIT_FAILED
    return EXIT_NOT_KEPT if result.has_flag("not_kept") else EXIT_MEASURED


def _pm(value, std):
    return f"{value:+7.3f} +/- {std:.3f}"


def print_result(result: Measurement, out=sys.stdout) -> None:
    p = lambda *a: print(*a, file=out)  # noqa: E731
    p(f"cycle {result.cycle_id}  station {result.station}  calibration {result.calibration_id}"
      + (f"  simulated vehicle seed {result.simulation_seed}" if result.simulation_seed is not None else ""))
    if not result.valid:
        f = result.failure
        p(f"MEASUREMENT FAILED (error {f and f.code}): {f and f.message}")
        if f and f.hint:
            p(f"  what to do: {f.hint}")
        p("no angle of this cycle is valid.")
        if result.captures_dir:
            p(f"the images are kept for review in {result.captures_dir}")
        for w in result.warnings:
            p(f"warning: {w}")
        return
    spec = result.vehicle_spec
    verdicts = result.verdicts or {}
    sim = result.errors is not None
    head = f"{'wheel':<6}{'toe (deg)':>20}{'camber (deg)':>20}"
    if spec:
        head += f"{'toe':>7}{'camber':>8}"
    if sim:
        head += f"{'toe err':>10}{'camber err':>12}"
    p("toe and camber of the wheels' spin axes (runout compensated)" if result.runout_compensated
      else "toe and camber of the rim planes (runout not compensated: `station measure --compensate`)")
    p(head)
    for w in WHEELS:
        d = result.wheels[w]
        line = f"{w:<6}{_pm(d.toe_deg, d.toe_std_deg):>20}{_pm(d.camber_deg, d.camber_std_deg):>20}"
        if spec:
            line += f"{verdict_word(verdicts.get(f'{w}.toe')):>7}{verdict_word(verdicts.get(f'{w}.camber')):>8}"
        if sim:
            e = result.errors[w]
            line += f"{e['toe_error_deg']:>+10.4f}{e['camber_error_deg']:>+12.4f}"
        p(line)
    for axle in AXLES:
        a = result.axles[axle]
        verdict = f"  {verdict_word(verdicts.get(axle + '.total_toe'))}" if spec else ""
        p(f"{axle} total toe {_pm(a.total_toe_deg, a.total_toe_std_deg)} deg{verdict}   "
          f"setback {a.setback_m * 1000:+.1f} mm   track {a.track_m:.3f} m")
    verdict = f"  {verdict_word(verdicts.get('thrust'))}" if spec else ""
    p(f"thrust angle {_pm(result.thrust_deg, result.thrust_std_deg)} deg{verdict}   "
      f"wheelbase L {result.wheelbase_m['left']:.3f} m  R {result.wheelbase_m['right']:.3f} m")
    if result.runout_compensated:
        p("runout  " + "   ".join(f"{w} {result.wheels[w].runout_deg:.3f} deg at {result.wheels[w].runout_phase_deg:.0f} "
                                   f"({result.wheels[w].runout_mm:.2f} mm)" for w in WHEELS))
    if spec:
        p(f"vehicle {spec}: {'PASS' if verdicts.get('overall') else 'FAIL'}")
    for w in result.warnings:
        p(f"warning: {w}")
    p("time: " + ", ".join(f"{k} {v * 1000:.0f} ms" for k, v in result.timing_s.items()))
    if result.recording:
        p(f"recording: {result.recording}")


def verdict_word(v):
    return {True: "ok", False: "OUT", None: "-"}[v]
