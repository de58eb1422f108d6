"""The Adjust page's feed without cameras: each reading's angles, uncertainty and verdicts against
the spec, and the live loop letting go of the cameras while a step runs (fake live session)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from calibration.station_frame import SIDE, WHEELS
from station.config import load_config
from station.live import Reading
from station.records.vehicle_specs import get_spec, load_vehicle_specs
from station.ui.hardware import Hardware
from station.ui.job import Jobs
from station.ui.live_feed import LiveFeed, reading_view
from station.ui.runner import StepRunner
from tests.result_builder import make_result

BASE_TOE = {"FL": 0.05, "FR": 0.06, "RL": 0.10, "RR": -0.02}


def _axis(wheel: str, toe_deg: float, camber_deg: float) -> np.ndarray:
    t, c = np.radians(toe_deg), np.radians(camber_deg)
    a = np.array([SIDE[wheel] * np.cos(t) * np.cos(c), np.sin(t), -np.sin(c)])
    return a / np.linalg.norm(a)


class FakeLive:
    """A LiveSession on a car whose FL toe follows ``toe_fl`` (a list, one value per update)."""

    opened = 0
    closed = 0

    def __init__(self, axle: str, toe_fl: list[float]):
        self.live_wheels = ("FL", "FR") if axle == "front" else tuple(WHEELS)
        self.base = make_result(3, toe=BASE_TOE, camber={w: 0.0 for w in WHEELS})
        self.centers = {w: np.asarray(self.base.wheels[w].center_station_m) for w in WHEELS}
        self.axes = {w: np.asarray(self.base.wheels[w].axis_station) for w in WHEELS}
        self.toe_fl = toe_fl
        self.n = 0
        self.runout_compensated = False
        FakeLive.opened += 1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        FakeLive.closed += 1

    def baseline(self):
        return self.base

    def update(self) -> Reading:
        time.sleep(0.01)
        toe = self.toe_fl[min(self.n, len(self.toe_fl) - 1)]
        self.axes["FL"] = _axis("FL", toe, 0.0)
        r = Reading(self.n, wheels={w: {} for w in self.live_wheels}, timing_s={"total": 0.01})
        self.n += 1
        return r


@pytest.fixture
def spec():
    config = load_config()
    return get_spec(load_vehicle_specs(config.vehicle_specs_path), "dodge-caravan-2007")


def test_a_reading_shows_each_angle_against_the_spec(spec):
    s = FakeLive("front", [0.05])
    base = s.baseline()
    for toe, ok in ((0.05, True), (0.149, True), (0.30, False), (-0.06, False)):
        s.axes["FL"] = _axis("FL", toe, 0.0)
        m = reading_view(Reading(1, wheels={"FL": {}, "FR": {}}), s.centers, s.axes, base, spec, s.live_wheels, 12.0)
        fl = m["wheels"]["FL"]["toe"]
        assert fl["value"] == pytest.approx(toe, abs=1e-6) and fl["ok"] is ok, toe
        assert fl["std"] == 0.004 and fl["window"] == pytest.approx({"nominal": 0.05, "low": -0.05, "high": 0.15})
        assert m["axles"]["front"]["value"] == pytest.approx(toe + BASE_TOE["FR"], abs=1e-6)
    assert m["thrust"]["value"] == pytest.approx((BASE_TOE["RL"] - BASE_TOE["RR"]) / 2, abs=1e-6)
    assert m["thrust"]["ok"] is True and m["wheels"]["RL"]["live"] is False and m["wheels"]["FL"]["live"]
    thrust = m["thrust"]["value"]
    assert m["wheels"]["FL"]["toe_thrust"] == pytest.approx(-0.06 - thrust, abs=1e-6)  # toe + s * thrust, s=-1
    lost = reading_view(Reading(2, wheels={"FR": {}}, errors={"FL": "cam3: no closed rim contour"}),
                        s.centers, s.axes, base, spec, s.live_wheels, 12.0)
    assert lost["wheels"]["FL"]["toe"]["value"] is None and lost["wheels"]["FL"]["error"].startswith("cam3")
    assert lost["axles"]["front"]["value"] is None and lost["wheels"]["FL"]["toe"]["ok"] is None
    assert reading_view(Reading(3, wheels={"FL": {}, "FR": {}}), s.centers, s.axes, base, None, s.live_wheels,
                        1.0)["wheels"]["FL"]["toe"]["ok"] is None  # no spec: no verdict


def test_a_reading_gives_toe_in_mm_at_the_measured_rim(spec):
    s = FakeLive("front", [0.1])
    base = s.baseline()  # rims of 0.2159 m radius: 17 inches, 431.8 mm across
    s.axes["FL"] = _axis("FL", 0.1, 0.0)
    m = reading_view(Reading(1, wheels={"FL": {}, "FR": {}}), s.centers, s.axes, base, spec, s.live_wheels, 12.0)
    fl = m["wheels"]["FL"]
    assert fl["rim_diameter_mm"] == 431.8
    assert fl["toe"]["mm"] == 0.8                      # 431.8 x sin(0.1 deg) = 0.754 mm
    assert m["wheels"]["FR"]["toe"]["mm"] == 0.5       # 431.8 x sin(0.06 deg) = 0.452 mm
    assert m["axles"]["front"]["mm"] == 1.2            # 431.8 x sin(0.16 deg) = 1.206 mm
    assert "mm" not in m["wheels"]["FL"]["camber"] and "mm" not in m["thrust"]
    base.wheels["FR"].rim_radius_m = None              # a synthetic result: no rim, no mm
    m = reading_view(Reading(2, wheels={"FL": {}, "FR": {}}), s.centers, s.axes, base, spec, s.live_wheels, 12.0)
    assert m["wheels"]["FR"]["toe"]["mm"] is None and m["wheels"]["FR"]["rim_diameter_mm"] is None
    assert m["axles"]["front"]["mm"] is None and m["wheels"]["FL"]["toe"]["mm"] == 0.8


def _wait(cond, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    raise TimeoutError


def test_the_live_view_lets_go_of_the_cameras_for_a_step_and_comes_back():
    config = load_config()
    gate = threading.Event()

    class Station:
        def __init__(self, progress):
            self.progress = progress

        def __enter__(self):
            assert FakeLive.opened == FakeLive.closed, "a step opened the cameras while the live view held them"
            return self

        def __exit__(self, *exc):
            pass

    hw = Hardware(config, seed=1, open_station=lambda cfg, seed, progress: Station(progress),
                  open_live=lambda cfg, seed, axle, progress, job, steps: FakeLive(axle, [0.05, 0.3] * 10_000))
    runner = StepRunner(hw)
    feed = LiveFeed(hw, Jobs(config), runner, linger_s=0.2)
    FakeLive.opened = FakeLive.closed = 0
    feed.subscribe("front")
    try:
        _wait(lambda: feed.latest[0] > 5)
        assert feed.status[1]["state"] == "live"
        runner.start("x", "Measurement", "J", lambda station, show: (gate.wait(10), None))
        _wait(lambda: feed.status[1]["state"] == "paused")
        assert "'Measurement' is using the cameras" in feed.status[1]["message"]
        assert FakeLive.closed == FakeLive.opened == 1
        n = feed.latest[0]
        time.sleep(0.3)
        assert feed.latest[0] == n  # no reading while the step holds the cameras
        gate.set()
        runner.wait(10)
        _wait(lambda: feed.latest[0] > n + 3)  # back, with a new session
        assert FakeLive.opened == 2 and runner.last["x"].state == "done"
    finally:
        feed.unsubscribe()
        _wait(lambda: feed.status[1]["state"] == "idle", 5)  # the last page left: the cameras rest
        feed.close()
    assert FakeLive.closed == FakeLive.opened
