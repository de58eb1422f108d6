"""The technician's guide through the rolls of runout compensation: how far the car has rolled.

``station measure --compensate`` asks for the car to be rolled back and forward
(station/procedures/runout.py, ``ROLL_PLAN``). :class:`GuidedRolling` shows, several times a
second, a bar of how far the car has rolled toward the position asked for ("roll back
[########------] 9.1 of 15 cm") from the front cameras alone (the live loop's tracking detection
and 3-D fit, station/procedures/live_follow.py), and returns once the front wheels' centres stand
within ``tolerance_m`` of that position and have stood still for ``still_updates`` readings. The
roll is the mean travel of the front rims' centres seen along the station's y (forward +) since
the first reading; one front rim lost for a moment (shown) does not hold the car up. On the
simulated station its technician (drivers.context.Simulation) rolls the car when asked; at a
real station the technician does.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from station.errors import ProcedureError, RollNotReached
from station.procedures.live_follow import Approach, FollowedRims, wait_until_at

FRONT = ("FL", "FR")
BAR_CHARS = 20


class GuidedRolling:
    """An AlignmentOperator whose ``roll_car`` guides the technician to the position live."""

    def __init__(self, station, mover=None, show: Callable[[str], None] = print, tolerance_m: float = 0.02,
                 still_m: float = 0.002, still_updates: int = 3, timeout_s: float = 300.0):
        """station: an open station.cycle.Station; mover: who rolls the car when asked (the
        simulated technician), None for a person; show: a line of the display."""
        self.mover = mover
        self.show = show
        self.approach = Approach(tolerance_m, still_m, still_updates, timeout_s)
        self.rims = FollowedRims(station, FRONT)
        self.start: dict | None = None   # wheel -> its rim centre at the first reading (3,), station frame (m)
        self.position_m = 0.0            # where the car must stand now, from the start (+ forward)

    def steer(self, angle_deg: float) -> None:
        raise ProcedureError("the rolling guide does not steer the wheels")

    def roll_car(self, distance_m: float) -> None:
        if self.start is None:
            self.start = self._centres()
            if len(self.start) < len(FRONT):
                raise RollNotReached("the front rims cannot be followed where the car stands",
                                     hint="check the front cameras' view and measure again")
        begin, self.position_m = self.position_m, self.position_m + float(distance_m)
        way = "forward" if distance_m > 0 else "back"
        self.show(f"roll the car {way} by about {abs(distance_m) * 100:.3g} cm (push it slowly, steering straight, "
                  "then let it stand still)")
        if self.mover is not None:
            self.mover.roll_car(distance_m)

        def line(travel: float, values: dict, reached: bool) -> str:
            done = (travel - begin) / distance_m if distance_m else 1.0
            filled = int(round(np.clip(done, 0.0, 1.0) * BAR_CHARS))
            return (f"  roll {way} [{'#' * filled}{'-' * (BAR_CHARS - filled)}] "
                    f"{(travel - begin) * 100 * np.sign(distance_m):.1f} of {abs(distance_m) * 100:.3g} cm"
                    + ("   hold still: capturing" if reached else ""))

        def lost(wheels: list[str]) -> str:
            return (f"  {', '.join(wheels)}: rim not seen ({'; '.join(str(self.rims.why.get(w)) for w in wheels)}); "
                    "roll back toward the start a little")

        if not wait_until_at(self.position_m, self.travel, FRONT, self.approach, line, self.show, lost, needed=1):
            raise RollNotReached(f"the car did not stand {self.position_m * 100:+.3g} cm from where it started "
                                 f"within {self.approach.timeout_s:.0f} s",
                                 hint="roll the car as the bar shows, let it stand still, and measure again")

    def travel(self) -> dict[str, float]:
        """{wheel: how far its rim centre has moved forward (+) since the first reading (m)} of
        the front wheels seen now."""
        return {w: float(c[1] - self.start[w][1]) for w, c in self._centres().items()}

    def _centres(self) -> dict[str, np.ndarray]:
        """{wheel: rim centre (3,), station frame (m)} of the front wheels in one capture."""
        return {w: np.asarray(c.center_station, float) for w, c in self.rims.circles().items()}
