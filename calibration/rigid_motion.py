"""The rigid motion between two sets of corresponding 3-D points (Kabsch), for stereo odometry
(station/odometry/robust_vo.py) and a wheel face's motion (station/wheel/face_points.py)."""

from __future__ import annotations

import numpy as np


def kabsch(P: np.ndarray, Q: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid fit ``P ~ A Q + b`` in least squares (A a rotation), batched.

    P, Q: (..., k, 3); w: (..., k) weights or None. Returns A (..., 3, 3), b (..., 3).
    """
    P = np.asarray(P, float)
    Q = np.asarray(Q, float)
    w = np.ones(P.shape[:-1]) if w is None else np.asarray(w, float)
    w = w / w.sum(axis=-1, keepdims=True)
    cP = np.einsum("...k,...kj->...j", w, P)
    cQ = np.einsum("...k,...kj->...j", w, Q)
    H = np.einsum("...k,...ki,...kj->...ij", w, Q - cQ[..., None, :], P - cP[..., None, :])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1
    D[..., 1, 1] = 1
    D[..., 2, 2] = d
    A = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    b = cP - np.einsum("...ij,...j->...i", A, cQ)
    return A, b
