"""The person at the lift, as the procedures talk to them: small protocols.

``station calibrate`` asks an operator to put the box somewhere and waits until it is there
(:class:`Operator`); the alignment procedures ask them to roll the car or turn the steering
wheel (:class:`AlignmentOperator`). A technician at a terminal (:class:`TerminalOperator`, the
box), the live guides that show how far the car has rolled or the wheels are steered
(station/procedures/roll_guide.py, steer_guide.py), a PLC (station/plc/roll_operator.py) or the
simulated station's operator (drivers.context.Simulation: it moves the box, rolls the car,
steers) implement them; the procedures never ask which one they have.
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


class AlignmentOperator(Protocol):
    def roll_car(self, distance_m: float) -> None:
        """Roll the car forward (+) or back (-) along the runways by about ``distance_m``."""

    def steer(self, angle_deg: float) -> None:
        """Turn the steering wheel until the front wheels point about ``angle_deg`` left (+) or
        right (-) of straight ahead."""


class TerminalOperator:
    """The box calibration's prompts on the terminal; waits for Enter."""

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
