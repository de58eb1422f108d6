"""Soak and fault bench: what the station does when things go wrong, in one table.

Each section (its own module) provokes one kind of fault many times and counts the outcomes:

* bench/faults_plc.py - Modbus TCP: pipelined and back-to-back requests, garbage, malformed and
  unknown requests, connection floods, read-only clients;
* bench/faults_processes.py - kill -9 of ``station measure`` and ``station serve`` at random
  moments (processes and memory left behind), a full and a read-only data disk;
* bench/faults_inputs.py - corrupt calibrations, configurations and images, hostile job ids.

    .venv/bin/python bench/faults.py                 # every section
    .venv/bin/python bench/faults.py --only plc --tries 200

A row: ``tries`` how often the fault was provoked; ``correct`` handled as specified (answered
right, refused with a clear message and exit code, the result kept with a warning); ``lost``
nothing came back where something must (an unanswered request, a result not printed or kept);
``wrong`` something wrong came back (another request's transaction id, wrong data, a
traceback, an internal error); ``procs left`` / ``MiB left``: processes the fault left running
afterwards and their resident memory. Everything but ``tries`` and ``correct`` should be 0.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

SECTIONS = {"plc": "bench.faults_plc", "processes": "bench.faults_processes", "inputs": "bench.faults_inputs"}


@dataclass
class FaultRow:
    fault: str
    tries: int
    correct: int = 0
    lost: int = 0
    wrong: int = 0
    procs_left: int = 0
    mib_left: float = 0.0

    def markdown(self) -> str:
        return (f"| {self.fault} | {self.tries} | {self.correct} | {self.lost} | {self.wrong} | "
                f"{self.procs_left} | {self.mib_left:.0f} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", choices=list(SECTIONS), action="append",
                    help="run only this section (repeatable; default: all)")
    ap.add_argument("--tries", type=int, default=None, help="tries per fault (default: each section's own)")
    args = ap.parse_args()
    rows: list[FaultRow] = []
    for name in args.only or SECTIONS:
        module = importlib.import_module(SECTIONS[name])
        print(f"running {name} ...", file=sys.stderr, flush=True)
        rows += module.rows(args.tries)
    print("| fault | tries | correct | lost | wrong | procs left | MiB left |")
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        print(row.markdown())
    bad = [r for r in rows if r.lost or r.wrong or r.procs_left or r.correct != r.tries]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
