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
FULL_SCALE_16 = 255 * SCALE_8_TO_16  # the 16-bit scale means and their noise are kept on


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


NOISE_KEY = "noise_by_level"  # a burst's temporal noise by grey level (station/capture/linearity.py)
NOISE_MIN_FRAMES = 3          # fewer frames tell too little of each pixel's noise
NOISE_BINS = 16               # grey-level bins over the camera's full scale
NOISE_MIN_PIXELS = 200        # a bin's pixels (of the subsampled grid) for its noise to count
NOISE_SAMPLE_PIXELS = 40_000  # pixels on the grid the noise is read on (a 1.3-Mpx frame: every 6th, 4 ms)


def noise_by_level(images: Sequence[np.ndarray]) -> list[list[float]]:
    """[[level, std], ...] of a burst of N >= NOISE_MIN_FRAMES (H,W) frames of one camera: each
    pixel's temporal standard deviation over the burst (on a grid of about NOISE_SAMPLE_PIXELS),
    by its mean grey level in NOISE_BINS bins of the full scale, the bin's median level and
    median std, on the 16-bit scale of ``mean_image``; bins of too few pixels left out. The
    scene stands still during a burst, so what varies from frame to frame is the sensor's
    noise: how it goes with the light tells whether the grey is proportional to light."""
    scale = SCALE_8_TO_16 if images[0].dtype == np.uint8 else 1
    step = max(1, round(float(np.sqrt(images[0].size / NOISE_SAMPLE_PIXELS))))
    stack = np.stack([im[::step, ::step] for im in images]).astype(np.float32)   # (N, h, w)
    mean = stack.mean(axis=0).ravel() * scale
    std = stack.std(axis=0, ddof=1).ravel() * scale
    bins = np.minimum((mean / FULL_SCALE_16 * NOISE_BINS).astype(int), NOISE_BINS - 1)   # (P,)
    order = np.argsort(bins, kind="stable")
    bounds = np.searchsorted(bins[order], np.arange(NOISE_BINS + 1))
    out = []
    for b in range(NOISE_BINS):
        idx = order[bounds[b]:bounds[b + 1]]
        if len(idx) >= NOISE_MIN_PIXELS:
            out.append([round(float(np.median(mean[idx])), 2), round(float(np.median(std[idx])), 3)])
    return out


def averaged_frames(bursts: Sequence[dict[str, Frame]]) -> dict[str, Frame]:
    """[{camera id: Frame}, ...] of N synchronised sets -> {camera id: Frame} whose image is the
    mean of the camera's N frames (mean_image); timestamp and frame id of its first frame,
    its metadata plus ``averaged_frames`` (N), the N frame ids, the burst's duration and, of
    NOISE_MIN_FRAMES or more, the noise by grey level (``noise_by_level``)."""
    out = {}
    for cam_id, first in bursts[0].items():
        frames = [b[cam_id] for b in bursts]
        md = dict(first.metadata)
        md.update({AVERAGED_FRAMES_KEY: len(frames), "burst_frame_ids": [int(f.frame_id) for f in frames],
                   "burst_ms": round((frames[-1].timestamp_ns - first.timestamp_ns) / 1e6, 3)})
        images = [f.image for f in frames]
        mean = mean_image(images)  # checks the frames alike first
        if len(images) >= NOISE_MIN_FRAMES:
            md[NOISE_KEY] = noise_by_level(images)
        out[cam_id] = Frame(cam_id, mean, first.timestamp_ns, first.frame_id, md)
    return out
