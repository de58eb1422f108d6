"""The technician's guide through a steering sweep: the front wheels' live steer angle.

``station caster`` asks for the wheels to be steered to a target and waits until they stand
there: :class:`GuidedSteering` shows, several times a second, how far the front wheels are
steered ("steer left: 8.7 of 10.0 deg") from the front cameras alone (the live loop's tracking
detection and 3-D fit, station/live.py), and returns once the mean of both wheels is within
``tolerance_deg`` of the target and has stood still for ``still_updates`` readings
(station/procedures/live_follow.py). The steer angle is the turn of each wheel's rim normal
about the station's up since the first reading (straight ahead), left +. On the simulated
station its technician (drivers.context.Simulation) turns the steering wheel when asked; at a
real station the technician does.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from station.errors import ProcedureError, SteerNotReached
from station.procedures.live_follow import Approach, FollowedRims, wait_until_at

FRONT = ("FL", "FR")


class GuidedSteering:
    """An AlignmentOperator whose ``steer`` guides the technician to the target live."""

    def __init__(self, station, mover=None, show: Callable[[str], None] = print, tolerance_deg: float = 1.0,
                 still_deg: float = 0.1, still_updates: int = 3, timeout_s: float = 300.0,
                 on_reading: Callable[[float, dict[str, float], bool], None] | None = None):
        """station: an open station.cycle.Station; mover: who turns the steering wheel when
        asked (the simulated technician), None for a person; show: a line of the display;
        on_reading(target deg, {wheel: steer angle deg}, reached): each reading, for a PLC (a wheel
        whose rim was not seen is left out); it may raise to end the steer (a PLC's timeout)."""
        self.mover = mover
        self.show = show
        self.approach = Approach(tolerance_deg, still_deg, still_updates, timeout_s)
        self.on_reading = on_reading
        self.rims = FollowedRims(station, FRONT)
        self.reference: dict | None = None   # wheel -> its rim normal straight ahead (3,)

    def roll_car(self, distance_m: float) -> None:
        raise ProcedureError("the steering guide does not roll the car")

    def steer(self, angle_deg: float) -> None:
        if self.reference is None:
            self.reference = self._normals()
            if len(self.reference) < 2:
                raise SteerNotReached("the front rims cannot be followed straight ahead",
                                      hint="check the front cameras' view and measure again")
        where = "straight ahead" if angle_deg == 0 else f"{'left' if angle_deg > 0 else 'right'}"
        self.show(f"steer {where}" + ("" if angle_deg == 0 else f" to {abs(angle_deg):g} deg")
                  + ", then hold the steering wheel still")
        if self.mover is not None:
            self.mover.steer(angle_deg)

        def line(mean: float, angles: dict, reached: bool) -> str:
            return (f"  {where}: {abs(mean):.1f} of {abs(angle_deg):g} deg   "
                    + "   ".join(f"{w} {angles[w]:+.1f}" for w in FRONT) + ("   hold still: capturing" if reached else ""))

        def lost(wheels: list[str]) -> str:
            return (f"  {', '.join(wheels)}: rim not seen ({'; '.join(str(self.rims.why.get(w)) for w in wheels)}); "
                    "steer back a little")

        if not wait_until_at(angle_deg, self.steer_angles, FRONT, self.approach, line, self.show, lost,
                             self.on_reading):
            raise SteerNotReached(f"the wheels did not stand at {angle_deg:+g} deg within "
                                  f"{self.approach.timeout_s:.0f} s",
                                  hint="steer to the target shown, hold the steering wheel still, and measure again")

    def steer_angles(self) -> dict[str, float]:
        """{wheel: steer angle (deg, left +)} of the front wheels seen now."""
        now = self._normals()
        out = {}
        for w, n in now.items():
            a, b = self.reference[w][:2], n[:2]
            out[w] = float(np.degrees(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b)))
        return out

    def _normals(self) -> dict[str, np.ndarray]:
        """{wheel: rim normal (3,)} of the front wheels in one capture of their cameras."""
        return {w: np.asarray(c.axis_station, float) for w, c in self.rims.circles().items()}
