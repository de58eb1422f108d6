"""Benchmark: the paper's visual odometry against the robust variant on simulated sequences.

    .venv/bin/python bench/odometry.py [--workdir DIR] [--skip-long] [--all-long] [--seed N]

Renders (once, cached in --workdir) the 11-step path like the paper's and the 243-step loop,
runs every variant with the same SIFT detections, and prints eq. 49's error (mean, std, max)
and the drift in % of the distance travelled. The paper reports mean 0.2488 m, std 0.1035 m
over 11 steps; the target for the robust variant is a mean <= 0.025 m and drift < 2 %.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

# Run as a script, Python puts bench/ first on the path, where bench/calibration.py would
# shadow the calibration package: the repository root goes first.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simulators.odometry_scene import write_sequence  # noqa: E402
from station.odometry.features import PAPER_MATCHING, MatchSettings  # noqa: E402
from station.odometry.pipeline import Variant, run_odometry  # noqa: E402
from station.odometry.robust_vo import RobustSettings  # noqa: E402
from station.odometry.sequence_io import open_sequence  # noqa: E402
from station.odometry.trajectory import summarize  # noqa: E402

VARIANTS = (
    Variant("paper", "paper", PAPER_MATCHING),
    Variant("paper estimator, filtered matches", "paper", MatchSettings()),
    Variant("robust, no refinement", "robust", MatchSettings(), RobustSettings(refine=False)),
    Variant("robust", "robust", MatchSettings()),
)


def _sequence(workdir: Path, kind: str, seed: int) -> Path:
    d = workdir / f"{kind}-seed{seed}"
    if not (d / "sequence.json").is_file():
        t0 = time.perf_counter()
        write_sequence(d, kind, seed=seed)
        n = len(list((d / "left").iterdir()))
        dt = time.perf_counter() - t0
        print(f"rendered {kind}: {n} stereo pairs in {dt:.1f} s ({dt / n:.2f} s per pair)")
    return d


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", default="/tmp/station-odometry-bench")
    ap.add_argument("--skip-long", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--all-long", action="store_true",
                    help="every variant on the long path too (default: the paper's and the robust one)")
    args = ap.parse_args()
    workdir = Path(args.workdir)
    kinds = ("short",) if args.skip_long else ("short", "long")
    rows = []
    for kind in kinds:
        seq = open_sequence(_sequence(workdir, kind, args.seed))
        t0 = time.perf_counter()
        variants = VARIANTS if kind == "short" or args.all_long else (VARIANTS[0], VARIANTS[-1])
        runs = run_odometry(seq, variants)
        dt = time.perf_counter() - t0
        print(f"{kind}: {len(seq) - 1} steps, all variants in {dt:.1f} s ({dt / (len(seq) - 1):.2f} s per step)")
        for name, run in runs.items():
            s = summarize(run.trajectory.positions, seq.truth[:, :3, 3])
            inl = [st.n_used / max(st.n_common, 1) for st in run.steps]
            common = sum(st.n_common for st in run.steps) / max(len(run.steps), 1)
            rows.append((kind, name, s, common, sum(inl) / max(len(inl), 1),
                         "" if run.error is None else f"failed: {run.error}"))
    print()
    print("| path | method | steps | mean e (m) | std (m) | max (m) | distance (m) | drift (%) | max drift (%) | common kp/step | kept |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for kind, name, s, common, kept, note in rows:
        print(f"| {kind} | {name} | {s.n_steps} | {s.mean_m:.4f} | {s.std_m:.4f} | {s.max_m:.4f} | "
              f"{s.distance_m:.2f} | {s.drift_pct:.2f} | {s.max_drift_pct:.2f} | {common:.0f} | "
              f"{100 * kept:.0f} % {note}|")
    print("| (paper, reported) | paper | 11 | 0.2488 | 0.1035 | | | | | | |")


if __name__ == "__main__":
    main()
