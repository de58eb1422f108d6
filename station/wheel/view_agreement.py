"""Do the two cameras of a pair see the same rim plane? Each view's own circle, against the pair's.

The pair's 3-D circle (station/wheel/circle_fit.py) rests on both views at once. Where one view's
edge lies off the flange edge on a whole arc (a dark lip shaded like the tyre, a glare, dust),
the pair's fit tilts toward that view's error, and nothing in its residuals shows it: the
other view does not see the arc's disparity, and the ellipse absorbs the bias. Each view alone
also determines the rim's axis: the circle of the pair's radius whose projection fits that
view's edge points best (its centre and axis free, five parameters). On a clean rim the two
views' axes agree to a few hundredths of a degree; a biased arc in one view turns its axis by
tenths. The pair's axis lies between them, and which view is right the pair cannot tell: the
axis is uncertain by half their disagreement (:func:`disagreement_covariance`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from calibration.camera_model import CameraModel
from station.wheel.conics import circle_conic, sampson_px

MIN_VIEW_POINTS = 20  # a view with fewer edge points has no axis of its own
ON_CIRCLE_PX = 1.5  # a view's points farther than this from the pair's circle are not on the rim it rests on


@dataclass(frozen=True)
class ViewAgreement:
    """Each view's own rim axis (station frame, unit, outward like the pair's), their angle and
    direction. ``axes_station``: (2,3), (precision, reference); ``std_deg``: (2,) each own axis's
    standard deviation from its points' noise; ``disagreement_station``: (3,) the precision view's
    axis minus the reference view's (radians, across the pair's axis)."""

    axes_station: np.ndarray
    std_deg: np.ndarray
    disagreement_station: np.ndarray

    @property
    def angle_deg(self) -> float:
        return float(np.degrees(np.linalg.norm(self.disagreement_station)))


def _tangent_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) across the unit ``axis`` (3,)."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def view_axis(points_px: np.ndarray, camera: CameraModel, center_station: np.ndarray, axis_station: np.ndarray,
              radius_m: float) -> tuple[np.ndarray, float] | None:
    """One view's own rim axis: the circle of radius ``radius_m`` whose image fits the view's
    edge points (N,2) (distorted px) best, started from the pair's circle (centre (3,), unit axis
    (3,), station frame). Returns (unit axis (3,), its standard deviation in degrees from the
    points' scatter), or None for a view with too few points."""
    xy = camera.pixels_to_normalized(np.asarray(points_px, float))
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if len(xy) < MIN_VIEW_POINTS:
        return None
    X = np.column_stack([xy, np.ones(len(xy))])
    focal = 0.5 * float(camera.K[0, 0] + camera.K[1, 1])
    R, t = camera.R_cam_station, camera.t_cam_station
    e1, e2 = _tangent_basis(axis_station)

    def pose(p):  # p = (a, b, dx, dy, dz): the axis tilted by a e1 + b e2, the centre moved by d
        n = axis_station + p[0] * e1 + p[1] * e2
        return n / np.linalg.norm(n), center_station + p[2:]

    def residuals(p):
        n, c = pose(p)
        return sampson_px(circle_conic(R @ c + t, R @ n, radius_m), X, focal)

    X = X[np.abs(residuals(np.zeros(5))) <= ON_CIRCLE_PX]  # arcs the pair's fit left out (another contour, hidden)
    if len(X) < MIN_VIEW_POINTS:
        return None
    sol = least_squares(residuals, np.zeros(5), x_scale=np.full(5, 1e-3), method="lm")
    n, _ = pose(sol.x)
    JtJ = sol.jac.T @ sol.jac
    dof = max(len(X) - 5, 1)
    try:
        cov = np.linalg.inv(JtJ) * float(sol.fun @ sol.fun) / dof
    except np.linalg.LinAlgError:
        return None
    std = float(np.degrees(np.sqrt(max(cov[0, 0] + cov[1, 1], 0.0) / 2)))
    return n, std


def view_agreement(points_px: tuple[np.ndarray, np.ndarray], cameras: tuple[CameraModel, CameraModel],
                   center_station: np.ndarray, axis_station: np.ndarray, radius_m: float) -> ViewAgreement | None:
    """Both views' own axes (:func:`view_axis`) for the pair's circle, or None if a view has none."""
    center = np.asarray(center_station, float)
    axis = np.asarray(axis_station, float)
    own = [view_axis(p, cam, center, axis, radius_m) for p, cam in zip(points_px, cameras)]
    if any(o is None for o in own):
        return None
    axes = np.array([o[0] for o in own])
    d = axes[0] - axes[1]
    d -= axis * (d @ axis)  # across the pair's axis
    return ViewAgreement(axes_station=axes, std_deg=np.array([o[1] for o in own]), disagreement_station=d)


def disagreement_covariance(agreement: ViewAgreement | None, expected_deg: float) -> np.ndarray:
    """(3,3) the axis covariance (rad^2) that two disagreeing views add: half the part of their
    disagreement beyond ``expected_deg`` (what two views of a clean rim differ by,
    ``measurement.view_agreement_deg``) and beyond their own noise, as a standard deviation in
    every direction across the axis. The pair's fit errs toward the wrong view's arc, whose
    bias tilts it in a direction of its own (on the simulated station's dark rims mostly in
    camber where the views disagreed in toe): the disagreement says how much, not which way.
    Zero when they agree."""
    if agreement is None:
        return np.zeros((3, 3))
    size = float(np.linalg.norm(agreement.disagreement_station))
    expected2 = np.radians(expected_deg) ** 2 + float(np.sum(np.radians(agreement.std_deg) ** 2))
    excess2 = size * size - expected2
    if excess2 <= 0:
        return np.zeros((3, 3))
    a = agreement.axes_station.sum(axis=0)
    a /= np.linalg.norm(a)
    return (excess2 / 4) * (np.eye(3) - np.outer(a, a))
