"""The registry: drivers by URI scheme, imported (with their system libraries) only when used."""

from __future__ import annotations

import subprocess
import sys

import pytest

import drivers.aravis as aravis
from drivers.base import CameraSettings
from drivers.errors import DriverError
from drivers.context import DriverContext
from drivers.registry import build_context, create_camera


def test_missing_pygobject_is_reported_only_when_an_aravis_camera_opens(monkeypatch):
    monkeypatch.setattr(aravis, "_gi_modules", None)
    monkeypatch.setitem(sys.modules, "gi", None)  # import gi -> ImportError
    cam = create_camera("cam5", "aravis://192.0.2.10", CameraSettings())  # creating needs nothing
    with pytest.raises(DriverError, match="the aravis:// driver needs PyGObject and Aravis 0.8") as e:
        cam.open()
    assert "gir1.2-aravis-0.8" in e.value.hint and "pygobject<3.51" in e.value.hint
    assert not cam.is_open


def test_aravis_uri_needs_an_address():
    with pytest.raises(DriverError, match="needs the camera's address"):
        create_camera("cam5", "aravis://", CameraSettings())


def test_nothing_optional_is_imported_for_a_replay_station(tmp_path):
    code = ("import sys; from drivers.registry import build_context, create_camera;"
            f"build_context(['replay://{tmp_path}'], None); create_camera('cam1', 'replay://{tmp_path}');"
            "print(sorted(m for m in ('gi', 'simulators.world', 'simulators.sim_camera', 'serial') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_sim_context_builds_the_world_once(tmp_path):
    from camera_fakes import station_config
    config = station_config(tmp_path, width=32, height=24)
    ctx = build_context([c.uri for c in config.cameras.values()], config, seed=3)
    world = ctx.simulation.world
    assert set(world.cameras) == set(config.cameras) and world.scene.vehicle is not None
    truth = ctx.simulation.truth()
    assert set(truth["wheels"]) == {"FL", "FR", "RL", "RR"} and set(truth["cameras"]) == set(config.cameras)
    assert ctx.trigger_board_port is None  # no board configured


def test_sim_station_with_a_simulated_trigger_board(tmp_path):
    from camera_fakes import station_config
    from station.capture.cameras import close_cameras, open_station_cameras
    from station.capture.sync import capture_cycle
    from drivers.trigger_board import TriggerBoard
    config = station_config(tmp_path, width=24, height=16)
    text = config.path.read_text().replace("port: null", "port: sim").replace("trigger: software ", "trigger: hardware ")
    config.path.write_text(text)
    from station.config import load_config
    config = load_config(config.path)
    from station.capture.cameras import open_trigger_board
    with pytest.raises(DriverError, match="no simulated board was started"):
        open_trigger_board(config, DriverContext())
    ctx = build_context([c.uri for c in config.cameras.values()], config)
    try:
        cams = open_station_cameras(config, ctx)
        board = open_trigger_board(config, ctx)
        assert isinstance(board, TriggerBoard) and board.model == "TB8-SIM"
        with board:
            frames = capture_cycle(cams, 60.0, trigger_board=board)
        assert len(frames) == 8 and len({f.timestamp_ns for f in frames.values()}) == 1
        close_cameras(cams)
    finally:
        ctx.close()
