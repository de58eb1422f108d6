"""The live guides of the procedures (rolling, steering): the bar, standing still, the timeout.

The wheels' readings are scripted (a stand-in for station/procedures/live_follow.FollowedRims);
tests/test_steering.py and tests/test_runout_cycle.py run the guides on the simulated station.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from station.errors import RollNotReached, SteerNotReached
from station.procedures.live_follow import Approach, wait_until_at
from station.procedures.roll_guide import GuidedRolling
from station.procedures.steer_guide import GuidedSteering


class ScriptedRims:
    """Each call of ``circles`` gives the next of ``readings`` ({wheel: (centre y m, heading deg)}),
    repeating the last; a wheel left out is not seen."""

    def __init__(self, readings):
        self.readings = list(readings)
        self.why = {}
        self.calls = 0

    def circles(self):
        r = self.readings[min(self.calls, len(self.readings) - 1)]
        self.calls += 1
        self.why = {w: "cam3: no closed rim contour" for w in ("FL", "FR") if w not in r}
        out = {}
        for w, (y, heading) in r.items():
            h = np.radians(heading)
            side = -1.0 if w == "FL" else 1.0
            out[w] = SimpleNamespace(center_station=np.array([side * 0.78, 1.35 + y, 0.33]),
                                     axis_station=np.array([side * np.cos(h), side * np.sin(h), 0.0]))
        return out


# a station as far as the guides look at it before their first reading: the front pairs' cameras
STATION = SimpleNamespace(config=SimpleNamespace(pairs={w: SimpleNamespace(precision=f"{w}p", reference=f"{w}r")
                                                        for w in ("FL", "FR")}))


def rolling(readings, timeout_s=5.0):
    shown = []
    g = GuidedRolling(STATION, show=shown.append, timeout_s=timeout_s)
    g.rims = ScriptedRims(readings)
    return g, shown


def steering(readings, timeout_s=5.0):
    shown = []
    g = GuidedSteering(STATION, show=shown.append, timeout_s=timeout_s)
    g.rims = ScriptedRims(readings)
    return g, shown


def both(y, heading=0.0):
    return {"FL": (y, heading), "FR": (y, heading)}


def test_the_roll_bar_fills_and_the_capture_waits_until_the_car_stands_still():
    # start, then the car rolls back in steps, overshoots a little, and settles at -15.5 cm
    readings = [both(0.0), both(-0.03), both(-0.08), both(-0.13), both(-0.16), both(-0.155), both(-0.155),
                both(-0.155)]
    g, shown = rolling(readings)
    g.roll_car(-0.15)
    bars = [s for s in shown if s.startswith("  roll back [")]
    assert bars[0] == "  roll back [####----------------] 3.0 of 15 cm"
    assert bars[1].startswith("  roll back [###########---------] 8.0 of 15 cm")
    assert "hold still" not in "".join(bars[:-1]) and bars[-1].endswith("15.5 of 15 cm   hold still: capturing")
    assert g.rims.calls == len(readings)  # the first reading is the start; it stops at the third still one


def test_each_roll_is_measured_from_where_the_last_ended():
    g, shown = rolling([both(0.0), both(-0.15), both(-0.15), both(-0.15), both(0.0), both(0.15), both(0.15),
                        both(0.15)])
    g.roll_car(-0.15)
    g.roll_car(0.30)
    last = [s for s in shown if s.startswith("  roll forward")]
    assert last[0] == "  roll forward [##########----------] 15.0 of 30 cm"
    assert last[-1].endswith("30.0 of 30 cm   hold still: capturing") and g.position_m == pytest.approx(0.15)


def test_a_roll_not_reached_in_time_is_refused_with_its_code():
    g, shown = rolling([both(0.0), both(-0.05)], timeout_s=0.2)
    with pytest.raises(RollNotReached) as e:
        g.roll_car(-0.15)
    assert e.value.code == 425 and "-15 cm" in str(e.value) and e.value.hint


def test_a_lost_rim_is_named_with_why_and_the_other_carries_the_roll():
    """One front rim tells how far the car rolled; with neither seen the wait starts over."""
    g, shown = rolling([both(0.0), {}, {"FR": (-0.15, 0.0)}, both(-0.15), both(-0.15)])
    g.roll_car(-0.15)
    assert any(s.startswith("  FL: rim not seen (cam3: no closed rim contour)") for s in shown)
    assert shown[-1].endswith("hold still: capturing") and g.rims.calls == 5


def test_the_steer_guide_reads_the_heading_turn_left_positive():
    g, shown = steering([both(0.0, 0.0), {"FL": (0, 4.0), "FR": (0, 3.0)}, both(0.0, 9.6), both(0.0, 9.65),
                         both(0.0, 9.62)])
    g.steer(10.0)
    assert shown[1].startswith("  left: 3.5 of 10 deg   FL +4.0   FR +3.0")
    assert shown[-1].endswith("hold still: capturing")
    g2, _ = steering([both(0.0, 0.0), both(0.0, 2.0)], timeout_s=0.2)
    with pytest.raises(SteerNotReached):
        g2.steer(-10.0)


def test_wait_until_at_hands_each_reading_on():
    seen = []
    values = iter([{"FL": 1.0, "FR": 2.0}, {"FR": 2.0}, {"FL": 2.0, "FR": 2.0}, {"FL": 2.0, "FR": 2.0}])
    ok = wait_until_at(2.0, lambda: next(values), ("FL", "FR"), Approach(0.5, 0.01, 2, 5.0),
                       lambda m, v, r: f"{m:.1f}", lambda s: None, lambda w: "lost",
                       on_reading=lambda t, v, r: seen.append((sorted(v), r)))
    both_ = ["FL", "FR"]
    assert ok and seen == [(both_, False), (["FR"], False), (both_, False), (both_, True)]  # FL lost: handed on
