"""The technician's guide through a steering sweep: the front wheels' live steer angle.

``station caster`` asks for the wheels to be steered to a target and waits until they stand
there: :class:`GuidedSteering` shows, several times a second, how far the front wheels are
steered ("steer left: 8.7 of 10.0 deg") from the front cameras alone (the live loop's tracking
detection and 3-D fit, station/live.py), and returns once the mean of both wheels is within
``tolerance_deg`` of the target and has stood still for ``still_updates`` readings. The steer
angle is the turn of each wheel's rim normal about the station's up since the first reading
(straight ahead), left +. On the simulated station its technician (drivers.context.Simulation)
turns the steering wheel when asked; at a real station the technician does.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from station.capture.sync import capture_cycle
from station.errors import ProcedureError, StationError, SteerNotReached
from station.live import live_wheel
from station.rim.camera_response import linear_images

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
        self.station = station
        self.mover = mover
        self.show = show
        self.tolerance_deg = tolerance_deg
        self.still_deg = still_deg
        self.still_updates = still_updates
        self.timeout_s = timeout_s
        self.on_reading = on_reading
        cfg = station.config
        self.pairs = {w: (cfg.pairs[w].precision, cfg.pairs[w].reference) for w in FRONT}
        self.cams = [c for w in FRONT for c in self.pairs[w]]
        self.previous: dict = {}
        self.reference: dict | None = None   # wheel -> its rim normal straight ahead (3,)
        self.why: dict = {}                  # wheel -> why it was not seen in the last reading

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
        t0, recent = time.monotonic(), []
        while time.monotonic() - t0 < self.timeout_s:
            angles = self.steer_angles()
            if len(angles) < 2:
                lost = sorted(set(FRONT) - set(angles))
                self.show(f"  {', '.join(lost)}: rim not seen ({'; '.join(str(self.why.get(w)) for w in lost)}); "
                          "steer back a little")
                recent = []
                if self.on_reading is not None:  # the wheels seen, for a PLC (a lost one left out)
                    self.on_reading(angle_deg, angles, False)
                continue
            mean = float(np.mean(list(angles.values())))
            recent = (recent + [mean])[-self.still_updates:]
            still = len(recent) == self.still_updates and np.ptp(recent) <= self.still_deg
            at = abs(mean - angle_deg) <= self.tolerance_deg
            self.show(f"  {where}: {abs(mean):.1f} of {abs(angle_deg):g} deg   "
                      + "   ".join(f"{w} {angles[w]:+.1f}" for w in FRONT)
                      + ("   hold still: capturing" if at and still else ""))
            if self.on_reading is not None:
                self.on_reading(angle_deg, angles, at and still)
            if at and still:
                return
        raise SteerNotReached(f"the wheels did not stand at {angle_deg:+g} deg within {self.timeout_s:.0f} s",
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
        st = self.station
        frames = capture_cycle({c: st.cameras[c] for c in self.cams}, st.timeout_s, st.trigger_board)
        images = linear_images({c: frames[c].image for c in self.cams}, st.config)
        out = {}
        for w in FRONT:
            cams = self.pairs[w]
            got = live_wheel(w, cams, {c: images[c] for c in cams}, {c: st.models[c] for c in cams},
                             {c: self.previous.get(c) for c in cams}, st.config)
            for c, d in got.detections.items():  # a wheel that failed searches both whole images next time
                if isinstance(d, StationError) or got.error is not None:
                    self.previous.pop(c, None)
                else:
                    self.previous[c] = d
            if got.error is None:
                out[w] = np.asarray(got.observation.circle.axis_station, float)
            self.why[w] = got.error
        return out
