"""station/cycle.py: a cycle on the assembled (small, simulated) station goes through the
sequencer's states, and a failed capture is kept and leaves the station ready for the next."""

from __future__ import annotations

from pathlib import Path

import pytest

from station.cycle import Station
from station.records.history import History
from tests.station_fixtures import small_station_config, truth_calibration


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    config = small_station_config(tmp_path_factory.mktemp("cycle"), capture__frames_averaged=1,
                                  recording__enabled=False)
    truth_calibration(config)
    with Station(config, seed=3, progress=lambda msg: None, workers=0) as s:
        yield s


@pytest.mark.slow
def test_a_cycle_passes_through_the_sequencer_and_is_kept(station):
    events = []
    station.sequencer.listeners.append(lambda old, event, new: events.append(event))
    result = station.measure(job_id="JOB-C1")
    assert result.valid, result.failure
    assert events == ["start", "captured", "measured", "reported"] and station.sequencer.state == "done"
    assert result.cycle_id and result.job_id == "JOB-C1" and result.errors is not None  # simulated: truth attached
    assert {"capture", "wheels", "total", "record_and_store"} <= set(result.timing_s)
    with History(station.config.data_path("history.sqlite")) as h:
        row = h.get(result.cycle_id)
    assert row["valid"] and row["result"]["wheels"]["FL"]["toe_deg"] == result.wheels["FL"].toe_deg


@pytest.mark.slow
def test_a_failed_capture_is_a_kept_invalid_result_and_the_next_cycle_runs(station, monkeypatch):
    cam = station.cameras["cam5"]
    monkeypatch.setattr(cam, "_grab", lambda timeout_s: None)   # the camera sends nothing
    failed = station.measure(job_id="JOB-C2")
    assert not failed.valid and failed.failure.code == 201 and "cam5" in failed.failure.message
    assert station.sequencer.state == "fault" and station.sequencer.fault.code == 201
    with History(station.config.data_path("history.sqlite")) as h:
        assert h.get(failed.cycle_id)["valid"] is False   # nothing lost: the failure is in the history
    monkeypatch.undo()
    again = station.measure(job_id="JOB-C3")
    assert again.valid and station.sequencer.state == "done" and station.sequencer.fault is None


@pytest.mark.slow
def test_an_unknown_vehicle_spec_is_raised_after_the_cycle_is_kept(station):
    from station.errors import ConfigError

    with pytest.raises(ConfigError, match="no-such-car"):
        station.measure(job_id="JOB-C4", vehicle_spec="no-such-car")
    assert station.sequencer.state == "done"
    with History(station.config.data_path("history.sqlite")) as h:
        kept = h.jobs("JOB-C4")
    assert len(kept) == 1 and any("no-such-car" in w for w in kept[0].warnings)


def _disk_full(*args, **kwargs):
    raise OSError(28, "No space left on device")


@pytest.mark.slow
def test_images_the_disk_refuses_are_a_warning_and_the_cycle_goes_on(station, monkeypatch):
    monkeypatch.setattr("station.capture.saving.save_cycle", _disk_full)
    result = station.measure(job_id="JOB-C5")
    assert result.valid and result.captures_dir is None
    assert result.has_flag("not_kept") and any("No space left on device" in w for w in result.warnings)
    with History(station.config.data_path("history.sqlite")) as h:
        kept = h.jobs("JOB-C5")
    assert len(kept) == 1 and kept[0].has_flag("not_kept")  # the history knows the images are missing


@pytest.mark.slow
def test_a_failed_capture_whose_images_the_disk_refuses_is_still_kept(station, monkeypatch):
    monkeypatch.setattr("station.capture.saving.save_cycle", _disk_full)
    monkeypatch.setattr(station.cameras["cam5"], "_grab", lambda timeout_s: None)
    failed = station.measure(job_id="JOB-C6")
    assert not failed.valid and failed.failure.code == 201  # the capture's own error, not the disk's
    assert failed.captures_dir is None and failed.has_flag("not_kept")
    with History(station.config.data_path("history.sqlite")) as h:
        assert h.get(failed.cycle_id)["valid"] is False


KILLED_SAVE = """
import sys, time
sys.path.insert(0, {root!r})
import cv2
import numpy as np
from drivers.base import Frame
from drivers.frame_store import save_cycle

def stuck(*args, **kwargs):
    print("writing", flush=True)
    time.sleep(600)

cv2.imencode = stuck  # the save stops after creating its temporary folder, until it is killed
save_cycle(sys.argv[1], {{"cam1": Frame("cam1", np.zeros((4, 4), np.uint8), 0, 0)}})
"""


def _killed_while_saving(tmp_path, target) -> int:
    """The PID of a process killed (SIGKILL) in the middle of saving a cycle to ``target``."""
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "killed_save.py"
    script.write_text(KILLED_SAVE.format(root=str(Path(__file__).resolve().parent.parent)))
    proc = subprocess.Popen([sys.executable, str(script), str(target)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
    finally:
        proc.kill()
        proc.wait()
    return proc.pid


@pytest.mark.slow
def test_a_new_station_removes_the_images_a_killed_one_left_half_saved(station, tmp_path):
    import os
    import tempfile

    captures = station.config.data_path("captures")
    dead_pid = _killed_while_saving(tmp_path, captures / "20261122T100000000Z-0001")
    left = [p for p in captures.iterdir() if p.name.startswith(".")]
    assert len(left) == 1 and f".{dead_pid}." in left[0].name  # what the killed save left behind
    running = Path(tempfile.mkdtemp(prefix=f".20261122T100000000Z-0002.{os.getpid()}.", dir=captures))
    with Station(station.config, seed=3, progress=lambda msg: None, workers=0):
        assert not left[0].exists()
        assert running.exists()  # a running process's save is left alone
    running.rmdir()
