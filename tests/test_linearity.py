"""Whether a camera's grey is proportional to light, from its burst's noise
(station/capture/linearity.py): a linear sensor's noise never falls as the light grows; an
sRGB-encoding camera read as linear shows it falling, and the cycle names the camera."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from camera_fakes import IDS, station_config
from simulators.sim_station import SimulatedStation
from station.capture.cameras import open_station_cameras
from station.capture.frame_average import NOISE_KEY, averaged_frames, noise_by_level
from station.capture.linearity import FALLING_SLOPE, noise_slope, response_warnings
from station.capture.sync import capture_averaged
from station.plc import register_map as rm
from station.plc.results import result_station_warning_bits
from station.result import Measurement, WarningFlag
from test_frame_average import CleanWorld

RAMP = np.tile(np.linspace(10, 240, 512, dtype=np.float32), (256, 1))  # (256, 512) light, 8-bit scale


def _burst(gamma=1.0, read=2.0, shot=0.0, n=8, seed=0):
    """n 8-bit frames of RAMP with read noise ``read`` and shot noise ``shot`` sqrt(light), encoded
    grey = 255 (light / 255)^gamma after the noise, as a camera encodes it."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        light = np.clip(RAMP + rng.standard_normal(RAMP.shape) * np.sqrt(read ** 2 + shot ** 2 * RAMP), 0, 255)
        out.append(np.rint(255 * (light / 255) ** gamma).astype(np.uint8))
    return out


@pytest.mark.parametrize("gamma,read,shot,configured,lo,hi", [
    (1.0, 2.0, 0.0, 1.0, -0.1, 0.1),     # linear, read noise: flat
    (1.0, 0.5, 0.35, 1.0, 0.35, 0.55),   # linear, shot noise: grows as sqrt(light)
    (0.45, 2.0, 0.0, 1.0, -1.3, -1.1),   # sRGB read as linear: falls as light^(gamma - 1) / gamma
    (0.45, 1.5, 0.2, 1.0, -0.9, -0.5),   # with some shot noise: still clearly falling
    (0.45, 0.5, 0.35, 1.0, -0.3, -0.05), # shot noise dominating: falls too little to tell
    (0.45, 2.0, 0.0, 0.45, -0.1, 0.1),   # sRGB and configured so: flat again
])
def test_the_noise_against_the_light_has_the_slope_the_response_gives(gamma, read, shot, configured, lo, hi):
    slope = noise_slope(noise_by_level(_burst(gamma, read, shot)), configured)
    assert lo < slope < hi


def test_a_quiet_or_flat_burst_is_not_judged():
    assert noise_slope(noise_by_level(_burst(read=0.3)), 1.0) is None  # quantisation, not noise
    flat = [np.full((64, 64), 120, np.uint8) + np.random.default_rng(k).integers(0, 3, (64, 64), dtype=np.uint8)
            for k in range(6)]
    assert noise_slope(noise_by_level(flat), 1.0) is None              # one level: no slope
    assert noise_slope([], 1.0) is None


def test_a_burst_names_its_noise_by_level_and_one_frame_does_not():
    from drivers.base import Frame

    bursts = [{"cam1": Frame("cam1", im, k, k, {})} for k, im in enumerate(_burst(n=4))]
    levels = averaged_frames(bursts)["cam1"].metadata[NOISE_KEY]
    assert len(levels) >= 10 and all(lv[1] == pytest.approx(2.0 * 257, rel=0.15) for lv in levels[1:-1])
    assert NOISE_KEY not in averaged_frames(bursts[:2])["cam1"].metadata


def test_a_simulated_srgb_camera_read_as_linear_is_named_until_it_is_configured(tmp_path):
    """cam3 of the simulated station encodes sRGB (sim://cam3?gamma=0.45); the station reads it
    as linear and names it in a warning with its flag and PLC bit; told its response_gamma, it
    does not."""
    config = station_config(tmp_path, {"cam3": "sim://cam3?gamma=0.45"}, width=256, height=192)
    world = CleanWorld(256, 192)
    cams = open_station_cameras(config, SimulatedStation(world).context())
    frames = capture_averaged(cams, 3.0, frames=6)
    warned = response_warnings(frames, config)
    assert [cid for cid, _ in warned] == ["cam3"]
    assert "its noise falls as its light grows" in warned[0][1] and "cameras.cam3.response_gamma" in warned[0][1]
    slopes = {cid: noise_slope(frames[cid].metadata[NOISE_KEY], 1.0) for cid in IDS}
    assert slopes["cam3"] < FALLING_SLOPE and all(abs(slopes[c]) < 0.15 for c in IDS if c != "cam3")
    config.cameras["cam3"] = replace(config.cameras["cam3"], response_gamma=0.45)
    assert response_warnings(frames, config) == []
    result = Measurement(station="x")
    result.warn(warned[0][1], WarningFlag("response", "FL", camera="cam3"))
    assert result_station_warning_bits(result) == (1 << rm.ANY_WARNING_BIT) | (1 << 5)
    for cam in cams.values():
        cam.close()


def test_the_screens_camera_check_names_a_camera_whose_grey_is_not_linear(tmp_path, monkeypatch):
    """The Cameras page's check takes a burst of NOISE_MIN_FRAMES and adds the same warning to
    that camera's own (the rims are not looked for here: the measurement is a stand-in)."""
    from types import SimpleNamespace

    from station.ui import camera_check

    config = station_config(tmp_path, {"cam3": "sim://cam3?gamma=0.45"}, width=256, height=192)
    cams = open_station_cameras(config, SimulatedStation(CleanWorld(256, 192)).context())
    monkeypatch.setattr(camera_check, "measure_frames", lambda images, *a, **k: Measurement(station="x"))
    station = SimpleNamespace(config=config, cameras=cams, timeout_s=3.0, trigger_board=None, models={},
                              workers=None, calibration=SimpleNamespace(pair_covariance=None))
    pngs, summary = camera_check.check_cameras(station, lambda text: None)
    warnings = {cid: c["warnings"] for cid, c in summary["cameras"].items()}
    assert len(warnings["cam3"]) == 1 and "its noise falls as its light grows" in warnings["cam3"][0]
    assert not any(w for cid, w in warnings.items() if cid != "cam3") and set(pngs) == set(IDS)
    for cam in cams.values():
        cam.close()
