"""Aravis buffers to numpy, without a camera: formats, byte order, Bayer tiles, corrupt buffers."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.aravis import PFNC, AravisCamera
from drivers.base import CameraSettings
from drivers.errors import FrameError


class _Buf:
    def __init__(self, data: bytes, w: int, h: int, fmt: str | int):
        self.data, self.w, self.h = data, w, h
        self.code = PFNC[fmt] if isinstance(fmt, str) else fmt

    def get_image_pixel_format(self):
        return self.code

    def get_image_width(self):
        return self.w

    def get_image_height(self):
        return self.h

    def get_image_data(self):
        return self.data


def _cam(fmt):
    return AravisCamera("cam5", "aravis://192.0.2.5", CameraSettings(8, 6, fmt))


def test_mono8_and_mono16_little_endian():
    img = np.arange(48, dtype=np.uint8).reshape(6, 8)
    out = _cam("Mono8")._to_numpy(_Buf(img.tobytes(), 8, 6, "Mono8"))
    assert np.array_equal(out, img) and out.flags.writeable
    img16 = (np.arange(48, dtype=np.uint16) * 1000).reshape(6, 8)
    out16 = _cam("Mono16")._to_numpy(_Buf(img16.astype("<u2").tobytes(), 8, 6, "Mono16"))
    assert out16.dtype == np.uint16 and np.array_equal(out16, img16)


@pytest.mark.parametrize("fmt,tile", [("BayerRG8", [[200, 100], [100, 0]]), ("BayerBG8", [[0, 100], [100, 200]]),
                                      ("BayerGR8", [[100, 200], [0, 100]]), ("BayerGB8", [[100, 0], [200, 100]])])
def test_bayer_tiles_give_the_same_grey(fmt, tile):
    """A flat scene R=200, G=100, B=0 seen through each GenICam tile: one grey level everywhere.

    OpenCV's two-letter Bayer names are shifted by a pixel against GenICam's; the wrong code
    would swap R and B and give 0.299*0 + 0.587*100 + 0.114*200 = 81 instead of 119."""
    mosaic = np.tile(np.array(tile, np.uint8), (3, 4))
    out = _cam(fmt)._to_numpy(_Buf(mosaic.tobytes(), 8, 6, fmt))
    assert out.shape == (6, 8) and out.dtype == np.uint8
    expect = round(0.299 * 200 + 0.587 * 100 + 0.114 * 0)
    assert abs(int(np.median(out[2:4, 2:6])) - expect) <= 1


def test_wrong_format_and_short_buffer_are_frame_errors():
    with pytest.raises(FrameError, match="cam5: the camera sent Mono16, configured for Mono8"):
        _cam("Mono8")._to_numpy(_Buf(bytes(96), 8, 6, "Mono16"))
    with pytest.raises(FrameError, match="sent 0x2180014"):
        _cam("Mono8")._to_numpy(_Buf(bytes(144), 8, 6, 0x02180014))  # RGB8
    with pytest.raises(FrameError, match="corrupt buffer .* 40 bytes for a 8x6 Mono8 image"):
        _cam("Mono8")._to_numpy(_Buf(bytes(40), 8, 6, "Mono8"))
    with pytest.raises(FrameError, match="0 bytes"):
        _cam("Mono16")._to_numpy(_Buf(None, 8, 6, "Mono16"))
