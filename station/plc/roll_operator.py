"""The PLC as the operator who rolls the car: runout compensation (issue 32) driven over Modbus.

``station.cycle.Station.measure(compensate=operator)`` calls ``operator.roll_car(distance_m)``
between its captures (station/procedures/runout.py, ``ROLL_PLAN``) and expects it to return
once the car stands still at the new position. :class:`PlcRollOperator` is that operator for a
PLC-triggered cycle (command 5): each ``roll_car`` becomes a :class:`RollPrompt` handed to a
:class:`RollGate` - the PLC device, which publishes the prompt registers, enters state roll and
blocks the cycle's worker thread until the PLC writes in position (command 6), the roll
timeout passes or the server stops (both raise ``RollNotConfirmed``, code 415). On the simulated
station the confirmed roll then moves the simulated car ("the PLC's simulated conveyor").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from station.errors import ProcedureError


@dataclass(frozen=True)
class RollPrompt:
    """One roll the station asks for: the ``step``-th of ``steps``, ``distance_m`` now (+ forward,
    - back) to stand at ``position_m`` from where the car stood at the trigger."""

    step: int
    steps: int
    distance_m: float
    position_m: float

    @property
    def distance_mm(self) -> int:
        return round(self.distance_m * 1000)

    @property
    def position_mm(self) -> int:
        return round(self.position_m * 1000)

    def describe(self) -> str:
        way = "forward" if self.distance_m > 0 else "back"
        to = f"{self.position_mm:+d} mm" if self.position_mm else "the start"
        return f"roll {self.step}/{self.steps}: {way} {abs(self.distance_mm)} mm (to {to})"


class RollGate(Protocol):
    def roll(self, prompt: RollPrompt) -> None:
        """Ask the PLC for ``prompt`` and return once it confirms the car in position; raises
        RollNotConfirmed (the roll timeout, the server stopping) or another coded error."""


def roll_plan(distance_m: float | None = None) -> list[float]:
    """The signed distances (m) the compensated cycle asks for, in order: the steps between the
    positions of ``station.procedures.runout.ROLL_PLAN`` (imported here, not at the top: the
    dry run needs only these numbers, not the measurement pipeline at start-up)."""
    from station.procedures.runout import ROLL_DISTANCE_M, ROLL_PLAN

    d = ROLL_DISTANCE_M if distance_m is None else distance_m
    return [(b - a) * d for a, b in zip(ROLL_PLAN, ROLL_PLAN[1:])]


class PlcRollOperator:
    """``station.operator.AlignmentOperator`` whose rolls the PLC makes (through ``gate``).
    ``steps``: how many rolls the procedure makes (for the prompt); ``simulation``: the simulated
    station (drivers.context.Simulation), whose car is moved once the PLC has confirmed."""

    def __init__(self, gate: RollGate, steps: int, simulation=None):
        self.gate = gate
        self.steps = steps
        self.simulation = simulation
        self.step = 0
        self.position_m = 0.0
        self.prompts: list[RollPrompt] = []

    def roll_car(self, distance_m: float) -> None:
        self.step += 1
        self.position_m += float(distance_m)
        prompt = RollPrompt(self.step, max(self.steps, self.step), float(distance_m), self.position_m)
        self.prompts.append(prompt)
        self.gate.roll(prompt)
        if self.simulation is not None:
            self.simulation.roll_car(distance_m)

    def steer(self, angle_deg: float) -> None:
        raise ProcedureError(f"runout compensation does not steer the front wheels ({angle_deg:+.0f} deg asked)",
                             hint="the steering sweep is PLC command 7 (station/plc/steer_operator.py)")
