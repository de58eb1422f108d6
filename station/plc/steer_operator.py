"""The PLC's view of a steering sweep (issue 33): caster, SAI and included angle over Modbus.

``station.cycle.Station.caster(operator)`` calls ``operator.steer(angle_deg)`` for each target of
``station.procedures.steering.STEER_PLAN`` and expects it to return once the front wheels stand
there. Nobody at the PLC turns the steering wheel: a technician does, guided by the station
(station/procedures/steer_guide.py, ``GuidedSteering``), which follows the front rims live and
returns once both wheels stand still at the target. :class:`PlcSteerOperator` is that guide seen
by the PLC: each ``steer`` becomes a :class:`SteerPrompt` handed to a :class:`SteerGate` - the PLC
device, which publishes the prompt registers and enters state steer; every live reading of the
guide (its ``on_reading``) is handed on to the live steer registers; once the guide returns the
gate leaves state steer. The PLC confirms nothing. A steer not reached within the gate's
``timeout_s`` (``plc.steer_timeout_s``) raises ``SteerNotReached`` (424) at the guide's next
reading; so does the server stopping.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

from station.errors import ProcedureError


@dataclass(frozen=True)
class SteerPrompt:
    """One steer the station asks for: the ``step``-th of ``steps``, the front wheels to point
    ``target_deg`` left (+) or right (-) of straight ahead."""

    step: int
    steps: int
    target_deg: float

    def describe(self) -> str:
        where = ("straight ahead" if self.target_deg == 0
                 else f"{abs(self.target_deg):g} deg {'left' if self.target_deg > 0 else 'right'}")
        return f"steer {self.step}/{self.steps}: {where}"


class SteerGate(Protocol):
    timeout_s: float  # how long a steer may take (plc.steer_timeout_s)

    def begin(self, prompt: SteerPrompt) -> None:
        """Publish ``prompt`` and enter state steer; raises SteerNotReached when the PLC cannot be
        asked now (a cycle abandoned after its timeout, the server stopped)."""

    def reading(self, angles: dict[str, float], reached: bool) -> None:
        """A live reading of the running steer ({wheel: steer angle deg}, a wheel not seen left out);
        raises SteerNotReached once the steer timed out or the server stopped."""

    def end(self, error: BaseException | None = None) -> None:
        """The running steer is over: reached (``error`` None) or given up (``error``): leave state steer."""


class SteerGuide(Protocol):
    """What steers the wheels and watches them (``GuidedSteering``, the dry run's synthetic wheels):
    ``steer`` returns once they stand still at the target, reporting each reading to the
    ``on_reading(target_deg, {wheel: deg}, reached)`` it was made with."""

    def steer(self, angle_deg: float) -> None: ...


MakeGuide = Callable[[Callable[[float, dict, bool], None]], SteerGuide]


def steer_plan(sweep_deg: float | None = None) -> list[float]:
    """The steer targets (deg, left +) a steering sweep asks for, in order: the positions of
    ``station.procedures.steering.STEER_PLAN`` after the first (straight ahead, captured where the
    wheels stand), times the sweep (imported here, not at the top: the dry run needs only these
    numbers, not the measurement pipeline at start-up)."""
    from station.procedures.steering import DEFAULT_SWEEP_DEG, STEER_PLAN

    sweep = DEFAULT_SWEEP_DEG if sweep_deg is None else sweep_deg
    return [p * sweep for p in STEER_PLAN[1:]]


class PlcSteerOperator:
    """``station.operator.AlignmentOperator`` whose steers the PLC sees (through ``gate``):
    ``make_guide(on_reading)`` builds the guide that steers and watches the wheels; ``steps``:
    how many steers the sweep asks for (for the prompt)."""

    def __init__(self, gate: SteerGate, steps: int, make_guide: MakeGuide):
        self.gate = gate
        self.steps = steps
        self.step = 0
        self.prompts: list[SteerPrompt] = []
        self.guide = make_guide(self._on_reading)

    def steer(self, angle_deg: float) -> None:
        self.step += 1
        prompt = SteerPrompt(self.step, max(self.steps, self.step), float(angle_deg))
        self.prompts.append(prompt)
        self.gate.begin(prompt)
        try:
            self.guide.steer(angle_deg)
        except BaseException as e:
            self.gate.end(e)
            raise
        self.gate.end(None)

    def _on_reading(self, target_deg: float, angles: dict[str, float], reached: bool) -> None:
        self.gate.reading(angles, reached)

    def roll_car(self, distance_m: float) -> None:
        raise ProcedureError(f"a steering sweep does not roll the car ({distance_m * 1000:+.0f} mm asked)",
                             hint="runout compensation is PLC command 5")
