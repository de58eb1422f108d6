"""Following wheels live while the technician moves the car: the guides' shared parts.

The guides of the procedures (steer_guide.py: the front wheels' steer angle; roll_guide.py: how
far the car has rolled) read the wheels several times a second with the live loop's tracking
detection and 3-D fit (station/live.py) and wait until the reading stands at a target:
:class:`FollowedRims` captures the wheels' cameras once and returns each wheel's 3-D rim circle;
:func:`wait_until_at` shows each reading and returns once the mean over the wheels is within a
tolerance of the target and has stood still for a few readings.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from station.capture.sync import capture_cycle
from station.errors import StationError
from station.live import live_wheel
from station.rim.camera_response import linear_images


class FollowedRims:
    """The rims of ``wheels`` followed from capture to capture (each camera's detection seeds the
    next search; a wheel that failed searches both whole images next time)."""

    def __init__(self, station, wheels: tuple[str, ...]):
        """station: an open station.cycle.Station."""
        self.station = station
        self.wheels = wheels
        cfg = station.config
        self.pairs = {w: (cfg.pairs[w].precision, cfg.pairs[w].reference) for w in wheels}
        self.cams = [c for w in wheels for c in self.pairs[w]]
        self.previous: dict = {}
        self.why: dict = {}  # wheel -> why it was not seen in the last capture (None: seen)

    def circles(self) -> dict:
        """{wheel: its rim's 3-D circle (``center_station`` (3,), ``axis_station`` (3,))} of the
        wheels seen in one capture of their cameras."""
        st = self.station
        frames = capture_cycle({c: st.cameras[c] for c in self.cams}, st.timeout_s, st.trigger_board)
        images = linear_images({c: frames[c].image for c in self.cams}, st.config)
        out = {}
        for w in self.wheels:
            cams = self.pairs[w]
            got = live_wheel(w, cams, {c: images[c] for c in cams}, {c: st.models[c] for c in cams},
                             {c: self.previous.get(c) for c in cams}, st.config)
            for c, d in got.detections.items():
                if isinstance(d, StationError) or got.error is not None:
                    self.previous.pop(c, None)
                else:
                    self.previous[c] = d
            if got.error is None:
                out[w] = got.observation.circle
            self.why[w] = got.error
        return out


@dataclass(frozen=True)
class Approach:
    """When a reading counts as standing at its target: within ``tolerance`` of it, and moving
    less than ``still`` over the last ``still_updates`` readings; ``timeout_s`` to get there."""

    tolerance: float
    still: float
    still_updates: int = 3
    timeout_s: float = 300.0


def wait_until_at(target: float, read: Callable[[], dict[str, float]], wheels: tuple[str, ...], approach: Approach,
                  line: Callable[[float, dict[str, float], bool], str], show: Callable[[str], None],
                  lost: Callable[[list[str]], str], on_reading: Callable | None = None,
                  needed: int | None = None) -> bool:
    """Read until the mean over ``wheels`` of ``read()`` ({wheel: value}) stands at ``target``;
    each reading is shown (``line(mean, values, reached)``) and handed to ``on_reading(target,
    values, reached)`` (which may raise to end the wait); a reading that misses a wheel shows
    ``lost(wheels missed)`` and is handed on without that wheel. ``needed`` wheels (all unless
    told) must be seen for a reading to count; the mean is then over those seen (one wheel
    tells how far a rigid car rolled). Returns True when reached, False when
    ``approach.timeout_s`` passed first."""
    t0, recent = time.monotonic(), []
    needed = len(wheels) if needed is None else needed
    while time.monotonic() - t0 < approach.timeout_s:
        values = read()
        missed = [w for w in wheels if w not in values]
        if missed:
            show(lost(missed))
        seen = [w for w in wheels if w in values]
        if len(seen) < needed:
            recent = []
            if on_reading is not None:  # the wheels seen (a PLC shows "no value" for the others)
                on_reading(target, values, False)
            continue
        mean = float(np.mean([values[w] for w in seen]))
        recent = (recent + [mean])[-approach.still_updates:]
        still = len(recent) == approach.still_updates and np.ptp(recent) <= approach.still
        reached = abs(mean - target) <= approach.tolerance and still
        show(line(mean, values, reached))
        if on_reading is not None:
            on_reading(target, values, reached)
        if reached:
            return True
    return False
