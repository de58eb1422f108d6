"""The dry run's steering sweep (``station serve --dry-run``, PLC command 7): synthetic front wheels
and a synthetic steering result, so a PLC programmer can commission the steer state without
cameras.

:class:`SyntheticSteering` stands in for ``station.procedures.steer_guide.GuidedSteering``: asked
for a target, its wheels turn there over ``RAMP_READINGS`` live readings (the inner wheel a little
more than the outer, as Ackermann steering does), then stand still for ``STILL_READINGS``; the
last reading reports them reached, and ``steer`` returns, as the guide does once the wheels stand
still at the target. :func:`synthetic_steering` is the caster, SAI, included angle and kingpin
offset the dry run reports: drawn from the job's random stream, so the same job always gets the
same values (a PLC simulator recomputes them), in the ranges of real cars.
"""

from __future__ import annotations

import random
import time
from typing import Callable

import numpy as np

from station.errors import SteerNotReached
from station.result import Steering, SteeringWheel

RAMP_READINGS = 8  # readings while the wheels turn to the target
STILL_READINGS = 3  # readings at the target, standing still (GuidedSteering's still_updates)
ACKERMANN_SHARE = 0.04  # the inner wheel steers this share more than the mean, the outer this share less
TOLERANCE_DEG = 1.0  # the mean within this of the target counts as there (GuidedSteering's tolerance_deg)


def wheel_angles(mean_deg: float) -> dict[str, float]:
    """{FL, FR: steer angle deg} for the wheels' mean steer ``mean_deg`` (left +): the inner wheel
    (FL in a left turn) steers more."""
    d = ACKERMANN_SHARE * abs(mean_deg)
    return {"FL": mean_deg + d, "FR": mean_deg - d}


class SyntheticSteering:
    """Front wheels that steer themselves to each target, reporting ``on_reading(target deg,
    {wheel: deg}, reached)`` every ``reading_s`` seconds. ``reach``: the share of each target they
    get to (below 1 a target off straight ahead is never reached: the steer times out);
    ``timeout_s``: as GuidedSteering's."""

    def __init__(self, on_reading: Callable[[float, dict, bool], None], reading_s: float = 0.1,
                 reach: float = 1.0, timeout_s: float = 300.0):
        self.on_reading = on_reading
        self.reading_s = reading_s
        self.reach = reach
        self.timeout_s = timeout_s
        self.mean_deg = 0.0  # where the wheels point now

    def steer(self, angle_deg: float) -> None:
        start, end = self.mean_deg, self.reach * float(angle_deg)
        at = abs(end - angle_deg) <= TOLERANCE_DEG
        path = np.linspace(start, end, RAMP_READINGS + 1)[1:]
        t0 = time.monotonic()
        k = 0
        while True:
            self.mean_deg = float(path[min(k, RAMP_READINGS - 1)])
            standing = k - (RAMP_READINGS - 1)  # readings at the end so far, less one
            reached = at and standing >= STILL_READINGS - 1
            self.on_reading(float(angle_deg), wheel_angles(self.mean_deg), reached)
            if reached:
                return
            if time.monotonic() - t0 > self.timeout_s:
                raise SteerNotReached(f"the wheels did not stand at {angle_deg:+g} deg within {self.timeout_s:.0f} s "
                                      "(dry run)")
            k += 1
            time.sleep(self.reading_s)


def synthetic_steering(rng: random.Random, camber_deg: dict[str, float], targets: list[float]) -> Steering:
    """A steering result for the sweep over ``targets`` (deg), each front wheel's values drawn from
    ``rng``: caster 2..7 deg, SAI 9..14 deg, the included angle their SAI + ``camber_deg``, a kingpin
    offset of -10..+60 mm; the steer angles those the synthetic wheels reached."""
    left, right = max(targets), min(targets)
    wheels = {}
    for w in ("FL", "FR"):
        caster, sai = round(rng.uniform(2.0, 7.0), 4), round(rng.uniform(9.0, 14.0), 4)
        offset_m = round(rng.uniform(-0.010, 0.060), 5)
        wheels[w] = SteeringWheel(
            caster_deg=caster, caster_std_deg=0.05, sai_deg=sai, sai_std_deg=0.05,
            included_angle_deg=round(sai + camber_deg[w], 4), included_angle_std_deg=0.06,
            kingpin_offset_m=offset_m, caster_trail_m=round(rng.uniform(0.0, 0.04), 5),
            caster_classic_deg=round(caster + rng.uniform(-0.3, 0.3), 4),
            caster_from_normals_deg=round(caster + rng.uniform(-0.1, 0.1), 4),
            sai_from_normals_deg=round(sai + rng.uniform(-1.0, 1.0), 4),
            steer_left_deg=wheel_angles(left)[w], steer_right_deg=wheel_angles(right)[w], misfit_deg=0.02)
    turns = {"left": {"inner_wheel": "FL", "inner_deg": abs(wheel_angles(left)["FL"]),
                      "outer_deg": abs(wheel_angles(left)["FR"])},
             "right": {"inner_wheel": "FR", "inner_deg": abs(wheel_angles(right)["FR"]),
                       "outer_deg": abs(wheel_angles(right)["FL"])}}
    return Steering(sweep_deg=float(left), wheels=wheels, toe_out_on_turns=turns)
