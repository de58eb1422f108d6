"""The PLC simulator's side of a steering sweep (command 7): it watches the steer state and checks
the steering result (station/plc/master.py uses it).

While a steering sweep runs, :class:`SteerWatch` reads the steer registers (225..231) at every
poll: each new prompt starts a :class:`SteerStep` (its step checked: the next one, the same number
of steps, a target), each new live reading (``steer_readings`` moved) is kept with the step, and
the time in state steer is the technician's (not the PLC's timeout). Nothing is written: the
station leaves state steer by itself. :func:`check_steering` checks the steering registers of a
finished cycle, :func:`format_steering` prints them.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from station.plc import register_map as rm

STEER_STATE = rm.STATE_CODES["steer"]


@dataclass
class SteerStep:
    """One steer the station asked for (225..227), the live readings seen ((FL deg, FR deg,
    reached), None for a wheel not seen) and the seconds spent in state steer."""

    step: int
    steps: int
    target_deg: float
    readings: list = field(default_factory=list)
    seconds: float = 0.0

    @property
    def reached(self) -> bool:
        return any(r[2] for r in self.readings)

    def describe(self, most: int = 12) -> str:
        where = "straight ahead" if self.target_deg == 0 else \
            f"{abs(self.target_deg):g} deg {'left' if self.target_deg > 0 else 'right'}"
        shown = self.readings if len(self.readings) <= most else \
            [self.readings[round(i * (len(self.readings) - 1) / (most - 1))] for i in range(most)]
        live = " ".join("/".join("-" if a is None else f"{a:+.1f}" for a in r[:2]) for r in shown)
        end = "reached" if self.reached else "not seen reached"
        return (f"steer {self.step}/{self.steps}: {where}; live FL/FR: {live or '-'}; {end} after "
                f"{self.seconds:.2f} s ({len(self.readings)} readings seen)")


class SteerWatch:
    """Follows one cycle's steers through ``read(start, count)`` -> registers."""

    def __init__(self, read):
        self.read = read
        self.steps: list[SteerStep] = []
        self.problems: list[str] = []
        self._count = 0  # steer_readings last seen
        self._t = None  # when state steer was last seen

    def poll(self, state: int) -> dict:
        """Read the steer registers once (state ``state`` just read); returns them decoded."""
        lo, hi = rm.STEER_BLOCK[0], rm.STEER_STATUS_END
        b = rm.decode_block(self.read(lo, hi - lo), lo)
        now = time.perf_counter()
        step = b["steer_step"]
        if state == STEER_STATE and step:
            if not self.steps or self.steps[-1].step != step:
                self._new_step(b)
            if self._t is not None:
                self.steps[-1].seconds += now - self._t
            self._t = now
        else:  # not in steer (state steer with step 0: the steer ended between the two reads)
            self._t = None
        if self.steps and b["steer_readings"] != self._count and (step == self.steps[-1].step or b["steer_reached"]):
            self.steps[-1].readings.append((b["FL_steer_i16"], b["FR_steer_i16"], bool(b["steer_reached"])))
        self._count = b["steer_readings"]
        return b

    def _new_step(self, b: dict) -> None:
        step, steps, target = b["steer_step"], b["steer_steps"], b["steer_target_i16"]
        if step != len(self.steps) + 1 or not 1 <= step <= steps:
            self.problems.append(f"steer prompt step {step} of {steps} after {len(self.steps)} steers")
        if self.steps and steps != self.steps[-1].steps:
            self.problems.append(f"steer prompt: {steps} steps, earlier {self.steps[-1].steps}")
        if target is None:
            self.problems.append(f"steer {step}: no target (-32768)")
        self.steps.append(SteerStep(step, steps, target if target is not None else math.nan))

    @property
    def seconds(self) -> float:
        return sum(s.seconds for s in self.steps)


def steering_values(b: dict) -> dict[str, dict[str, float | None]]:
    """{FL, FR: {caster, sai, included_angle (deg, float32 copy), kingpin_offset_mm}} of a decoded
    steer block; None where NaN."""
    def v(x):
        return None if x is None or (isinstance(x, float) and math.isnan(x)) else x
    return {w: {**{k: v(b[f"{w}_{k}_f32"]) for k, _ in rm.STEERING_ANGLES},
                "kingpin_offset_mm": v(b[f"{w}_kingpin_offset_mm_f32"])} for w in rm.FRONT}


def check_steering(b: dict, steered: bool, done: bool) -> list[str]:
    """Problems with a finished cycle's steer block ``b``: the prompt and the live reading cleared;
    once done, ``steering_valid`` is 1 after a steering sweep (``steered``) and 0 otherwise, and each
    float32 agrees with its int16 copy (NaN with -32768)."""
    p = []
    if (b["steer_step"], b["steer_steps"], b["steer_reached"], b["steer_readings"]) != (0, 0, 0, 0) \
            or b["FL_steer_i16"] is not None or b["FR_steer_i16"] is not None:
        p.append("steer prompt or live reading not cleared at the cycle's end")
    if not done:
        return p
    if b["steering_valid"] != int(steered):
        p.append(f"steering_valid {b['steering_valid']} after a cycle {'with' if steered else 'without'} a sweep")
    values = steering_values(b)
    for w in rm.FRONT:
        for key in [k for k, _ in rm.STEERING_ANGLES] + ["kingpin_offset_mm"]:
            f32, i16 = values[w][key], b[f"{w}_{key}_i16"]
            if (f32 is None) != (i16 is None) or (f32 is None) == steered:
                p.append(f"{w} {key}: float32 {f32}, int16 {i16} in a cycle {'with' if steered else 'without'} a sweep")
            elif f32 is not None and abs(f32 - i16) > 0.0051:
                p.append(f"{w} {key}: float32 {f32:.4f} and int16 {i16:.2f} disagree")
    return p


def format_steering(values: dict) -> str:
    return "steering: " + "; ".join(
        f"{w} caster {v['caster']:+.2f} SAI {v['sai']:+.2f} included {v['included_angle']:+.2f} deg, kingpin offset "
        f"{v['kingpin_offset_mm']:+.1f} mm" if v["caster"] is not None else f"{w} -" for w, v in values.items())
