"""A wheel's spin axis from its rim seen at several roll positions (runout compensation).

A rim's lip plane is tilted against the wheel's spin axis (lateral runout); the station measures
the lip plane's normal n. Rolled by an angle theta about its spin axis a, the rim's normal turns
with it: n_i = Rot(a, theta_i) m, m the normal at theta = 0. With each capture's roll angle known
(station/wheel/rim_pattern.py: to about 0.01 deg from the rim's face), the normals fix the axis:
:func:`fit_spin_axis` finds a and m by least squares, and the runout is the angle between them.
Without the roll angles the normals only lie on a cone about the axis, which a few positions
over a quarter turn pin down poorly (:func:`fit_cone`, kept to compare).

Shapes: normals (K,3) unit, outward; roll angles (K,) rad about the outward axis; covariances
(K,3,3) of the normals (rad^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from station.wheel.rim_pattern import ring_basis
from station.wheel.uncertainty import axis_basis, normal_from


@dataclass(frozen=True)
class SpinAxis:
    """The fitted spin axis (3,), unit outward, and its (3,3) covariance; the rim normal at roll
    0 (3,); the runout: the tilt between them (deg), its direction (deg, in the rim plane at roll
    0, from the station's up projected onto it toward axis x up), the lip's wobble across its
    diameter (mm); the normals' RMS misfit (deg)."""

    axis_station: np.ndarray
    cov_axis: np.ndarray
    normal_at_zero: np.ndarray
    runout_deg: float
    runout_phase_deg: float
    runout_mm: float
    misfit_deg: float


def rotate(axis: np.ndarray, angles_rad: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """(K,3) each vector (K,3) or one vector (3,) turned by angles_rad (K,) about the unit axis
    (3,) (Rodrigues, right-handed)."""
    a = np.asarray(axis, float)
    v = np.broadcast_to(np.asarray(vectors, float), (len(angles_rad), 3))
    c, s = np.cos(angles_rad)[:, None], np.sin(angles_rad)[:, None]
    return v * c + np.cross(a, v) * s + np.outer(v @ a, a) * (1 - c)


def rotation_matrix(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """(3,3) rotation by ``angle_rad`` about the unit ``axis`` (3,) (Rodrigues)."""
    return rotate(axis, np.full(3, angle_rad), np.eye(3)).T


def _residuals(p: np.ndarray, normals: np.ndarray, angles: np.ndarray, basis, whiten: np.ndarray) -> np.ndarray:
    """(2K,) the normals less the model's, across each normal, whitened by its covariance:
    p = (axis offsets (2), normal-at-zero offsets (2)); whiten (K,2,3)."""
    a = normal_from(p[:2], *basis)
    m = normal_from(p[2:4], *basis)
    return np.einsum("kij,kj->ki", whiten, normals - rotate(a, angles, m)).ravel()


def _whitening(normals: np.ndarray, cov_normals: np.ndarray | None) -> np.ndarray:
    """(K,2,3): per normal, the map from a 3-D residual to its two components across the normal,
    scaled by their inverse square-root covariance (plain components without covariances)."""
    out = []
    for i, n in enumerate(normals):
        e1 = np.cross(n, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        P = np.stack([e1, np.cross(n, e1)])                                        # (2,3)
        if cov_normals is None:
            out.append(P)
            continue
        vals, vecs = np.linalg.eigh(P @ cov_normals[i] @ P.T)
        out.append((vecs / np.sqrt(np.maximum(vals, 1e-20))) @ vecs.T @ P)
    return np.array(out)


def fit_spin_axis(normals: np.ndarray, roll_rad: np.ndarray, cov_normals: np.ndarray | None = None,
                  lip_radius_m: float = 0.0) -> SpinAxis:
    """The spin axis of a rim whose normals (K,3) were measured at roll angles (K,) (relative to
    any one capture; K >= 2, and the angles must differ). ``cov_normals`` (K,3,3): the normals'
    covariances: each weighs its normal (generalised least squares) and the axis' covariance is
    the fit's; without them the normals count alike and no covariance is stated. ``lip_radius_m``
    for the runout in mm."""
    n = np.asarray(normals, float)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    theta = np.asarray(roll_rad, float)
    basis = axis_basis(n.mean(axis=0))
    cov_n = None if cov_normals is None else np.asarray(cov_normals, float)
    whiten = _whitening(n, cov_n)
    sol = least_squares(_residuals, np.zeros(4), args=(n, theta, basis, whiten), method="lm", xtol=1e-15, ftol=1e-15)
    a = normal_from(sol.x[:2], *basis)
    m = normal_from(sol.x[2:4], *basis)
    cov = np.full((3, 3), np.nan) if cov_n is None else _axis_covariance(sol, basis)
    unweighted = _residuals(sol.x, n, theta, basis, _whitening(n, None))
    misfit = float(np.degrees(np.sqrt(np.mean(unweighted ** 2) * 2)))
    return spin_axis(a, cov, m, misfit, lip_radius_m)


def spin_axis(axis: np.ndarray, cov_axis: np.ndarray, normal_at_zero: np.ndarray, misfit_deg: float,
              lip_radius_m: float) -> SpinAxis:
    """The SpinAxis of spin axis ``axis`` (3,) with its (3,3) covariance and the rim normal at
    roll 0 (3,): the runout is the tilt between them."""
    a, m = np.asarray(axis, float), np.asarray(normal_at_zero, float)
    tilt = float(np.arccos(np.clip(a @ m, -1.0, 1.0)))
    e1, e2 = ring_basis(m)
    toward = a - m * (a @ m)  # the spin axis seen from the rim's normal: the rim leans away from it
    phase = float(np.degrees(np.arctan2(-(toward @ e2), -(toward @ e1)))) % 360.0 if tilt > 0 else 0.0
    return SpinAxis(a, np.asarray(cov_axis, float), m, float(np.degrees(tilt)), phase,
                    2000.0 * lip_radius_m * np.sin(tilt), misfit_deg)


def _axis_covariance(sol, basis) -> np.ndarray:
    """(3,3) covariance of the fitted axis: the whitened fit's (J^T J)^-1, carried to the axis."""
    cov_p = np.linalg.pinv(sol.jac.T @ sol.jac)
    h = 1e-7
    J_axis = np.stack([(normal_from(sol.x[:2] + h * e, *basis) - normal_from(sol.x[:2] - h * e, *basis)) / (2 * h)
                       for e in np.eye(2)], axis=1)                                # (3,2)
    return J_axis @ cov_p[:2, :2] @ J_axis.T


def fit_cone(normals: np.ndarray) -> np.ndarray:
    """(3,) the axis of the cone the normals (K,3) lie on, without roll angles: the unit a for
    which every a . n_i is the same (least squares; K >= 3)."""
    n = np.asarray(normals, float)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    basis = axis_basis(n.mean(axis=0))

    def res(p):
        d = n @ normal_from(p, *basis)
        return d - d.mean()

    return normal_from(least_squares(res, np.zeros(2), method="lm", xtol=1e-15, ftol=1e-15).x, *basis)
