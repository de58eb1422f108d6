"""`station live`: toe and camber of one axle (or all wheels), updated continuously, vs the spec."""

from __future__ import annotations

import sys

from station.commands.arguments import job_id, seed
from station.config import load_config


def add_arguments(parser):
    parser.add_argument("--axle", choices=["front", "rear", "all"], default="front",
                        help="the wheels to follow (default front; all: the four wheels)")
    parser.add_argument("--vehicle", metavar="NAME", help="vehicle spec from config/vehicles.yaml: adds OK/ADJUST")
    parser.add_argument("--job", metavar="ID", type=job_id,
                        help="the job being adjusted: its runout kept by `station measure --compensate --job ID` "
                             "is applied (toe and camber of the spin axes)")
    parser.add_argument("--seconds", type=float, default=None, help="stop after S seconds (default: until Ctrl-C)")
    parser.add_argument("--seed", type=seed, default=1,
                        help="simulated station only: which random vehicle stands on the lift (default 1)")
    parser.add_argument("--cache", metavar="DIR",
                        help="simulated station only: where the pre-rendered adjustment frames are kept "
                             "(default DATA_DIR/live-cache)")
    parser.add_argument("--max-updates", type=int, default=None, help=argparse_suppress())


def argparse_suppress():
    import argparse
    return argparse.SUPPRESS


def run(args) -> int:
    from station.live import LiveSession, format_reading

    config = load_config(args.config)
    spec = None
    if args.vehicle:  # a typo in the vehicle name is found before the cameras are opened
        from station.records.vehicle_specs import get_spec, load_vehicle_specs
        spec = get_spec(load_vehicle_specs(config.vehicle_specs_path), args.vehicle, config.vehicle_specs_path)
    if args.seconds is not None and args.seconds <= 0:
        print(f"--seconds must be positive, not {args.seconds}", file=sys.stderr)
        return 2
    tty = sys.stdout.isatty()
    state = {"lines": 0}

    def show(reading):
        lines = format_reading(reading, spec, live_wheels=session.live_wheels)
        if tty:  # redraw in place
            up = f"\x1b[{state['lines']}F" if state["lines"] else ""
            sys.stdout.write(up + "".join(f"\x1b[2K{line}\n" for line in lines))
            sys.stdout.flush()
            state["lines"] = len(lines)
        else:
            print(" | ".join(lines[1:]), flush=True)

    try:
        with LiveSession(config, axle=args.axle, seed=args.seed, cache_dir=args.cache, job_id=args.job) as session:
            print(f"live {args.axle} axle: first a full measurement of all four wheels (the car frame)",
                  flush=True)
            for warning in session.baseline().warnings:  # they hold for every update that follows
                print(f"warning: {warning}", flush=True)
            print("toe and camber of the wheels' spin axes (the runout kept for this job)" if session.runout_compensated
                  else "toe and camber of the rim planes (runout not compensated)", flush=True)
            summary = session.run(args.seconds, show, max_updates=args.max_updates)
    except KeyboardInterrupt:  # during setup: nothing measured yet, nothing to lose
        print("stopped (Ctrl-C)", file=sys.stderr)
        return 130
    print(f"{summary['updates']} updates in {summary['elapsed_s']:.1f} s: {summary['rate_hz']:.1f} Hz "
          f"(median per update {_ms(summary['total_ms'])}: capture {_ms(summary['capture_ms'])}, "
          f"wheels {_ms(summary['wheels_ms'])}; work summed over the live wheels: detection "
          f"{_ms(summary['detect_ms'])}, 3-D {_ms(summary['reconstruct_ms'])})"
          + ("; stopped by Ctrl-C" if summary["interrupted"] else ""), flush=True)
    return 0


def _ms(v):
    return "-" if v is None else f"{v:.0f} ms"
