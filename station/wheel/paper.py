"""The paper's 3-D wheel (section 3.2) from one stereo pair, exactly as published.

The epipolar line of each left (precision) rim point meets the right rim curve at two points;
the one in the same order along the line is chosen; the top and bottom 10 % of the diameter
(where the lines graze the rim) are pruned (Fig. 9d); points are triangulated by eq. 24; PCA of
the 3-D rim gives the centre and the spin axis w (oriented outward from the car). Inputs are
the rim-flange edge points each camera detected (distorted pixels) and the pair's calibrated
CameraModels; outputs are in the station frame (docs/conventions.md). The station's default
is the 3-D circle fit (station/wheel/circle_fit.py); this one is kept to measure the gain.
"""

from __future__ import annotations

import numpy as np

from calibration.camera_model import CameraModel
from calibration.triangulation import homogeneous, triangulate_paper
from station.errors import MeasurementError
from station.wheel.epipolar import fit_conic, pair_relation, pair_tangency, pencil_basis
from station.wheel.fit import WheelFit, outward_sign

PRUNE_FRACTION = 0.10  # the paper's Fig. 9d: 10 % of the diameter at the top and the bottom


def line_conic_intersections(lines: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Where lines meet a conic, ordered along each line's direction (b, -a).

    lines: (N,3) homogeneous lines (a, b, c); C: (3,3). Returns (N,2,2): two points per line
    (NaN where the line misses the conic).
    """
    a, b, c = lines.T
    nrm2 = a * a + b * b
    x0 = np.stack([-a * c / nrm2, -b * c / nrm2, np.ones_like(a)], axis=1)
    u = np.stack([b, -a, np.zeros_like(a)], axis=1) / np.sqrt(nrm2)[:, None]
    A = np.einsum("ni,ij,nj->n", u, C, u)
    B = 2 * np.einsum("ni,ij,nj->n", u, C, x0)
    K = np.einsum("ni,ij,nj->n", x0, C, x0)
    disc = B * B - 4 * A * K
    with np.errstate(invalid="ignore"):
        root = np.sqrt(disc)
    s = np.stack([(-B - root) / (2 * A), (-B + root) / (2 * A)], axis=1)
    s.sort(axis=1)
    return x0[:, None, :2] + s[:, :, None] * u[:, None, :2]


def match_rim_points(xy_l: np.ndarray, xy_r: np.ndarray, R: np.ndarray, t: np.ndarray,
                     prune_fraction: float = PRUNE_FRACTION) -> tuple[np.ndarray, np.ndarray, float]:
    """Section 3.2's matching: left points -> their epipolar lines' crossings of the right rim.

    xy_l (N,2), xy_r (M,2): undistorted normalised rim points of the left and right cameras.
    R, t: the paper's pair (eqs 34-35). Returns (p_l (K,3), p_r (K,3)) matched homogeneous
    points after pruning, and the epipolar tangency residual (radians): the two epipolar planes
    tangent to the rim must be the same from both cameras; their angle differences (RMS) grow
    when a camera of the pair has moved since calibration.
    """
    C_l, C_r = fit_conic(xy_l), fit_conic(xy_r)
    p_l = homogeneous(xy_l)
    n_l = np.cross(t, p_l)                   # epipolar plane normals in the left frame (N,3)
    n_l /= np.linalg.norm(n_l, axis=1, keepdims=True)
    n_r = n_l @ R.T                          # the same planes in the right frame
    # Order of the left point among its line's two crossings of the left rim, kept on the right.
    cross_l = line_conic_intersections(n_l, C_l)
    first = np.linalg.norm(cross_l[:, 0] - xy_l, axis=1) < np.linalg.norm(cross_l[:, 1] - xy_l, axis=1)
    cross_r = line_conic_intersections(n_r, C_r)
    chosen = np.where(first[:, None], cross_r[:, 0], cross_r[:, 1])
    # Prune where the lines graze the rim: the top/bottom 10 % of the pencil of planes that cut it.
    e1, e2 = pencil_basis(t, p_l.mean(axis=0))
    theta = np.arctan(np.einsum("ni,i->n", n_l, e2) / np.einsum("ni,i->n", n_l, e1))
    (lo_l, hi_l), tangency = pair_tangency(C_l, C_r, R, e1, e2)
    span = hi_l - lo_l
    keep = (theta > lo_l + prune_fraction * span) & (theta < hi_l - prune_fraction * span)
    keep &= np.all(np.isfinite(chosen), axis=1)
    return p_l[keep], homogeneous(chosen[keep]), tangency


def reconstruct_paper(points_l_px: np.ndarray, points_r_px: np.ndarray, cam_l: CameraModel,
                      cam_r: CameraModel) -> WheelFit:
    """The paper's 3-D wheel: match, prune, triangulate (eq. 24), PCA. Station frame."""
    xy_l = cam_l.pixels_to_normalized(points_l_px)
    xy_r = cam_r.pixels_to_normalized(points_r_px)
    R, t = pair_relation(cam_l, cam_r)
    p_l, p_r, tangency = match_rim_points(xy_l, xy_r, R, t)
    if len(p_l) < 20:
        raise MeasurementError(f"{cam_l.name}/{cam_r.name}: only {len(p_l)} rim points could be matched")
    X_l = triangulate_paper(p_l, p_r, R, t)
    X = (X_l - cam_l.t_cam_station) @ cam_l.R_cam_station  # left frame -> station, (N,3)
    center = X.mean(axis=0)
    _, sv, Vt = np.linalg.svd(X - center, full_matrices=False)
    w = Vt[2]
    if w[0] * outward_sign(center) < 0:
        w = -w
    radius = float(np.mean(np.linalg.norm((X - center) - np.outer((X - center) @ w, w), axis=1)))
    f = 0.5 * (cam_l.K[0, 0] + cam_r.K[0, 0])
    # A plane-angle error d moves a rim point across its epipolar line by about f * d pixels
    # (the rays to the wheel are roughly perpendicular to the baseline).
    return WheelFit("paper", center, w, radius, points_station=X, epipolar_rms_px=tangency * f,
                    n_points=(len(points_l_px), len(points_r_px)))
