"""A front wheel's steering axis from its full pose at several steer positions.

Steered with the brake held, the wheel turns as a rigid body about its kingpin (steering) axis.
Its pose at each position is its rim's 3-D circle (the normal a, the centre c) and how far the
rim's face has turned about a since the reference position (psi, from the face's pattern:
station/wheel/rim_pattern.py). With the ring basis (e1, e2) of a (rim_pattern.ring_basis), the
body's frame is ``B = [f, a x f, a]``, ``f = cos(psi) e1 + sin(psi) e2``: the direction of the
reference's e1 carried along by the body. Between positions the body turned by ``B_k B_0^T``.

:func:`fit_steering_axis` finds the unit axis u and each position's steer angle delta_k for
which ``B_k = Rot(u, delta_k) B_0`` best (generalised least squares on the rotation vectors,
each position's weighted by its normal's and its turn's uncertainty), and the axis' point from
the centres: ``c_k = p + Rot(u, delta_k) (c_0 - p)``. From the normals alone (psi unknown) the
axis is weak across the wheel (SAI: the turn about the wheel's own axis carries it); the face's
turn fixes it.

Shapes: normals (K,3) unit outward; psi (K,) rad; centres (K,3) m; covariances (K,3,3) rad^2
(normals) and (K,) rad^2 (psi); frames (K,3,3) with columns f, a x f, a.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from station.wheel.rim_pattern import ring_basis
from station.wheel.runout import rotation_matrix
from station.wheel.uncertainty import axis_basis, normal_from


@dataclass(frozen=True)
class SteeringAxis:
    """The fitted steering axis: unit direction (3,) pointing up, its (3,3) covariance; a point on
    it (3,) (the one nearest the reference centre); each position's steer angle about it (K,)
    (deg, right-handed about the upward axis: + turns the wheel's front to the left); the pose
    misfit (deg RMS)."""

    direction_station: np.ndarray
    cov_direction: np.ndarray
    point_station: np.ndarray
    steer_deg: np.ndarray
    misfit_deg: float


def body_frames(normals: np.ndarray, psi_rad: np.ndarray) -> np.ndarray:
    """(K,3,3) the wheel's body frames from its rim normals (K,3) and its face's turns (K,)."""
    out = []
    for a, psi in zip(np.asarray(normals, float), np.asarray(psi_rad, float)):
        a = a / np.linalg.norm(a)
        e1, e2 = ring_basis(a)
        f = np.cos(psi) * e1 + np.sin(psi) * e2
        out.append(np.stack([f, np.cross(a, f), a], axis=1))
    return np.array(out)


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """(3,) the rotation vector (axis x angle, rad) of the rotation matrix R (3,3)."""
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2
    s = np.linalg.norm(w)
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    angle = np.arctan2(s, c)
    return w * (angle / s) if s > 1e-12 else w


def fit_steering_axis(normals: np.ndarray, psi_rad: np.ndarray, centers: np.ndarray,
                      cov_normals: np.ndarray | None = None, var_psi: np.ndarray | None = None,
                      reference: int = 0) -> SteeringAxis:
    """The steering axis of a wheel seen at K >= 3 steer positions (normals (K,3), face turns
    psi (K,) rad relative to position ``reference``, centres (K,3)). ``cov_normals`` (K,3,3) and
    ``var_psi`` (K,) weigh each position and give the axis' covariance (without them every
    position counts alike and no covariance is stated)."""
    B = body_frames(normals, psi_rad)
    K = len(B)
    rel = np.array([rotation_vector(B[k] @ B[reference].T) for k in range(K)])        # (K,3)
    u0 = _principal_direction(rel)
    basis = axis_basis(u0)
    delta0 = rel @ u0
    whiten = _whitening(B, cov_normals, var_psi)
    others = [k for k in range(K) if k != reference]

    def residuals(p):
        u = normal_from(p[:2], *basis)
        B0 = rotation_matrix_from_vector(p[2:5]) @ B[reference]
        delta = np.zeros(K)
        delta[others] = p[5:]
        res = [whiten[k] @ rotation_vector(B[k] @ (rotation_matrix(u, delta[k]) @ B0).T) for k in range(K)]
        return np.concatenate(res)

    x0 = np.concatenate([np.zeros(5), delta0[others]])
    sol = least_squares(residuals, x0, method="lm", xtol=1e-15, ftol=1e-15)
    u = normal_from(sol.x[:2], *basis)
    delta = np.zeros(K)
    delta[others] = sol.x[5:]
    if u[2] < 0:
        u, delta = -u, -delta
    cov = np.full((3, 3), np.nan)
    if cov_normals is not None:
        cov_p = np.linalg.pinv(sol.jac.T @ sol.jac)
        h = 1e-7
        J = np.stack([(normal_from(sol.x[:2] + h * e, *basis) - normal_from(sol.x[:2] - h * e, *basis)) / (2 * h)
                      for e in np.eye(2)], axis=1)                                       # (3,2)
        cov = J @ cov_p[:2, :2] @ J.T
    B0 = rotation_matrix_from_vector(sol.x[2:5]) @ B[reference]
    misfit = np.array([rotation_vector(B[k] @ (rotation_matrix(u, delta[k]) @ B0).T) for k in range(K)])
    point = _axis_point(u, delta, np.asarray(centers, float), reference)
    return SteeringAxis(u, cov, point, np.degrees(delta), float(np.degrees(np.sqrt(np.mean(np.sum(misfit ** 2, 1))))))


def rotation_matrix_from_vector(v: np.ndarray) -> np.ndarray:
    """(3,3) the rotation of rotation vector v (3,) (rad)."""
    angle = float(np.linalg.norm(v))
    return np.eye(3) if angle < 1e-15 else rotation_matrix(np.asarray(v) / angle, angle)


def _principal_direction(rotation_vectors: np.ndarray) -> np.ndarray:
    """(3,) the unit direction the rotation vectors (K,3) lie along (pointing up)."""
    _, _, vt = np.linalg.svd(rotation_vectors)
    u = vt[0]
    return u if u[2] >= 0 else -u


def _whitening(B: np.ndarray, cov_normals: np.ndarray | None, var_psi: np.ndarray | None) -> np.ndarray:
    """(K,3,3) per position: the map from a rotation-vector residual to whitened components:
    across the rim normal by the normal's covariance, about it by the face turn's variance."""
    out = []
    for k, frame in enumerate(B):
        a = frame[:, 2]
        P = frame.T                      # rows f, a x f, a: residual in the body's axes
        if cov_normals is None:
            out.append(P)
            continue
        # a tilt of the normal by t (3, across a) is the rotation a x t; its covariance
        A = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        C = A @ cov_normals[k] @ A.T + np.outer(a, a) * float(var_psi[k])
        C_body = P @ C @ P.T
        vals, vecs = np.linalg.eigh(C_body)
        out.append((vecs / np.sqrt(np.maximum(vals, 1e-20))) @ vecs.T @ P)
    return np.array(out)


def _axis_point(u: np.ndarray, delta: np.ndarray, centers: np.ndarray, reference: int) -> np.ndarray:
    """(3,) the point of the axis nearest the reference centre: c_k = p + Rot_k (c_0 - p) in
    least squares, p across u."""
    rows, rhs = [], []
    for k, d in enumerate(delta):
        R = rotation_matrix(u, d)
        rows.append(np.hstack([R, np.eye(3) - R]))
        rhs.append(centers[k])
    A, b = np.vstack(rows), np.concatenate(rhs)
    # p along u is free: fix it by p . u = c_ref . u (a row weighted like the others)
    A = np.vstack([A, np.concatenate([np.zeros(3), u])])
    b = np.concatenate([b, [centers[reference] @ u]])
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    return x[3:]
