"""Synchronised capture of eight cameras: one trigger, one deadline, one error naming the culprits."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from camera_fakes import IDS, FakeWorld, station_config
from drivers.base import Camera, Frame
from drivers.errors import CameraMissing, CameraTimeout, DriverError, FrameError
from drivers.registry import create_camera
from drivers.trigger_board import TriggerBoard
from simulators.sim_station import SimulatedStation
from simulators.trigger_board_sim import TriggerBoardSim
from station.capture.cameras import close_cameras, open_station_cameras
from station.capture.saving import capture_and_save, new_cycle_id, save_capture
from station.capture.sync import capture_cycle


@pytest.fixture
def config(tmp_path):
    return station_config(tmp_path)


@pytest.fixture
def world():
    return FakeWorld()


def test_eight_software_triggered_cameras(config, world):
    cams = open_station_cameras(config, SimulatedStation(world).context())
    assert list(cams) == IDS and all(c.is_open for c in cams.values())
    t = time.monotonic()
    frames = capture_cycle(cams, 3.0)
    assert time.monotonic() - t < 2.0
    assert list(frames) == IDS
    for i, cid in enumerate(IDS, 1):
        assert np.array_equal(frames[cid].image, world.render(cid, np.random.default_rng([7, i, 0])))
        assert frames[cid].metadata["latency_ms"] >= -5
    stamps = [f.timestamp_ns for f in frames.values()]
    assert max(stamps) - min(stamps) < 0.2e9  # released together
    assert [f.frame_id for f in capture_cycle(cams, 3.0).values()] == [1] * 8


def test_hardware_trigger_through_the_board(config, world):
    with TriggerBoardSim() as sim, TriggerBoard(sim.port, timeout_s=2.0) as board:
        cams = open_station_cameras(config, SimulatedStation(world, trigger_lines=sim.lines).context())
        for c in cams.values():
            c.configure(trigger="hardware")
        frames = capture_cycle(cams, 3.0, trigger_board=board)
        assert sim.fired == 1 and {f.metadata["board_seq"] for f in frames.values()} == {1}
        stamps = {f.timestamp_ns for f in frames.values()}
        assert len(stamps) == 1  # one edge on every wire
        sim.fault_mask = 1 << 4  # cam5's wire
        with pytest.raises(DriverError, match=r"\(cam5\): cam5: trigger line 4 did not fire") as e:
            capture_cycle(cams, 1.0, trigger_board=board)
        assert set(e.value.failures) == {"cam5"} and e.value.code == 204
        assert set(e.value.frames) == set(IDS) - {"cam5"}  # the others fired and are kept
        sim.fault_mask = 0
        sim.mute = True  # the board does not answer: every hardware-triggered camera is named
        with pytest.raises(DriverError, match="no answer to FIRE") as e:
            capture_cycle(cams, 1.0, trigger_board=board)
        assert set(e.value.failures) == set(IDS)
        sim.mute = False
        sim.fault_mask = 0
        assert len(capture_cycle(cams, 3.0, trigger_board=board)) == 8  # the next cycle works


def test_missing_and_late_cameras_are_named_and_the_deadline_holds(config, world):
    cams = open_station_cameras(config, SimulatedStation(world).context())
    world.delay["cam3"] = 1.6  # late
    world.dead.add("cam6")  # broken
    t = time.monotonic()
    with pytest.raises(DriverError) as e:
        capture_cycle(cams, 0.8)
    assert 0.75 < time.monotonic() - t < 1.2  # the deadline, and only the deadline
    assert set(e.value.failures) == {"cam3", "cam6"}
    assert "cam3, cam6" in str(e.value) and "sensor fault" in e.value.failures["cam6"]
    assert set(e.value.frames) == set(IDS) - {"cam3", "cam6"}  # what did arrive rides on the error
    time.sleep(1.0)  # let the late render finish
    world.delay.clear()
    world.dead.clear()
    assert len(capture_cycle(cams, 3.0)) == 8  # back: the next cycle works


class _LateCam(Camera):
    """Stamps its frame when it arrives, 120 ms after the trigger."""

    def _open(self):
        self.n = 0

    def _grab(self, timeout_s):
        time.sleep(0.12)
        self.n += 1
        return Frame(self.camera_id, np.zeros((30, 40), np.uint8), time.monotonic_ns(), self.n)


def test_max_skew_names_the_slow_camera(config, world):
    cams = open_station_cameras(config, SimulatedStation(world).context())
    cams["cam8"] = _LateCam("cam8", "late://", cams["cam1"].settings).open()
    frames = capture_cycle(cams, 3.0)  # without a skew limit only the deadline counts
    assert frames["cam8"].metadata["latency_ms"] >= 110
    with pytest.raises(CameraTimeout, match=r"\(cam8\).*limit 50 ms") as e:
        capture_cycle(cams, 3.0, max_skew_s=0.05)
    assert set(e.value.failures) == {"cam8"}


def test_stale_and_repeated_frames_are_refused(config, world):
    class Stale(Camera):
        def _open(self): self.n = 0
        def _grab(self, timeout_s):
            self.n += 1
            return Frame(self.camera_id, np.zeros((30, 40), np.uint8), time.monotonic_ns() - 10**9, self.n)

    class Repeat(Camera):
        def _open(self): pass
        def _grab(self, timeout_s):
            return Frame(self.camera_id, np.zeros((30, 40), np.uint8), time.monotonic_ns(), 5)

    cams = open_station_cameras(config, SimulatedStation(world).context())
    s = cams["cam1"].settings
    cams["cam2"] = Stale("cam2", "x://", s).open()
    cams["cam4"] = Repeat("cam4", "y://", s).open()
    capture_cycle({"cam4": cams["cam4"]}, 1.0)
    with pytest.raises(FrameError) as e:
        capture_cycle(cams, 3.0)
    assert "stale frame" in e.value.failures["cam2"] and "repeated frame 5" in e.value.failures["cam4"]
    assert set(e.value.failures) == {"cam2", "cam4"}


def test_a_set_lost_to_one_corrupt_buffer_is_taken_again(config, world, caplog):
    class Lossy(Camera):  # the first buffer arrives damaged (packet loss), the next ones whole
        def _open(self): self.n = 0
        def _grab(self, timeout_s):
            self.n += 1
            if self.n == 1:
                raise FrameError(f"{self.camera_id}: corrupt buffer from 10.0.0.3 (missing packets)")
            return Frame(self.camera_id, np.full((30, 40), 7, np.uint8), time.monotonic_ns(), self.n)

    cams = open_station_cameras(config, SimulatedStation(world).context())
    cams["cam3"] = Lossy("cam3", "x://", cams["cam1"].settings).open()
    frames = capture_cycle(cams, 3.0)
    assert list(frames) == IDS and frames["cam3"].frame_id == 2
    assert "corrupt buffer" in caplog.text and "taking the set again" in caplog.text
    cams["cam5"] = _Silent("cam5", "y://", cams["cam1"].settings).open()
    t = time.monotonic()
    with pytest.raises(CameraTimeout):  # a silent camera is not retried: one deadline
        capture_cycle(cams, 0.5)
    assert time.monotonic() - t < 1.2


class _Silent(Camera):
    def _open(self): pass
    def _grab(self, timeout_s):
        time.sleep(timeout_s)
        raise CameraTimeout(f"{self.camera_id}: no frame within {timeout_s:.3g} s")


def test_opening_fails_once_listing_every_camera(tmp_path, world):
    uris = {"cam2": f"replay://{tmp_path / 'nowhere'}", "cam5": "v4l2:///dev/video98"}
    config = station_config(tmp_path, uris)
    with pytest.raises(CameraMissing) as e:
        open_station_cameras(config, SimulatedStation(world).context())
    assert set(e.value.failures) == {"cam2", "cam5"}
    assert "(cam2, cam5)" in str(e.value) and "/dev/video98" in str(e.value)
    # sim cameras without a world: every one is named, in one error
    with pytest.raises(DriverError) as e:
        open_station_cameras(station_config(tmp_path))
    assert set(e.value.failures) == set(IDS)


def test_two_cameras_with_one_address(tmp_path, world):
    uris = {"cam1": "aravis://10.0.0.7", "cam2": "aravis://10.0.0.7/"}  # the loader sees two URIs
    config = station_config(tmp_path, uris)
    with pytest.raises(DriverError, match="cam2 and cam1 both use aravis://10.0.0.7"):
        open_station_cameras(config, SimulatedStation(world).context())


def test_saved_cycle_replays_bit_for_bit(config, world, tmp_path):
    cams = open_station_cameras(config, SimulatedStation(world).context())
    frames, path = capture_and_save(cams, 3.0, config.data_path("captures", new_cycle_id()),
                                    truth={"toe_deg": 0.1})
    meta = json.loads((path / "cycle.json").read_text())
    assert meta["complete"] and meta["failures"] == {} and set(meta["cameras"]) == set(IDS)
    assert json.loads((path / "truth.json").read_text()) == {"toe_deg": 0.1}
    replay = {cid: create_camera(cid, f"replay://{path}", cams[cid].settings).open() for cid in IDS}
    again = capture_cycle(replay, 3.0)
    for cid in IDS:
        assert again[cid].image.tobytes() == frames[cid].image.tobytes()


def test_a_failed_cycle_keeps_what_arrived(config, world, tmp_path):
    cams = open_station_cameras(config, SimulatedStation(world).context())
    world.dead.add("cam7")
    with pytest.raises(DriverError) as e:
        capture_and_save(cams, 3.0, tmp_path / "cycle-x")
    meta = json.loads((e.value.saved_to / "cycle.json").read_text())
    assert meta["complete"] is False and set(meta["failures"]) == {"cam7"}
    assert set(meta["cameras"]) == set(IDS) - {"cam7"}
    close_cameras(cams)
    assert not any(c.is_open for c in cams.values())


def test_cycle_ids_sort_and_never_collide():
    ids = [new_cycle_id() for _ in range(50)]
    assert len(set(ids)) == 50 and ids == sorted(ids)


def test_save_refuses_to_overwrite(tmp_path):
    f = {"cam1": Frame("cam1", np.zeros((2, 2), np.uint8), 0, 0)}
    save_capture(f, tmp_path / "c")
    with pytest.raises(FrameError, match="never overwritten"):
        save_capture(f, tmp_path / "c")


# --- the commands ---------------------------------------------------------------------------
def test_station_capture_and_cameras_commands(tmp_path, capsys):
    from station.cli import main
    config = station_config(tmp_path, width=32, height=24)
    out = tmp_path / "set1"
    assert main(["--config", str(config.path), "capture", "--out", str(out), "--timeout", "60"]) == 0
    meta = json.loads((out / "cycle.json").read_text())
    assert meta["complete"] and set(meta["cameras"]) == set(IDS) and (out / "truth.json").exists()
    assert "captured 8 frames (each the mean of 8) in" in capsys.readouterr().out  # capture.frames_averaged
    assert meta["cameras"]["cam1"]["averaged_frames"] == 8 and meta["cameras"]["cam1"]["dtype"] == "uint16"
    raw = tmp_path / "raw"
    assert main(["--config", str(config.path), "capture", "--out", str(raw), "--frames", "1"]) == 0
    assert "captured 8 frames in" in capsys.readouterr().out
    assert json.loads((raw / "cycle.json").read_text())["cameras"]["cam1"]["dtype"] == "uint8"
    assert main(["--config", str(config.path), "capture", "--out", str(tmp_path / "x"), "--frames", "0"]) == 2
    assert "expected 1 to 64 frames" in capsys.readouterr().err and not (tmp_path / "x").exists()
    # the same --out again: refused, nothing overwritten
    assert main(["--config", str(config.path), "capture", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    # replay the saved set through the station's own configuration
    uris = {cid: f"replay://{out}?camera={cid}" for cid in IDS}
    (tmp_path / "r").mkdir()
    replay_cfg = station_config(tmp_path / "r", uris, width=32, height=24)
    assert main(["--config", str(replay_cfg.path), "cameras", "--snap", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["id"] for r in rows] == IDS and all(r["open"] for r in rows)
    assert rows[0]["vendor"] == "replay" and rows[0]["resolution"] == "32x24"
    assert rows[0]["last_frame"].startswith("now: #1")


def test_station_cameras_lists_failures_without_a_traceback(tmp_path, capsys):
    from station.cli import main
    uris = {"cam3": f"replay://{tmp_path / 'gone'}", "cam4": "v4l2:///dev/video97"}
    config = station_config(tmp_path, uris, width=32, height=24)
    assert main(["--config", str(config.path), "cameras"]) == 2
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].split()[:4] == ["camera", "wheel", "role", "state"]
    assert sum("FAILED" in ln for ln in lines[1:9]) == 2 and "simulated" in lines[1]
    assert "cam4: no device /dev/video97" in out and "cam3: replay directory" in out
    assert main(["--config", str(config.path), "capture", "--timeout", "30"]) == 2
    err = capsys.readouterr().err
    assert "error 202" in err and "(cam3, cam4)" in err and "Traceback" not in err


def test_station_cycle_saves_under_data_dir_unless_told_not_to(tmp_path, world):
    from station.capture.saving import capture_station_cycle
    config = station_config(tmp_path)
    cams = open_station_cameras(config, SimulatedStation(world).context())
    frames, path = capture_station_cycle(cams, config, truth={"x": 1})
    assert path.parent == config.data_path("captures") and len(frames) == 8
    assert json.loads((path / "cycle.json").read_text())["station"] == config.name
    (tmp_path / "k").mkdir()
    config2 = station_config(tmp_path / "k")
    config2.path.write_text(config2.path.read_text().replace("keep_captures: true", "keep_captures: false"))
    from station.config import load_config
    config2 = load_config(config2.path)
    captures = config2.data_path("captures")
    kept = sorted(captures.iterdir()) if captures.exists() else []
    frames, path = capture_station_cycle(cams, config2)
    assert path is None and len(frames) == 8
    assert (sorted(captures.iterdir()) if captures.exists() else []) == kept  # nothing new saved
