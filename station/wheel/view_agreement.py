"""Do the two cameras of a pair see the same rim plane? Each view's own circle, against the pair's.

The pair's 3-D circle (station/wheel/circle_fit.py) rests on both views at once. Where one view's
edge lies off the flange edge on a whole arc (a dark lip shaded like the tyre, a glare, dust),
the pair's fit tilts toward that view's error, and nothing in its residuals shows it: the
other view does not see the arc's disparity, and the ellipse absorbs the bias. Each view alone
also determines the rim's axis: the circle of the pair's radius whose projection fits that
view's edge points best (its centre and axis free, five parameters). On a clean rim the two
views' axes agree within what a slowly varying edge bias of a few hundredths of a pixel turns
them by (a hundredth of a degree to a tenth: the nearer a view looks along the axis, the more);
a biased arc in one view turns its axis by tenths. The pair's axis lies between them, and which view
is right the pair cannot tell. It follows a view's own tilt by a share the pair's fit gives (for a
slow edge bias in that view alone, its tilt per pixel over the view's own): that share of the
excess disagreement is the axis's stated uncertainty (:func:`disagreement_covariance`); half of
it in whichever direction is the bound a wheel is refused by (:func:`disagreement_bound_covariance`).
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
    standard deviation from its points' noise, ``bias_deg_per_px`` (2,) per pixel of a slowly
    varying edge bias; ``disagreement_station``: (3,) the precision view's
    axis minus the reference view's (radians, across the pair's axis); ``pair_deg_per_px``:
    (2,) how far the pair's axis turns per pixel of the same bias in each view alone (the
    ``tilt_per_px`` of ``station.wheel.uncertainty.bias_covariance``), None where the pair's fit
    did not say."""

    axes_station: np.ndarray
    std_deg: np.ndarray
    bias_deg_per_px: np.ndarray
    disagreement_station: np.ndarray
    pair_deg_per_px: np.ndarray | None = None

    @property
    def follow(self) -> float:
        """The share of a view's own tilt the pair's axis follows, RMS over the two views
        (either may be the one that is off); 1/sqrt(2) where the pair's fit did not say."""
        if self.pair_deg_per_px is None or not np.all(self.bias_deg_per_px > 0):
            return float(np.sqrt(0.5))
        return float(np.sqrt(np.mean((np.asarray(self.pair_deg_per_px, float) / self.bias_deg_per_px) ** 2)))

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
              radius_m: float) -> tuple[np.ndarray, float, float] | None:
    """One view's own rim axis: the circle of radius ``radius_m`` whose image fits the view's
    edge points (N,2) (distorted px) best, started from the pair's circle (centre (3,), unit axis
    (3,), station frame). Returns (unit axis (3,), its standard deviation in degrees from the
    points' scatter, and per pixel of a slowly varying edge bias (modes 1 and 2 of the rim angle
    at random phases: the bias no clean edge is free of, which a view seeing its rim nearly
    face-on turns into a large tilt), or None for a view with too few points."""
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
    n, c = pose(sol.x)
    J = sol.jac
    try:
        JtJ_inv = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return None
    cov = JtJ_inv * float(sol.fun @ sol.fun) / max(len(X) - 5, 1)
    std = float(np.degrees(np.sqrt(max(cov[0, 0] + cov[1, 1], 0.0) / 2)))
    # a slowly varying edge bias of 1 px: modes 1 and 2 of the angle about the rim's image
    # centre, each at a random phase (cos and sin halves), through the solution dp = -(J'J)^-1 J' r
    cc = R @ c + t
    phi = np.arctan2(X[:, 1] - cc[1] / cc[2], X[:, 0] - cc[0] / cc[2])
    modes = np.column_stack([np.cos(phi), np.sin(phi), np.cos(2 * phi), np.sin(2 * phi)])  # (N,4)
    tilts = (JtJ_inv @ (J.T @ modes))[:2]                                                    # (2,4)
    per_px = float(np.degrees(np.sqrt(np.sum(tilts ** 2) / 2 / 2)))  # per direction across the axis
    return n, std, per_px


