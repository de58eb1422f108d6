"""Epipolar geometry of a camera pair and the rim: the planes through the baseline that touch it.

Both cameras of a pair see the same two epipolar planes tangent to the 3-D rim circle (the
paper's section 2.5). The angle between the planes found from the left and the right image,
times the focal length, is the pair's epipolar tangency residual (px): the station's check
that a camera has not moved since calibration (docs/measurement.md, "Calibration drift").
Where a camera did not see the rim near the points those planes touch, the tangents are
extrapolated and the check is not made (``tangent_point_gaps_deg``).
"""

from __future__ import annotations

import numpy as np

from calibration.camera_model import CameraModel
from calibration.triangulation import homogeneous
from station.errors import MeasurementError
from station.rim.ellipse_fit import fit_direct


def pair_relation(cam_l: CameraModel, cam_r: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """The paper's stereo extrinsics (eqs 34-35): R = R_r R_l^T, t = t_l - R^T t_r."""
    R = cam_r.R_cam_station @ cam_l.R_cam_station.T
    t = cam_l.t_cam_station - R.T @ cam_r.t_cam_station
    return R, t


def fit_conic(xy: np.ndarray) -> np.ndarray:
    """Direct least-squares ellipse (Fitzgibbon, the rim detector's) through (N,2) points, as
    the (3,3) conic C with x^T C x = 0 for homogeneous points on it (unit norm)."""
    M = fit_direct(xy).conic_matrix()
    return M / np.linalg.norm(M)


def pair_tangency(C_l: np.ndarray, C_r: np.ndarray, R: np.ndarray, e1: np.ndarray, e2: np.ndarray):
    """((lo, hi) the left cone's tangent epipolar plane angles, RMS difference (rad) of the
    right cone's from them)."""
    lo_l, hi_l = _tangent_planes(C_l, e1, e2)
    lo_r, hi_r = _tangent_planes(R.T @ C_r @ R, e1, e2)  # right conic as a cone in the left frame
    return (lo_l, hi_l), float(np.sqrt(((lo_l - lo_r) ** 2 + (hi_l - hi_r) ** 2) / 2))


def epipolar_tangency_px(xy_l: np.ndarray, xy_r: np.ndarray, cam_l: CameraModel, cam_r: CameraModel) -> float:
    """The pair's epipolar tangency residual (px, as in ``reconstruct_paper``) of the rims
    through the normalised points xy_l (N,2) and xy_r (M,2)."""
    R, t = pair_relation(cam_l, cam_r)
    e1, e2 = pencil_basis(t, homogeneous(xy_l).mean(axis=0))
    _, tangency = pair_tangency(fit_conic(xy_l), fit_conic(xy_r), R, e1, e2)
    return tangency * 0.5 * (cam_l.K[0, 0] + cam_r.K[0, 0])


def epipolar_tangent_points(xy: np.ndarray, epipole: np.ndarray):
    """The two points (2,2) where lines from the ``epipole`` (3,) (homogeneous, normalised
    coordinates) touch the ellipse through normalised points xy (N,2), and that ellipse; None
    when the epipole is not outside it. They lie on the epipole's polar line C e."""
    e = fit_direct(xy)
    C = e.conic_matrix()
    a, b, c = C @ epipole
    n2 = a * a + b * b
    p0 = np.array([-a * c / n2, -b * c / n2, 1.0])                   # the polar's point nearest the origin
    d = np.array([-b, a, 0.0]) / np.sqrt(n2)                          # and its direction
    qa, qb, qc = d @ C @ d, 2 * d @ C @ p0, p0 @ C @ p0
    disc = qb * qb - 4 * qa * qc
    if not disc > 0:
        return None
    roots = (-qb + np.array([-1.0, 1.0]) * np.sqrt(disc)) / (2 * qa)
    return p0[:2][None, :] + roots[:, None] * d[None, :2], e


def tangent_point_gaps_deg(xy_l: np.ndarray, xy_r: np.ndarray, cam_l: CameraModel, cam_r: CameraModel) -> np.ndarray:
    """(4,) for each point where an epipolar plane touches the rim (two per view), how far
    (degrees of the ellipse parameter) it lies from the nearest of the view's rim points
    xy (N,2) (normalised): the epipolar check measures the tangents there, and interpolates
    them only where the rim was seen near those points. NaN where no tangent point exists."""
    R, t = pair_relation(cam_l, cam_r)
    gaps = []
    for xy, epipole in ((xy_l, t), (xy_r, -R @ t)):   # the other camera's centre in this one's frame
        found = epipolar_tangent_points(xy, epipole)
        if found is None:
            gaps += [np.nan, np.nan]
            continue
        feet, e = found
        le = e.to_local(np.vstack([feet, xy]))
        ang = np.arctan2(le[:, 1] / e.axes_px[1], le[:, 0] / e.axes_px[0])
        diff = np.abs(np.angle(np.exp(1j * (ang[:2, None] - ang[None, 2:]))))  # (2,N)
        gaps += list(np.degrees(diff.min(axis=1)))
    return np.array(gaps)


def pencil_basis(t: np.ndarray, toward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals e1, e2 spanning the epipolar planes (all contain t); e1's plane contains
    the direction ``toward`` (the rim), so the rim's planes have small angles."""
    tu = t / np.linalg.norm(t)
    e1 = np.cross(tu, toward)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(tu, e1)


def _tangent_planes(C: np.ndarray, e1: np.ndarray, e2: np.ndarray) -> tuple[float, float]:
    """Angles (rad) of the two epipolar planes n = cos a e1 + sin a e2 tangent to the cone x^T C x = 0.

    A plane n^T x = 0 touches the cone when n^T C* n = 0 (C* the adjugate, the dual conic).
    """
    C_dual = np.linalg.inv(C) * np.linalg.det(C)
    E = np.stack([e1, e2], axis=1)
    M = E.T @ C_dual @ E
    disc = M[0, 1] ** 2 - M[0, 0] * M[1, 1]
    if disc <= 0:
        raise MeasurementError("the epipolar planes miss the rim: the pair's calibration does not fit the images")
    roots = np.arctan((-M[0, 1] + np.array([-1.0, 1.0]) * np.sqrt(disc)) / M[1, 1])
    return float(roots.min()), float(roots.max())
