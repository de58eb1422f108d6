"""`station odometry DIR`: stereo visual odometry of a sequence (the paper's section 3.3).

Reads our simulated layout, KITTI's and its common variants (docs/odometry.md), runs the
paper's method and/or the robust variant, prints the trajectory and, when the truth is known
(``DIR/poses.txt`` or ``--truth FILE``), the errors against it per method: translation (eq. 49,
mean and final), drift, rotation and KITTI's segment errors. Writes each trajectory as a KITTI
pose file and, with ``--rerun``, a recording.
A simulated sequence to run it on: ``python -m simulators.odometry_scene DIR``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from station.errors import OdometryError


def add_arguments(parser) -> None:
    parser.add_argument("directory", metavar="DIR", help="sequence folder: image_0/ image_1/, "
                        "image_l/ image_r/ or left/ right/ (colour KITTI: image_2/ image_3/, "
                        "image_02/ image_03/) with calib.txt, or left/ right/ with stereo.json; "
                        "DIR/poses.txt, if there, is the truth")
    parser.add_argument("--method", choices=("paper", "robust", "both"), default="both",
                        help="the paper's method, the robust variant, or both (default)")
    parser.add_argument("--out", metavar="FILE", help="trajectory file (KITTI poses; .csv for "
                        "step,x,y,z); with both methods, _paper/_robust is added to the name "
                        "(default: DIR/trajectory_<method>.txt)")
    parser.add_argument("--rerun", metavar="FILE.rrd", help="also write a Rerun recording")
    parser.add_argument("--truth", "--poses", dest="truth", metavar="FILE",
                        help="ground-truth poses (KITTI format: one line of 12 numbers per image), "
                        "if not DIR/poses.txt; prints the errors against them")
    parser.add_argument("--max-steps", type=int, metavar="N", help="stop after N steps")
    parser.add_argument("--quiet", action="store_true", help="print the summary only")


def _out_paths(args, methods) -> dict[str, Path]:
    if args.out:
        out = Path(args.out)
        if len(methods) == 1:
            return {methods[0]: out}
        return {m: out.with_name(f"{out.stem}_{m}{out.suffix or '.txt'}") for m in methods}
    return {m: Path(args.directory) / f"trajectory_{m}.txt" for m in methods}


def run(args) -> int:
    from station.odometry.pipeline import run_odometry
    from station.odometry.sequence_io import open_sequence
    from station.odometry.truth_errors import compare

    if args.max_steps is not None and args.max_steps < 1:
        raise OdometryError(f"--max-steps must be at least 1, got {args.max_steps}")
    directory = Path(args.directory)
    seq = open_sequence(directory, args.truth)
    methods = ("paper", "robust") if args.method == "both" else (args.method,)
    span = "" if seq.times_s is None else f", {seq.times_s[-1] - seq.times_s[0]:.1f} s (times.txt)"
    print(f"{directory}: {len(seq)} stereo images ({seq.source}), {seq.left.width}x{seq.left.height}, "
          f"baseline {float(np.linalg.norm(seq.right.t_cam_station)):.3f} m{span}")
    for note in seq.notes:
        print(f"note: {note}")
    progress = None
    if sys.stderr.isatty():
        def progress(method, step, run):
            print(f"\r{method}: step {step}/{len(seq) - 1}", end="", file=sys.stderr, flush=True)
    runs = run_odometry(seq, methods, max_steps=args.max_steps, on_step=progress)
    if progress:
        print(file=sys.stderr)

    B_true = None if seq.truth is None else seq.truth[:, :3, 3]
    if not args.quiet:
        _print_table(runs, B_true)
    for m, r in runs.items():
        print(f"{m:>7}: {len(r.trajectory) - 1} steps")
    if seq.truth is not None:
        _print_truth_errors({m: compare(np.array(r.trajectory.poses), seq.truth) for m, r in runs.items()},
                            seq.truth_file)

    for m, path in _out_paths(args, methods).items():
        print(f"trajectory ({m}) -> {runs[m].trajectory.write(path)}")
    if args.rerun:
        from station.odometry.recording import write_recording
        print(f"recording -> {write_recording(args.rerun, seq, runs)}")
    errors = [r.error for r in runs.values() if r.error is not None]
    if errors:
        kept = ", ".join(f"{m}: {len(r.trajectory) - 1} steps" for m, r in runs.items())
        first = errors[0]
        raise OdometryError(f"{first} (trajectory kept up to the last good step: {kept})",
                            hint=first.hint)
    return 0


# (label, how to get the value from a TruthErrors, format)
TRUTH_ROWS = (
    ("steps compared", lambda e: e.translation.n_steps, "{:d}"),
    ("true path length (m)", lambda e: e.translation.distance_m, "{:.3f}"),
    ("mean translation error (m)", lambda e: e.translation.mean_m, "{:.4f}"),
    ("  std (m)", lambda e: e.translation.std_m, "{:.4f}"),
    ("  max (m)", lambda e: e.translation.max_m, "{:.4f}"),
    ("final translation error (m)", lambda e: e.translation.final_m, "{:.4f}"),
    ("drift: final error / path (%)", lambda e: e.translation.drift_pct, "{:.2f}"),
    ("  max over steps >= 1 m (%)", lambda e: e.translation.max_drift_pct, "{:.2f}"),
    ("mean rotation error (deg)", lambda e: e.rot_mean_deg, "{:.3f}"),
    ("final rotation error (deg)", lambda e: e.rot_final_deg, "{:.3f}"),
    ("segments: translation (%)", lambda e: e.segments.t_pct, "{:.2f}"),
    ("segments: rotation (deg/m)", lambda e: e.segments.r_deg_per_m, "{:.4f}"),
    ("segments compared", lambda e: e.segments.n_segments, "{:d}"),
)


def _print_truth_errors(errors: dict, truth_file) -> None:
    """The errors of each method against the truth, one column per method."""
    width = max(len(label) for label, _, _ in TRUTH_ROWS)
    print(f"errors against the truth ({truth_file}):")
    print(" " * width + "".join(f" {m:>10}" for m in errors))
    for label, get, fmt in TRUTH_ROWS:
        cells = []
        for e in errors.values():
            v = get(e)
            cells.append(f" {'-' if isinstance(v, float) and not np.isfinite(v) else fmt.format(v):>10}")
        print(f"{label:<{width}}" + "".join(cells))
    described = {}
    for m, e in errors.items():
        if e.segments.n_segments:
            described.setdefault(e.segments.lengths_m, (e.segments.kitti_lengths, []))[1].append(m)
    if not described:
        print("segments: none (too few images along the path)")
    for lengths, (kitti, names) in described.items():
        whose = f" ({', '.join(names)})" if len(described) > 1 else ""
        if kitti:
            print(f"segments{whose}: KITTI's, 100 to 800 m, from every 10th image")
        else:
            print(f"segments{whose}: {', '.join(f'{v:.2f}' for v in lengths)} m (10-80 % of the path; "
                  "KITTI's 100-800 m need a path of 100 m), from every image")


def _print_table(runs, B_true) -> None:
    head = f"{'step':>4}"
    if B_true is not None:
        head += f" {'true x':>8} {'y':>8} {'z':>8}"
    for m in runs:
        head += f" | {m + ' x':>9} {'y':>8} {'z':>8}" + (f" {'e (m)':>7}" if B_true is not None else "")
    print(head)
    n = max(len(r.trajectory) for r in runs.values())
    for i in range(n):
        row = f"{i:>4}"
        if B_true is not None:
            row += " ".join(f" {v:8.4f}" for v in B_true[i]) if i < len(B_true) else " " * 27
        for r in runs.values():
            B = r.trajectory.positions
            if i < len(B):
                row += " | " + " ".join(f"{v:9.4f}" if k == 0 else f"{v:8.4f}" for k, v in enumerate(B[i]))
                if B_true is not None and i < len(B_true):
                    row += f" {float(((B[i] - B_true[i]) ** 2).sum() ** 0.5):7.4f}"
            else:
                row += " | " + " " * 35
        print(row)
