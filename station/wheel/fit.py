"""One wheel as a 3-D circle in the station frame: what both 3-D methods return.

Shapes: centre (3,), axis (3,) unit outward from the car (docs/conventions.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class WheelFit:
    """One wheel in the station frame. Shapes: center (3,), axis (3,) unit outward."""

    method: str
    center_station: np.ndarray
    axis_station: np.ndarray
    radius_m: float
    points_station: np.ndarray | None = None  # (N,3) triangulated rim (paper method)
    cov_center: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    cov_axis: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    reprojection_rms_px: float = float("nan")
    epipolar_rms_px: float = float("nan")
    n_points: tuple[int, int] = (0, 0)
    view_median_px: tuple[float, float] = (float("nan"), float("nan"))  # median |residual| per view
    calibration_share: tuple[float, float] | None = None  # traces of the calibration's (centre m^2, axis) covariance
    grazing_left_out: bool = False  # fitted without the points seen across the lip at a grazing angle
    arcs_left_out: bool = False  # arcs that do not follow the circle of the other half of the rim left out
    faint_left_out: bool = False  # fitted without the points of faint edge step (_without_faint)
    tangent_gap_deg: tuple[float, float] = (float("nan"), float("nan"))  # per view, the larger of its
    # tangent_point_gaps_deg on all its rim points: whether it saw the rim where the epipolar planes touch
    other_contour_mm: float | None = None  # some on another concentric contour, this much outside (station/wheel/other_contour.py)
    cov_axis_noise: np.ndarray | None = None  # (3,3) the part of cov_axis from the points' noise alone
    cov_axis_bias_views: tuple | None = None  # ((3,3), (3,3)) each view's own edge-bias part of cov_axis
    tilt_per_px_views: tuple | None = None  # (2,) deg the axis turns per px of one view's slow edge bias



def outward_sign(center_station: np.ndarray) -> float:
    """+1 for a right-hand wheel (x > 0), -1 for a left-hand one."""
    return 1.0 if center_station[0] >= 0 else -1.0
