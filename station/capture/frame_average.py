"""A burst of frames of the car on the lift, averaged into one image per camera.

The car stands still while a camera takes a few frames (30-100 ms apart): the rim edge stays
where it is, the sensor's read noise does not. The mean of N frames has 1/sqrt(N) of one
frame's noise, and the fractions of a grey level between them, so it is kept on the 16-bit
scale: an 8-bit grey g is 257 g there (65535 = 255 x 257, the scale ``to_grey`` reads 16-bit
images on), a 16-bit frame stays on its own. At 1.3 Mpx the noise of one frame acts on toe and
camber mostly through the detector's decisions (which arcs take which edge model), so
averaging gains more than the square root on the points alone would suggest (noise-free
images measured camber at 0.010 deg RMS, single sigma-2 frames at 0.015:
docs/history/accuracy.md). ``capture.frames_averaged`` sets N (docs/configuration.md).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drivers.base import AVERAGED_FRAMES_KEY, Frame
from drivers.errors import FrameError

SCALE_8_TO_16 = 257  # 65535 / 255


def mean_image(images: Sequence[np.ndarray]) -> np.ndarray:
    """N (H,W) uint8 or uint16 images of one camera (the same shape and type) -> their mean,
    (H,W) uint16 on the 16-bit scale (8-bit input times 257), rounded to the nearest level."""
    first = images[0]
    if any(im.shape != first.shape or im.dtype != first.dtype for im in images):
        raise FrameError("frames of one burst differ in size or pixel type "
                         f"({sorted({(im.shape, str(im.dtype)) for im in images})})",
                         hint="the camera's settings changed during the burst: capture again")
    scale = SCALE_8_TO_16 if first.dtype == np.uint8 else 1
    total = np.sum(np.stack(images), axis=0, dtype=np.uint32)
    return np.rint(total * (scale / len(images))).astype(np.uint16)


def averaged_frames(bursts: Sequence[dict[str, Frame]]) -> dict[str, Frame]:
    """[{camera id: Frame}, ...] of N synchronised sets -> {camera id: Frame} whose image is the
    mean of the camera's N frames (mean_image); timestamp and frame id of its first frame,
    its metadata plus ``averaged_frames`` (N), the N frame ids and the burst's duration."""
    out = {}
    for cam_id, first in bursts[0].items():
        frames = [b[cam_id] for b in bursts]
        md = dict(first.metadata)
        md.update({AVERAGED_FRAMES_KEY: len(frames), "burst_frame_ids": [int(f.frame_id) for f in frames],
                   "burst_ms": round((frames[-1].timestamp_ns - first.timestamp_ns) / 1e6, 3)})
        out[cam_id] = Frame(cam_id, mean_image([f.image for f in frames]), first.timestamp_ns, first.frame_id, md)
    return out
