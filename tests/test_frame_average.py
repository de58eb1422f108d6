"""A burst of frames averaged per camera: the scale, the noise, the capture, the replay."""

from __future__ import annotations

import re

import numpy as np
import pytest

from camera_fakes import IDS, station_config
from drivers.base import AVERAGED_FRAMES_KEY, CameraSettings, Frame
from drivers.errors import FrameError
from drivers.registry import create_camera
from simulators.sim_station import SimulatedStation
from station.capture.cameras import open_station_cameras
from station.capture.saving import capture_and_save
from station.capture.sync import capture_averaged
from station.errors import ConfigError
from station.capture.frame_average import averaged_frames, mean_image
from station.rim.preprocess import noise_grey, to_grey


class CleanWorld:
    """SimWorld's interface as SimCamera uses it: a fixed clean ramp plus N(0, 2) per frame."""

    def __init__(self, width=64, height=48, sigma=2.0):
        from types import SimpleNamespace
        self.cameras = {cid: SimpleNamespace(width=width, height=height) for cid in IDS}
        self.config = SimpleNamespace(simulation=SimpleNamespace(station_seed=7))
        self.clean = np.tile(np.linspace(40, 200, width, dtype=np.float32), (height, 1))
        self.sigma = sigma

    def render(self, cam_id, rng=None, exposure=1.0):
        noisy = self.clean + rng.standard_normal(self.clean.shape, dtype=np.float32) * np.float32(self.sigma)
        return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def test_mean_of_8_bit_frames_is_kept_on_the_16_bit_scale():
    a = np.full((48, 48), 10, np.uint8)
    b = np.full((48, 48), 13, np.uint8)
    m = mean_image([a, a, b])  # 11 grey levels
    assert m.dtype == np.uint16 and np.all(m == 11 * 257)
    assert np.allclose(to_grey(m), 11.0, atol=1e-3)  # the detector reads it as 11 grey levels
    m = mean_image([a, b])  # 11.5: a fraction an 8-bit frame cannot hold
    assert np.allclose(to_grey(m), 11.5, atol=1 / 257)
    assert np.all(mean_image([np.full((2, 2), 255, np.uint8)] * 8) == 65535)


def test_mean_of_16_bit_frames_stays_on_their_scale():
    a = np.full((3, 3), 1000, np.uint16)
    b = np.full((3, 3), 1003, np.uint16)
    assert np.all(mean_image([a, b, b]) == 1002)


def test_frames_of_different_size_or_type_are_refused():
    with pytest.raises(FrameError, match="differ in size or pixel type"):
        mean_image([np.zeros((3, 3), np.uint8), np.zeros((3, 4), np.uint8)])
    with pytest.raises(FrameError):
        mean_image([np.zeros((3, 3), np.uint8), np.zeros((3, 3), np.uint16)])


def test_the_noise_falls_with_the_square_root_of_the_frames():
    world = CleanWorld(256, 192)
    frames = [world.render("cam1", np.random.default_rng([1, k])) for k in range(8)]
    one = noise_grey(to_grey(frames[0]))
    eight = noise_grey(to_grey(mean_image(frames)))
    assert one == pytest.approx(2.0, rel=0.1)
    assert eight == pytest.approx(2.0 / np.sqrt(8), rel=0.15)


def test_averaged_frames_name_their_burst():
    bursts = [{"cam1": Frame("cam1", np.full((48, 48), 10 + k, np.uint8), 1_000_000 * (k + 1), 5 + k, {"x": 1})}
              for k in range(4)]
    out = averaged_frames(bursts)["cam1"]
    assert out.frame_id == 5 and out.timestamp_ns == 1_000_000
    assert out.metadata[AVERAGED_FRAMES_KEY] == 4 and out.metadata["burst_frame_ids"] == [5, 6, 7, 8]
    assert out.metadata["burst_ms"] == pytest.approx(3.0) and out.metadata["x"] == 1
    assert np.allclose(to_grey(out.image), 11.5, atol=1 / 257)


def test_a_cycle_captures_the_burst_and_a_replay_serves_it_once(tmp_path):
    config = station_config(tmp_path, width=64, height=48)
    world = CleanWorld()
    cams = open_station_cameras(config, SimulatedStation(world).context())
    frames, path = capture_and_save(cams, 3.0, tmp_path / "cycle", frames_averaged=6)
    assert set(frames) == set(IDS)
    f = frames["cam3"]
    assert f.image.dtype == np.uint16 and f.metadata[AVERAGED_FRAMES_KEY] == 6
    assert len(set(f.metadata["burst_frame_ids"])) == 6   # six exposures, not one frame six times
    assert np.abs(to_grey(f.image) - world.clean).std() < 2.0 / np.sqrt(6) * 1.3
    # replayed with the camera still configured Mono8: the kept mean comes back as it was,
    # and a replay is never averaged again (a second cycle would be another saved set)
    replay = {cid: create_camera(cid, f"replay://{path}", CameraSettings(64, 48, "Mono8")).open()
              for cid in ("cam1", "cam3")}
    assert not any(cam.exposes for cam in replay.values())
    got = capture_averaged(replay, 3.0, frames=6)
    assert np.array_equal(got["cam3"].image, f.image) and got["cam3"].metadata[AVERAGED_FRAMES_KEY] == 6
    for cam in replay.values():
        cam.close()


def test_one_frame_is_the_raw_frame(tmp_path):
    config = station_config(tmp_path, width=64, height=48)
    cams = open_station_cameras(config, SimulatedStation(CleanWorld()).context())
    frames = capture_averaged(cams, 3.0, frames=1)
    assert frames["cam1"].image.dtype == np.uint8 and AVERAGED_FRAMES_KEY not in frames["cam1"].metadata


def test_configuration_bounds(tmp_path):
    from station.config import DEFAULT_CONFIG, load_config

    assert load_config(None).capture.frames_averaged >= 1
    for bad in ("0", "65", "2.5"):
        text = DEFAULT_CONFIG.read_text().replace("data_dir: ../var", f"data_dir: {tmp_path / 'var'}")
        text = re.sub(r"(?m)^  frames_averaged: \d+", f"  frames_averaged: {bad}", text)
        assert f"frames_averaged: {bad}" in text
        path = tmp_path / "station.yaml"
        path.write_text(text)
        with pytest.raises(ConfigError, match="frames_averaged"):
            load_config(path)
