"""Whether an image is exposed well enough to look for a rim in it: its darkest and brightest
grey levels, and a black, saturated or flat image refused with what to change."""

from __future__ import annotations

import numpy as np

from station.errors import RimNotFound
from station.rim.npfast import percentiles

BLACK_GREY = 12.0  # an image whose brightest grey level (99.5th percentile, of 255) is under this is black


def exposure_levels(grey: np.ndarray) -> tuple[float, float]:
    """The darkest and brightest grey levels (1st, 99.5th percentile) of ``grey`` (H,W), from
    about 2e4 of its pixels (enough to tell the exposure)."""
    step = max(1, int(np.sqrt(grey.size / 20000)))
    lo, hi = percentiles(grey[::step, ::step], [1.0, 99.5])
    return float(lo), float(hi)


def check_exposure(grey: np.ndarray, tag: str) -> float:
    """RimNotFound for a black, saturated or flat image; else its brightest grey level."""
    lo, hi = exposure_levels(grey)
    if hi < BLACK_GREY:
        raise RimNotFound(f"{tag}: image is black (brightest grey level {hi:.0f} of 255)",
                          hint="check the lighting, the exposure time and that the lens is uncovered")
    if lo > 243:
        raise RimNotFound(f"{tag}: image is saturated (darkest grey level {lo:.0f} of 255)",
                          hint="reduce the exposure time or gain")
    if hi - lo < 8:
        raise RimNotFound(f"{tag}: image has no contrast (grey levels {lo:.0f}..{hi:.0f})",
                          hint="check that the camera sees the wheel and is in focus")
    return hi
