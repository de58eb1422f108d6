"""V4L2Camera: error paths here; a real /dev/video* camera when one is connected."""

from __future__ import annotations

import glob
import os

import numpy as np
import pytest

import drivers.v4l2 as v4l2
from drivers.base import CameraSettings
from drivers.errors import CameraMissing, DriverError
from drivers.registry import create_camera

DEVICES = sorted(glob.glob("/dev/video*"))


def _cam(path, **kw):
    return create_camera("cam2", f"v4l2://{path}", CameraSettings(**{"width": 640, "height": 480, **kw}))


def test_no_device():
    with pytest.raises(CameraMissing, match="cam2: no device /dev/video97") as e:
        _cam("/dev/video97").open()
    assert "ls /dev/video" in e.value.hint


def test_not_a_v4l2_device():
    # /dev/null is a character device that answers VIDIOC_QUERYCAP with ENOTTY
    with pytest.raises(DriverError, match="cam2: /dev/null is not a V4L2 device"):
        _cam("/dev/null").open()


class _FakeCapture:
    """cv2.VideoCapture as OpenCV behaves for a busy device or a format it cannot give."""

    opened = True
    width, height = 640, 480

    def __init__(self, *a):
        self.props = {}

    def isOpened(self):
        return self.opened

    def set(self, prop, value):
        if prop not in (v4l2.cv2.CAP_PROP_FRAME_WIDTH, v4l2.cv2.CAP_PROP_FRAME_HEIGHT):
            self.props[prop] = value
        return True

    def get(self, prop):
        if prop == v4l2.cv2.CAP_PROP_FRAME_WIDTH:
            return self.width
        if prop == v4l2.cv2.CAP_PROP_FRAME_HEIGHT:
            return self.height
        if prop == v4l2.cv2.CAP_PROP_FOURCC:
            return v4l2.cv2.VideoWriter_fourcc(*"YUYV")
        return self.props.get(prop, 0)

    def read(self):
        return True, np.full((self.height, self.width, 3), 77, np.uint8)

    def release(self):
        pass


@pytest.fixture
def fake_device(monkeypatch, tmp_path):
    """A path that exists and answers QUERYCAP as a capture device; OpenCV replaced by a fake."""
    path = tmp_path / "video0"
    path.write_bytes(b"")
    monkeypatch.setattr(v4l2, "querycap", lambda p: {"driver": "uvcvideo", "card": "Fake UVC", "bus": "usb-1",
                                                      "caps": v4l2.V4L2_CAP_VIDEO_CAPTURE})
    monkeypatch.setattr(v4l2.cv2, "VideoCapture", _FakeCapture)
    yield str(path)
    _FakeCapture.opened, _FakeCapture.width, _FakeCapture.height = True, 640, 480


def test_busy_device(fake_device):
    _FakeCapture.opened = False
    with pytest.raises(DriverError, match="cam2: .*Fake UVC.* cannot stream: busy") as e:
        _cam(fake_device).open()
    assert "fuser" in e.value.hint


def test_unsupported_formats_and_modes(fake_device):
    _FakeCapture.width, _FakeCapture.height = 320, 240
    with pytest.raises(DriverError, match="does not offer 640x480 \\(it set 320x240\\)"):
        _cam(fake_device).open()
    _FakeCapture.width, _FakeCapture.height = 640, 480
    with pytest.raises(DriverError, match="does not offer Y16"):
        _cam(fake_device, pixel_format="Mono16").open()
    with pytest.raises(DriverError, match="unsupported pixel format BayerRG8 for a V4L2 camera"):
        _cam(fake_device, pixel_format="BayerRG8").open()
    with pytest.raises(DriverError, match="no hardware trigger input"):
        _cam(fake_device, trigger="hardware").open()


def test_colour_camera_gives_grey_frames(fake_device):
    cam = _cam(fake_device, exposure_us=5000).open()
    assert cam._cap.props[v4l2.cv2.CAP_PROP_EXPOSURE] == 50  # 100 us units
    f = cam.snap(1.0)
    assert f.image.shape == (480, 640) and f.image.dtype == np.uint8 and int(f.image[0, 0]) == 77
    assert cam.identity().model == "Fake UVC"


@pytest.mark.skipif(not DEVICES, reason="no /dev/video* device on this machine (and v4l2loopback cannot load)")
def test_real_device_snap():
    path = DEVICES[0]
    cam = create_camera("cam1", f"v4l2://{path}", CameraSettings(640, 480)).open()
    try:
        f = cam.snap(5.0)
        assert f.image.shape == (480, 640)
    finally:
        cam.close()


@pytest.mark.skipif(not DEVICES, reason="no /dev/video* device on this machine")
def test_real_device_querycap():
    info = v4l2.querycap(DEVICES[0])
    assert info["driver"] and isinstance(info["caps"], int)
    assert os.path.exists(DEVICES[0])
