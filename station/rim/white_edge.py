"""Rim edges at the sensor's white: how much of a detected rim an over-exposure cut off.

A bright rim driven to the white (a long exposure, a polished lip under a lamp) has its edge
profile cut off at the top: the blurred step's 50 % level then lies toward the dark tyre, by
half a pixel where the metal would be twice the white. ``white_share`` measures it for every
detection (``details["white_share"]``); ``station measure`` warns above
``measurement.white_edge_limit`` (docs/rim-detection.md, known limits).
"""

from __future__ import annotations

import numpy as np

WHITE_GREY = 254.5   # grey (of 0..255, also for 16-bit input) at which the sensor is at its white
WHITE_RADIUS_PX = 2  # a rim point with a white pixel this near has its edge profile cut off


def white_share(grey: np.ndarray, points_px: np.ndarray, radius: int = WHITE_RADIUS_PX) -> float:
    """Share of the rim points (N,2, image pixels of ``grey``) with a pixel at the sensor's white
    within ``radius`` px in x and y. On the simulated station an exposure 1.5x (2x) too long
    made toe 0.038 (0.072) deg RMS instead of 0.026. The cut-off profiles are not refitted
    on their samples under the white: that needs their blur, which cut-off profiles do not
    tell well (docs/rim-detection.md, known limits)."""
    if len(points_px) == 0:
        return 0.0
    h, w = grey.shape
    p = np.round(points_px).astype(int)
    lo = np.clip(p.min(axis=0) - radius, 0, [w - 1, h - 1])
    hi = np.clip(p.max(axis=0) + radius + 1, 1, [w, h])
    if not grey[lo[1]:hi[1], lo[0]:hi[0]].max() >= WHITE_GREY:  # the usual case: nothing at the white
        return 0.0
    d = np.arange(-radius, radius + 1)
    x = np.clip(p[:, 0, None, None] + d[None, None, :], 0, w - 1)    # (N,1,K)
    y = np.clip(p[:, 1, None, None] + d[None, :, None], 0, h - 1)    # (N,K,1)
    white = grey.ravel()[y * w + x] >= WHITE_GREY                   # (N,K,K): grey[y, x], by flat index
    return float(np.mean(white.any(axis=(1, 2))))
