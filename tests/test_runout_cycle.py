"""Runout compensation on the assembled (small, simulated) station: `station measure
--compensate`'s cycle, the runout kept with the job and applied to its later measurements, and a
roll that did not happen refused with its code and kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration.station_frame import WHEELS
from station.cycle import Station
from station.errors import RollTooShort
from station.procedures.runout import ROLL_PLAN
from station.procedures.runout_store import runout_path
from station.records.history import History
from tests.station_fixtures import small_station_config, truth_calibration


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    # full resolution: the rims seen 15 cm either side need it; one frame per capture
    config = small_station_config(tmp_path_factory.mktemp("runout"), 1.0, capture__frames_averaged=1,
                                  simulation__runout_max_deg=0.3)
    truth_calibration(config)
    with Station(config, seed=3, progress=lambda msg: None, workers=0) as s:
        yield s


def _spin_error(result, truth, w):
    t = truth["wheels"][w]
    return np.hypot(result.wheels[w].toe_deg - t["toe_deg"], result.wheels[w].camber_deg - t["camber_deg"])


@pytest.mark.slow
def test_a_compensated_cycle_measures_the_spin_axes_and_keeps_the_runout_with_its_job(station):
    result = station.measure(job_id="JOB-R1", compensate=station.context.simulation)
    assert result.valid, result.failure
    assert result.runout_compensated and result.to_json()["runout_compensated"] is True
    truth = result.truth
    rim_off = []
    for w in WHEELS:
        t = truth["wheels"][w]
        assert _spin_error(result, truth, w) < 0.06, w
        assert result.wheels[w].runout_deg == pytest.approx(t["runout_deg"], abs=0.06), w
        assert result.to_json()["wheels"][w]["runout_mm"] == pytest.approx(t["runout_mm"], abs=0.6), w
        rim_off.append(np.hypot(t["rim_toe_deg"] - t["toe_deg"], t["rim_camber_deg"] - t["camber_deg"]))
    assert max(rim_off) > 0.1  # the vehicle's rims run out: the rim planes are not the spin axes
    # every position's frames are kept, the cycle is in the history, the recording shows the roll
    folders = sorted(p.name for p in Path(result.captures_dir).iterdir() if p.is_dir())
    assert folders == [f"position-{k + 1}" for k in range(len(ROLL_PLAN))]
    with History(station.config.data_path("history.sqlite"), read_only=True) as h:
        assert h.get(result.cycle_id)["result"]["runout_compensated"] is True
    from station.records.recording import read_recording_summary
    entities = read_recording_summary(result.recording)["entities"]
    assert {f"/vehicle/{w}/runout/cone" for w in WHEELS} <= set(entities)
    assert runout_path(station.config, "JOB-R1").exists()
    assert "toe and camber of the wheels' spin axes (runout compensated)" in _printed(result)
    assert "runout  FL " in _printed(result)

    # the same job measured again: the kept runout is applied (the car stood still) ...
    again = station.measure(job_id="JOB-R1")
    assert again.runout_compensated and any("runout kept for job 'JOB-R1'" in w for w in again.warnings)
    for w in WHEELS:
        assert _spin_error(again, again.truth, w) < 0.06, w
    # ... also after the car rolled 5 cm: the runout turns with the rim
    station.context.simulation.roll_car(0.05)
    rolled = station.measure(job_id="JOB-R1")
    assert rolled.runout_compensated
    for w in WHEELS:
        assert _spin_error(rolled, rolled.truth, w) < 0.06, w
    # another job has no runout kept: its values are of the rim planes, and compared with those
    other = station.measure(job_id="JOB-R2")
    assert not other.runout_compensated and not other.to_json()["runout_compensated"]
    worst = max(WHEELS, key=lambda w: rim_off[WHEELS.index(w)])
    assert _spin_error(other, other.truth, worst) > 0.08
    assert abs(other.errors[worst]["toe_error_deg"]) < 0.06 and abs(other.errors[worst]["camber_error_deg"]) < 0.06
    assert "toe and camber of the rim planes (runout not compensated" in _printed(other)


def _printed(result) -> str:
    import io

    from station.commands.measure import print_result

    out = io.StringIO()
    print_result(result, out)
    return out.getvalue()


@pytest.mark.slow
def test_live_applies_the_runout_kept_for_its_job(station, tmp_path):
    from station.live import LiveSession

    if not runout_path(station.config, "JOB-R1").exists():
        station.measure(job_id="JOB-R1", compensate=station.context.simulation)
    shown = []
    with LiveSession(station.config, axle="front", seed=3, cache_dir=tmp_path / "cache", hold=1, n_steps=3,
                     toe_span_deg=0.3, progress=lambda s: None, workers=0, job_id="JOB-R1") as s:
        s.baseline()
        assert s.runout_compensated
        s.run(None, shown.append, max_updates=3)
    for r in shown:
        for w in ("FL", "FR"):
            assert abs(r.wheels[w]["toe_deg"] - r.truth_toe_deg[w]) < 0.06, (w, r.wheels[w], r.truth_toe_deg)


class _StandsStill:
    """An operator who does not roll the car."""

    def roll_car(self, distance_m: float) -> None:
        pass

    def steer(self, angle_deg: float) -> None:
        pass


@pytest.mark.slow
def test_a_roll_that_did_not_happen_is_refused_with_its_code_and_kept(station):
    result = station.measure(job_id="JOB-R3", compensate=_StandsStill())
    assert not result.valid and result.failure.code == RollTooShort.code
    assert "turned the wheel through only" in result.failure.message and result.failure.hint
    assert station.sequencer.state == "done"  # a refused procedure is a measured failure, not a fault
    with History(station.config.data_path("history.sqlite"), read_only=True) as h:
        row = h.get(result.cycle_id)
    assert row is not None and not row["valid"]
    assert not runout_path(station.config, "JOB-R3").exists()


@pytest.mark.slow
def test_a_position_that_fails_is_left_out_and_named(station, monkeypatch):
    """A rim lost at one position between the roll's ends costs that position, not the cycle."""
    from station.result import Failure

    measure, calls = Station._measure, []

    def third_fails(self, cycle, frames, method, **kw):
        result = measure(self, cycle, frames, method, **kw)
        calls.append(result)
        if len(calls) == 3:
            result.valid, result.failure = False, Failure(400, "FR (cam1, cam2): a rim made to fail", "none", "FR")
        return result

    monkeypatch.setattr(Station, "_measure", third_fails)
    result = station.measure(compensate=station.context.simulation)
    assert result.valid, result.failure
    assert result.runout_compensated
    assert f"runout compensation: position 3 of {len(ROLL_PLAN)} left out (FR (cam1, cam2): a rim made to fail)" \
        in result.warnings
    for w in WHEELS:
        assert _spin_error(result, result.truth, w) < 0.06, w