def view_agreement(points_px: tuple[np.ndarray, np.ndarray], cameras: tuple[CameraModel, CameraModel],
                   center_station: np.ndarray, axis_station: np.ndarray, radius_m: float,
                   pair_deg_per_px: tuple[float, float] | None = None) -> ViewAgreement | None:
    """Both views' own axes (:func:`view_axis`) for the pair's circle, or None if a view has
    none; ``pair_deg_per_px``: the pair's fit's tilt per pixel of each view's slow edge bias
    (``WheelFit.tilt_per_px_views``)."""
    center = np.asarray(center_station, float)
    axis = np.asarray(axis_station, float)
    own = [view_axis(p, cam, center, axis, radius_m) for p, cam in zip(points_px, cameras)]
    if any(o is None for o in own):
        return None
    axes = np.array([o[0] for o in own])
    d = axes[0] - axes[1]
    d -= axis * (d @ axis)  # across the pair's axis
    return ViewAgreement(axes_station=axes, std_deg=np.array([o[1] for o in own]),
                         bias_deg_per_px=np.array([o[2] for o in own]), disagreement_station=d,
                         pair_deg_per_px=None if pair_deg_per_px is None else np.asarray(pair_deg_per_px, float))


def disagreement_covariance(agreement: ViewAgreement | None, edge_bias_px: float) -> np.ndarray:
    """(3,3) the axis covariance (rad^2) that two disagreeing views add to the pair's axis: the
    part of their disagreement beyond what their own noise and a slowly varying edge bias of
    ``edge_bias_px`` (``measurement.view_edge_bias_px``) explain, times the share of a view's own
    tilt the pair's axis follows (``ViewAgreement.follow``), spread over the two directions
    across the axis. The pair's fit errs toward the wrong view's arc, whose bias tilts it in a
    direction of its own (on the simulated station's dark rims mostly in camber where the views
    disagreed in toe): the disagreement says how much, not which way. Zero when they agree.

    The pair's fit rests on both views, so it follows a view's own tilt by 0.38-0.5 of it (the
    median wheel of six rim scenarios); half the disagreement in each direction would count
    that share about twice over, and would state the wheels whose views disagree 1.7-3 times their
    error (docs/history/accuracy.md)."""
    excess2 = _excess2(agreement, edge_bias_px)
    if excess2 <= 0:
        return np.zeros((3, 3))
    return (excess2 * agreement.follow ** 2 / 2) * _across(agreement)


def disagreement_bound_covariance(agreement: ViewAgreement | None, edge_bias_px: float) -> np.ndarray:
    """(3,3) the bound a wheel is refused by (station/stated_uncertainty.py): half the excess
    disagreement (:func:`disagreement_covariance`) as a standard deviation in every direction
    across the axis, the pair's fit as far as halfway toward the view that is off and all of it
    in the angle at hand. On gunmetal and polished rims a disagreement just beyond its expected
    size already marks a biased arc; refused by the stated share instead, a gunmetal wheel 0.027
    deg off in camber would be reported at 0.008 (docs/history/accuracy.md)."""
    excess2 = _excess2(agreement, edge_bias_px)
    if excess2 <= 0:
        return np.zeros((3, 3))
    return (excess2 / 4) * _across(agreement)


def _excess2(agreement: ViewAgreement | None, edge_bias_px: float) -> float:
    """The squared disagreement (rad^2) beyond what the views' noise and an edge bias of
    ``edge_bias_px`` explain, 0 without an agreement. What is subtracted from the squared
    disagreement (two directions) is one direction's expected variance, half its expected
    square: on gunmetal and polished rims a disagreement just beyond its expected size already
    marks a biased arc (subtracting the whole expected square took wheels 0.1-0.2 deg off:
    docs/history/accuracy.md, "Why held-out B states toe 1.7 times its error")."""
    if agreement is None:
        return 0.0
    size = float(np.linalg.norm(agreement.disagreement_station))
    expected2 = float(np.sum(np.radians(agreement.std_deg) ** 2)
                      + np.sum(np.radians(edge_bias_px * agreement.bias_deg_per_px) ** 2))
    return size * size - expected2


def _across(agreement: ViewAgreement) -> np.ndarray:
    """(3,3) the projector across the views' mean axis."""
    a = agreement.axes_station.sum(axis=0)
    a /= np.linalg.norm(a)
    return np.eye(3) - np.outer(a, a)
