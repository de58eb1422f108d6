"""`station live`: the loop on a small simulated station, the display, Ctrl-C."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from station.live import LiveSession, Reading, format_reading, rate_summary
from tests.station_fixtures import small_station_config, truth_calibration

ROOT = Path(__file__).resolve().parents[1]
SEED = 1


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("live")
    config = small_station_config(tmp)
    truth_calibration(config)
    return config, tmp / "cache"


@pytest.fixture(scope="module")
def session_run(station):
    config, cache = station
    shown = []
    with LiveSession(config, axle="front", seed=SEED, cache_dir=cache, hold=1, n_steps=3, toe_span_deg=0.5,
                     progress=lambda s: None) as s:
        s.baseline()
        summary = s.run(None, shown.append, max_updates=5)
    return summary, shown


def test_live_loop_measures_the_adjusted_wheel_and_stops(session_run):
    summary, shown = session_run
    assert summary["updates"] == 5 and not summary["interrupted"] and summary["rate_hz"] > 0
    for r in shown:
        assert set(r.wheels) == {"FL", "FR"}, r.errors
        for w in ("FL", "FR"):  # the measured toe follows the simulated adjustment
            assert abs(r.wheels[w]["toe_deg"] - r.truth_toe_deg[w]) < 0.1
    fl = [r.wheels["FL"]["toe_deg"] for r in shown]
    true_fl = [r.truth_toe_deg["FL"] for r in shown]
    assert max(true_fl) - min(true_fl) == pytest.approx(0.5)  # hold=1: steps 0,1,2,1,0
    assert max(fl) - min(fl) == pytest.approx(0.5, abs=0.1)
    fr = [r.wheels["FR"]["toe_deg"] for r in shown]
    assert max(fr) - min(fr) < 0.1  # the other wheel stays put


def test_display_formats_values_and_verdicts():
    from station.records.vehicle_specs import AngleSpec, VehicleSpec

    spec = VehicleSpec("x", "X", "", {"front.toe": AngleSpec(0.05, 0.10), "front.camber": AngleSpec(0.1, 0.4),
                                      "front.total_toe": AngleSpec(0.10, 0.20)})
    r = Reading(7, wheels={"FL": {"toe_deg": 0.123, "camber_deg": -0.5}}, total_toe_deg={},
                errors={"FR": "cam3: no closed rim contour"},
                timing_s={"capture": 0.01, "wheels": 0.05, "detect": 0.03, "reconstruct": 0.02, "angles": 0.001, "total": 0.07})
    lines = format_reading(r, spec, live_wheels=("FL", "FR"))
    fl = next(line for line in lines if line.startswith("FL"))
    assert "+0.123" in fl and "[-0.05, +0.15]" in fl and "OK" in fl
    assert "-0.500" in fl and "[-0.30, +0.50]" in fl and "ADJUST" in fl
    assert any("FR" in line and "no closed rim contour" in line for line in lines)
    assert any("update 7: 70 ms" in line for line in lines)
    r.total_toe_deg = {"front": 0.35}
    assert any(line.startswith("front total toe +0.350") and "ADJUST" in line
               for line in format_reading(r, spec, ("FL", "FR")))
    assert "OK" not in "".join(format_reading(r, None, ("FL",))[1:])  # no spec: no verdicts


def test_display_uses_the_real_vehicle_spec_per_wheel():
    from station.config import load_config
    from station.records.vehicle_specs import get_spec, load_vehicle_specs

    cfg = load_config()
    spec = get_spec(load_vehicle_specs(cfg.vehicle_specs_path), "dodge-caravan-2007")
    r = Reading(1, wheels={"FR": {"toe_deg": 0.05, "camber_deg": 2.0}})
    fr = next(line for line in format_reading(r, spec, ("FR",)) if line.startswith("FR"))
    toe, camber = spec.angles["FR.toe"], spec.angles["FR.camber"]
    assert f"[{toe.low_deg:+.2f}, {toe.high_deg:+.2f}]" in fr and f"[{camber.low_deg:+.2f}, {camber.high_deg:+.2f}]" in fr
    assert fr.count("OK") == 1 and fr.count("ADJUST") == 1  # toe on nominal, camber 2 deg out


def test_rate_summary():
    s = rate_summary([{"total": 0.1, "capture": 0.01}] * 10, 1.25, interrupted=True)
    assert s["rate_hz"] == pytest.approx(8.0) and s["total_ms"] == pytest.approx(100) and s["interrupted"]
    assert rate_summary([], 0.0)["rate_hz"] == 0.0


def test_unknown_axle_is_refused(station):
    from station.errors import MeasurementError

    with pytest.raises(MeasurementError, match="unknown axle"):
        LiveSession(station[0], axle="middle")


def _cli(config, cache, *extra):
    # the station the module fixture built (its calibration is there), not this test's own data dir
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "STATION_DATA_DIR": str(config.data_dir)}
    return [sys.executable, "-m", "station.cli", "--config", str(config.path), "live", "--seed", str(SEED),
            "--cache", str(cache), *extra], env


def test_cli_stops_at_seconds_and_reports_the_rate(station, session_run):
    config, cache = station
    cmd, env = _cli(config, cache, "--seconds", "1", "--vehicle", "dodge-caravan-2007")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr
    assert " Hz " in out.stdout and "updates in" in out.stdout and "FL" in out.stdout
    assert "[" in out.stdout.splitlines()[-2]  # the spec's ranges are shown
    # the first full measurement's warnings are shown before the live readings (here: 640x512
    # cameras, rims too small for the best accuracy)
    lines = out.stdout.splitlines()
    warned = [k for k, line in enumerate(lines) if line.startswith("warning: ") and "the rim spans only" in line]
    readings = [k for k, line in enumerate(lines) if line.startswith("FL")]
    assert warned and readings and max(warned) < min(readings), out.stdout[:2000]


def test_ctrl_c_exits_cleanly(station, session_run):
    config, cache = station
    cmd, env = _cli(config, cache)
    # A shell that starts a job in the background (as a CI runner may) sets SIGINT to "ignore",
    # and the children inherit it: give the command back the terminal's default handler.
    cmd[1:3] = ["-c", "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
                      "from station.cli import main; sys.exit(main(sys.argv[1:]))"]
    # its own process group, signalled as a whole: a terminal's Ctrl-C reaches the worker
    # processes too, and they must neither print tracebacks nor hold the exit up
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
                         start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        line = ""
        while time.monotonic() < deadline:  # wait for the first live update
            line = p.stdout.readline()
            if line.startswith("FL") or "update" in line:
                break
        os.killpg(p.pid, signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode in (0, 130), err
    assert "Traceback" not in err
    assert "stopped by Ctrl-C" in out or "stopped" in err


def test_a_failed_first_measurement_keeps_its_own_hint(station, monkeypatch):
    import station.live as live
    from station.errors import MeasurementError
    from station.result import Failure, Measurement

    config, cache = station
    refused = Measurement(station=config.name, failure=Failure(404, "FL less certain than the limit",
                                                               "light the wheel with diffuse panels", "FL"))
    monkeypatch.setattr(live, "measure_frames", lambda *a, **k: refused)
    with LiveSession(config, axle="front", seed=SEED, cache_dir=cache, progress=lambda s: None) as s:
        with pytest.raises(MeasurementError, match="FL less certain") as e:
            s.baseline()
    assert e.value.hint == "light the wheel with diffuse panels"
