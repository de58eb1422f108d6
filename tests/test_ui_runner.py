"""The screen's step runner (station/ui/runner.py): a page polling a step sees its ending all at
once, never "error" without the hint that names the crash log (written before the state
changes), nor "failed" without its message."""

from __future__ import annotations

import contextlib
import threading
import time

import pytest

from station.config import load_config
from station.errors import MeasurementError
from station.ui.hardware import Hardware
from station.ui.runner import StepRunner


@pytest.mark.parametrize("error", [ZeroDivisionError("a bug"), MeasurementError("no rim", hint="clean the rim")])
def test_a_page_sees_a_step_end_with_its_message_and_hint(tmp_path, monkeypatch, error):
    hw = Hardware(load_config(), seed=1, open_station=lambda cfg, seed, progress: contextlib.nullcontext())
    runner = StepRunner(hw, crash_dir=tmp_path)
    slow_log = runner._crash_log
    monkeypatch.setattr(runner, "_crash_log", lambda run, e: (time.sleep(0.3), slow_log(run, e))[1])

    def work(station, show):
        raise error

    seen, done = [], threading.Event()

    def poll():
        while not done.is_set():
            seen.append(run.view())

    run = runner.start("measurement", "Measurement", "J", work)
    t = threading.Thread(target=poll)
    t.start()
    runner.wait(10)
    done.set()
    t.join()
    ended = [v for v in seen + [run.view()] if v["state"] != "running"]
    assert ended and all(v["message"] and v["hint"] and v["finished_utc"] for v in ended)
    assert all(v["lines"][-1].startswith("Measurement: ") for v in ended)
    if isinstance(error, ZeroDivisionError):
        assert ended[-1]["state"] == "error" and str(tmp_path) in ended[-1]["hint"]
    else:
        assert ended[-1]["state"] == "failed" and ended[-1]["hint"] == "clean the rim"
