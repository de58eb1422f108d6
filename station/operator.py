"""Who places the calibration box: a tiny protocol the calibration flow talks to.

``station calibrate`` asks an operator to put the box somewhere and waits until it is there.
A technician at a terminal (:class:`TerminalOperator`) or the simulated operator
(simulators/sim_operator.py, which moves the box in the simulated world) implement it; the
flow never asks which one it has.
"""

from __future__ import annotations

import sys
from typing import Protocol


class Operator(Protocol):
    def place_box_for_intrinsics(self, cam_ids: list[str], pose_index: int) -> None:
        """Hold/put the box in front of ``cam_ids`` in a new pose (a different tilt/place)."""

    def place_box_at_fixture(self, wheel: str) -> None:
        """Put the box on the fixture of ``wheel`` (runway, bottom centre and yaw as configured)."""

    def done(self) -> None:
        """The calibration no longer needs the box."""


class TerminalOperator:
    """Prompts on the terminal and waits for Enter."""

    def __init__(self, stream_in=None, stream_out=None):
        self.inp = stream_in or sys.stdin
        self.out = stream_out or sys.stderr

    def _ask(self, text: str) -> None:
        print(f"{text} - press Enter when done", file=self.out, flush=True)
        self.inp.readline()

    def place_box_for_intrinsics(self, cam_ids: list[str], pose_index: int) -> None:
        tilt = "tilted" if pose_index % 2 else "turned"
        self._ask(f"pose {pose_index + 1}: hold the box in front of {', '.join(cam_ids)}, {tilt} differently "
                  "from before, showing two faces to both cameras, filling a different part of the image")

    def place_box_at_fixture(self, wheel: str) -> None:
        self._ask(f"put the box on the {wheel} fixture (stops against the runway pins)")

    def done(self) -> None:
        print("calibration images taken; remove the box", file=self.out, flush=True)
