"""How long the `station` command takes to answer --help, per command (wall time, median of N).

Every command imports only what it needs when it runs: `station --help` and a command's own
--help load neither numpy's BLAS threads, OpenCV, Rerun nor the measurement pipeline.

    .venv/bin/python bench/cli_startup.py [--repeat 7]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from station.cli import COMMANDS  # noqa: E402


def seconds(args: list[str], repeat: int) -> float:
    """Median wall time (s) of ``station <args>`` over ``repeat`` runs (one warm-up first)."""
    cmd = [sys.executable, "-m", "station.cli", *args]
    subprocess.run(cmd, capture_output=True, check=True, cwd=ROOT)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(cmd, capture_output=True, check=True, cwd=ROOT)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    print(f"| command | median wall time of --help (s), {args.repeat} runs |")
    print("|---|---|")
    print(f"| station --help | {seconds(['--help'], args.repeat):.3f} |")
    for name in COMMANDS:
        print(f"| station {name} --help | {seconds([name, '--help'], args.repeat):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
