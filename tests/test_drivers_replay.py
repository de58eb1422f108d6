"""ReplayCamera: a saved cycle comes back bit for bit; every bad input is a clear error."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.base import CameraSettings, Frame
from drivers.errors import CameraMissing, CameraTimeout, DriverError, FrameError
from drivers.frame_store import save_cycle
from drivers.registry import create_camera, driver_class, uri_address

W, H = 48, 32


def _frames(seed, ids=("cam1", "cam2"), dtype=np.uint8):
    rng = np.random.default_rng(seed)
    hi = 256 if dtype == np.uint8 else 65536
    return {cid: Frame(cid, rng.integers(0, hi, (H, W)).astype(dtype), 1000 + i, 10 + i, {"exposure_us": 800})
            for i, cid in enumerate(ids)}


def _cam(uri, cam_id="cam1", fmt="Mono8", trigger="software"):
    return create_camera(cam_id, uri, CameraSettings(W, H, fmt, trigger=trigger)).open()


@pytest.mark.parametrize("dtype,fmt", [(np.uint8, "Mono8"), (np.uint16, "Mono16")])
def test_bit_for_bit(tmp_path, dtype, fmt):
    saved = _frames(1, dtype=dtype)
    d = save_cycle(tmp_path / "c1", saved)
    for cid, f in saved.items():
        cam = _cam(f"replay://{d}", cid, fmt)
        got = cam.snap(1.0)
        assert got.image.dtype == dtype and got.image.tobytes() == f.image.tobytes()
        assert got.metadata["recorded_timestamp_ns"] == f.timestamp_ns
        assert got.metadata["recorded_frame_id"] == f.frame_id
        assert got.metadata["exposure_us"] == 800
        ident = cam.identity()
        assert ident.vendor == "replay" and cid in ident.serial


def test_directory_of_cycles_in_order_then_end_or_loop(tmp_path):
    for k in range(3):
        save_cycle(tmp_path / f"c{k}", _frames(k))
    cam = _cam(f"replay://{tmp_path}?camera=cam2", "camX")
    images = [cam.snap(1.0).image for _ in range(3)]
    for k in range(3):
        assert np.array_equal(images[k], _frames(k)["cam2"].image)
    with pytest.raises(CameraMissing, match="at its end"):
        cam.snap(1.0)
    looped = _cam(f"replay://{tmp_path}?camera=cam2&loop=1", "camX")
    got = [looped.snap(1.0).image for _ in range(4)]
    assert np.array_equal(got[3], images[0])


def test_software_trigger_is_required(tmp_path):
    d = save_cycle(tmp_path / "c", _frames(0))
    cam = _cam(f"replay://{d}")
    cam.arm()
    with pytest.raises(CameraTimeout, match="cam1"):
        cam.grab(0.05)
    cam.trigger()
    assert cam.grab(0.05).image.shape == (H, W)


def test_bad_inputs_name_the_camera(tmp_path):
    with pytest.raises(CameraMissing, match="cam1: replay directory .* does not exist"):
        _cam(f"replay://{tmp_path / 'nope'}")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CameraMissing, match="no saved cycle"):
        _cam(f"replay://{tmp_path / 'empty'}")
    d = save_cycle(tmp_path / "c", _frames(0))
    with pytest.raises(CameraMissing, match="cam7.*has no frame of cam7.*cam1, cam2"):
        _cam(f"replay://{d}", "cam7")
    # wrong resolution for the configuration
    cam = create_camera("cam1", f"replay://{d}", CameraSettings(64, 64)).open()
    with pytest.raises(FrameError, match="48x32.*64x64"):
        cam.snap(1.0)
    # Mono16 configured, 8-bit saved
    with pytest.raises(FrameError, match="Mono16"):
        _cam(f"replay://{d}", fmt="Mono16").snap(1.0)
    # a truncated PNG
    (d / "cam1.png").write_bytes((d / "cam1.png").read_bytes()[:50])
    with pytest.raises(FrameError, match="cam1.png"):
        _cam(f"replay://{d}").snap(1.0)
    # cycle.json that lies about the shape
    meta = json.loads((d / "cycle.json").read_text())
    meta["cameras"]["cam2"]["shape"] = [10, 10]
    (d / "cycle.json").write_text(json.dumps(meta))
    with pytest.raises(FrameError, match="corrupt"):
        _cam(f"replay://{d}", "cam2").snap(1.0)


def test_registry_and_addresses(tmp_path):
    with pytest.raises(DriverError, match="unknown camera URI scheme.*sim://, replay://, aravis://, v4l2://"):
        driver_class("gige://10.0.0.1")
    with pytest.raises(DriverError, match="unknown camera URI scheme"):
        driver_class("/dev/video0")
    assert uri_address("aravis://127.0.0.2/") == uri_address("aravis://127.0.0.2")
    assert uri_address(f"replay://{tmp_path}", "cam1") != uri_address(f"replay://{tmp_path}", "cam2")
    assert uri_address(f"replay://{tmp_path}?camera=cam2", "cam1") == uri_address(f"replay://{tmp_path}/", "cam2")
