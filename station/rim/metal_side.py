"""Is the bright side of a rim edge the rim's metal? The share of a rim where it is not.

The detector follows a bright-inside, dark-outside step round the rim. At the flange edge the
bright side is the lip's metal, brighter than the tyre for some pixels inward. Under one harsh
lamp that need not hold: where the light strikes the tyre's shoulder and grazes the lip (the
arch's shadow, a low sun), the tyre just outside the flange is lit brighter than the lip, and
the step the detector finds is the lit shoulder's outer fall, 1-5 px beyond the flange. A lip
dirty or shaded as dark as the tyre, or a glossy lip mirroring something dark, does the same.
Such a profile is a bright line, not an edge: a few pixels inward the image drops to the lip's
shade, no brighter than the tyre beyond the step.

The test, per edge point: somewhere ``INNER_REACH_PX`` inside the edge the image is no brighter
than the mean of ``TYRE_SIDE_PX`` outside it. An arc of ``ARC_DEG`` where ``WRONG_SHARE`` of the
points fail it is an arc whose edge is not the rim's; :func:`dark_side_share` is the share of
the rim's points on such arcs (``details["metal_side_dark_share"]`` of a detection). The
measurement names the camera with such arcs when a pair's views disagree (station/stated_uncertainty.py).
"""

from __future__ import annotations

import numpy as np

from station.rim.ellipse import Ellipse
from station.rim.preprocess import PixelMap
from station.rim.subpixel import sample_profiles

INNER_REACH_PX = (1.5, 6.0)   # inside the edge: where the metal must stay brighter than the tyre
TYRE_SIDE_PX = (1.5, 3.0)     # outside the edge: the tyre's level beside it
STEP_PX = 0.5
ARC_DEG = 10.0
WRONG_SHARE = 0.3             # of an arc's points failing: an arc whose edge is not the rim's, not noise


def metal_brighter(grey: np.ndarray, points_px: np.ndarray, normals_px: np.ndarray) -> np.ndarray:
    """(N,) bool: at each edge point (N,2) (image pixels of ``grey``, float32), with unit outward
    normals (N,2), the image ``INNER_REACH_PX`` inside stays brighter than the tyre
    ``TYRE_SIDE_PX`` outside."""
    s = np.arange(-INNER_REACH_PX[1], TYRE_SIDE_PX[1] + STEP_PX / 2, STEP_PX)
    prof = sample_profiles(grey, points_px, normals_px, s)                  # (N,S)
    inner = (s >= -INNER_REACH_PX[1]) & (s <= -INNER_REACH_PX[0])
    tyre = (s >= TYRE_SIDE_PX[0]) & (s <= TYRE_SIDE_PX[1])
    return prof[:, inner].min(axis=1) > prof[:, tyre].mean(axis=1)


def wrong_arcs(angle_rad: np.ndarray, bright: np.ndarray) -> np.ndarray:
    """(N,) bool: the points (at angles (N,) rad round the rim) on arcs of ``ARC_DEG`` where at
    least ``WRONG_SHARE`` of the points failed :func:`metal_brighter` (``bright`` (N,))."""
    n_arcs = int(round(360.0 / ARC_DEG))
    arc = ((np.asarray(angle_rad) % (2 * np.pi)) / (2 * np.pi) * n_arcs).astype(int) % n_arcs
    count = np.bincount(arc, minlength=n_arcs)
    failed = np.bincount(arc, weights=(~np.asarray(bright)).astype(float), minlength=n_arcs)
    return ((count > 0) & (failed >= WRONG_SHARE * count))[arc]


def dark_side_share(grey: np.ndarray, ellipse: Ellipse, points_px: np.ndarray, pmap: PixelMap) -> float:
    """Share of the edge points (N,2) (image pixels of ``grey``) of the fitted ``ellipse`` (ideal
    pixels of ``pmap``) on arcs whose bright side is not the rim's metal (:func:`wrong_arcs`)."""
    if len(points_px) == 0:
        return 0.0
    ideal = pmap.undistort(points_px)
    _, t = ellipse.distance(ideal)
    _, normals, _ = pmap.along_normals(ideal, ellipse.normal_at(t))
    return float(np.mean(wrong_arcs(t, metal_brighter(grey, points_px, normals))))
