"""SimCamera: software, hardware (simulated trigger board) and free-run triggers; determinism."""

from __future__ import annotations

import time

import numpy as np
import pytest

from camera_fakes import FakeWorld, station_config
from drivers.base import CameraSettings
from drivers.errors import CameraMissing, CameraTimeout, DriverError
from drivers.context import DriverContext
from drivers.registry import create_camera
from drivers.trigger_board import TriggerBoard
from simulators.sim_station import SimulatedStation
from simulators.trigger_board_sim import TriggerBoardSim, TriggerLines

S = CameraSettings(40, 30)


def _ctx(world, **station):
    return SimulatedStation(world, **station).context()


def _cam(world, uri="sim://cam3", trigger="software", **station):
    from dataclasses import replace
    return create_camera("cam3", uri, replace(S, trigger=trigger), _ctx(world, **station)).open()


def test_software_trigger_and_determinism():
    world = FakeWorld()
    cam = _cam(world)
    cam.arm()
    with pytest.raises(CameraTimeout, match="cam3"):
        cam.grab(0.05)  # armed, not triggered
    f0, f1 = cam.snap(1.0), cam.snap(1.0)
    assert (f0.frame_id, f1.frame_id) == (0, 1)
    assert not np.array_equal(f0.image, f1.image)  # fresh sensor noise per frame
    expect = world.render("cam3", np.random.default_rng([7, 3, 1]))
    assert np.array_equal(f1.image, expect)
    again = _cam(FakeWorld())
    assert np.array_equal(again.snap(1.0).image, f0.image)  # same world/seed -> same frames
    other = _cam(FakeWorld(), seed=8)
    assert not np.array_equal(other.snap(1.0).image, f0.image)
    ident = cam.identity()
    assert (ident.vendor, ident.serial, ident.width, ident.height) == ("simulated", "SIM-cam3", 40, 30)


def test_hardware_trigger_from_the_simulated_board():
    world = FakeWorld()
    with TriggerBoardSim() as sim, TriggerBoard(sim.port, timeout_s=0.5) as board:
        cam = _cam(world, trigger="hardware", trigger_lines=sim.lines)
        assert cam.line == 2  # cam3 -> line 2 by default
        cam.arm()
        cam.trigger()  # a software trigger does nothing in hardware mode
        with pytest.raises(CameraTimeout):
            cam.grab(0.05)
        board.fire(mask=0b011)  # lines 0, 1: not ours
        with pytest.raises(CameraTimeout):
            cam.grab(0.05)
        report = board.fire(mask=0b100)
        f = cam.grab(1.0)
        assert f.frame_id == 0 and report.fired_mask == 0b100
        assert 0 <= f.timestamp_ns - report.host_ns < 0.5e9
        cam.arm()
        sim.fault_mask = 0b100  # our wire is cut: the board says so, the camera sees nothing
        with pytest.raises(DriverError, match="line\\(s\\) 2 did not fire"):
            board.fire()
        with pytest.raises(CameraTimeout):
            cam.grab(0.05)


def test_free_run_frames_on_a_clock():
    cam = _cam(FakeWorld(), uri="sim://cam3?fps=50", trigger="free-run")
    cam.arm()
    t = np.array([cam.grab(1.0).timestamp_ns for _ in range(3)])
    d = np.diff(t)
    assert np.all(d > 0) and np.all(d % 20_000_000 == 0)  # on the 50 fps frame clock


def test_errors_name_the_camera():
    with pytest.raises(DriverError, match="cam3: sim:// cameras need the simulated station"):
        create_camera("cam3", "sim://cam3", S, DriverContext()).open()
    with pytest.raises(CameraMissing, match="no camera 'cam9'"):
        _cam(FakeWorld(), uri="sim://cam9")
    with pytest.raises(DriverError, match="40x30, configured for 64x48"):
        create_camera("cam3", "sim://cam3", CameraSettings(64, 48), _ctx(FakeWorld())).open()
    with pytest.raises(DriverError, match="BayerRG8"):
        create_camera("cam3", "sim://cam3", CameraSettings(40, 30, "BayerRG8"), _ctx(FakeWorld())).open()
    with pytest.raises(DriverError, match="unknown trigger mode 'external'"):
        create_camera("cam3", "sim://cam3", CameraSettings(40, 30, trigger="external"), _ctx(FakeWorld())).open()


def test_mono16_and_roi():
    from dataclasses import replace
    cam = create_camera("cam3", "sim://cam3", replace(S, pixel_format="Mono16", roi=(4, 2, 16, 8)),
                        _ctx(FakeWorld())).open()
    f = cam.snap(1.0)
    assert f.image.dtype == np.uint16 and f.image.shape == (8, 16)
    full = FakeWorld().render("cam3", np.random.default_rng([7, 3, 0]))
    assert np.array_equal(f.image, full[2:10, 4:20].astype(np.uint16) << 8)


def test_real_sim_world_small(tmp_path):
    """The real simulator behind SimCamera: frames equal world.render with the camera's stream."""
    from simulators.world import SimWorld
    config = station_config(tmp_path, width=64, height=48)
    world = SimWorld.from_config(config)
    cam = create_camera("cam1", "sim://cam1", CameraSettings(64, 48), _ctx(world)).open()
    f = cam.snap(30.0)
    assert f.image.shape == (48, 64) and f.image.dtype == np.uint8
    assert np.array_equal(f.image, world.render("cam1", np.random.default_rng([7, 1, 0])))


def test_trigger_lines_wait():
    lines = TriggerLines(2)
    assert lines.wait(1, 0, 0.01) is None
    lines.pulse(0b10, 123)
    assert lines.wait(1, 0, 0.01) == (1, 123)
    with pytest.raises(ValueError, match="line 5"):
        lines.wait(5, 0, 0.01)
    t = time.monotonic()
    assert lines.wait(0, 0, 0.1) is None and time.monotonic() - t >= 0.09
