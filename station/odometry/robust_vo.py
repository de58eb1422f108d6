"""A robust variant of the paper's step estimate.

Differences from :mod:`station.odometry.paper_vo`, each measurable on its own:

1. triangulation by optimal correction (``triangulate_optimal``) instead of eq. 24;
2. outlier rejection: RANSAC over minimal 3-point rigid fits, every hypothesis scored at once
   by the reprojection error of all points in the four images (pixels);
3. an orthonormal rigid fit (Kabsch/Umeyama without scale) instead of ``P Q^+``, so the step
   is a rotation and a translation, never a shear or a scale;
4. optional local refinement: the six pose parameters minimise the reprojection error of the
   inliers in all four images (robust Huber loss), which weighs far points by their real,
   image-space accuracy instead of their (poor) depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calibration.rigid_motion import kabsch
from calibration.triangulation import opencv_from_paper, triangulate_optimal
from station.odometry.paper_vo import StepEstimate


@dataclass(frozen=True)
class RobustSettings:
    """inlier_px: max reprojection error (px) of an inlier in any of the four images.
    hypotheses: RANSAC samples. refine: run the reprojection refinement. min_inliers: fewer
    make the step fail. seed: RANSAC's random generator (fixed: results are reproducible)."""

    inlier_px: float = 2.0
    hypotheses: int = 300
    refine: bool = True
    min_inliers: int = 8
    seed: int = 0


@dataclass
class _Obs:
    """The four observations of k points (normalised xy, (k,2) each) and the pair."""

    l0: np.ndarray
    r0: np.ndarray
    l1: np.ndarray
    r1: np.ndarray
    R_rl: np.ndarray
    t_rl: np.ndarray


def _proj(X: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(X[..., 2:] > 1e-9, X[..., 2:], np.nan)
        return X[..., :2] / z


def residuals(A: np.ndarray, b: np.ndarray, P: np.ndarray, Q: np.ndarray, obs: _Obs) -> np.ndarray:
    """Reprojection residuals (..., k, 8) in normalised units, for ``P = A Q + b``.

    Q (step i) mapped into step i-1 against its left/right observations, and P (step i-1)
    mapped into step i against its. A: (..., 3, 3), b: (..., 3). Behind-camera: NaN.
    """
    Q0 = np.einsum("...ij,kj->...ki", A, Q) + b[..., None, :]
    P1 = np.einsum("...ji,...kj->...ki", A, P[None] - b[..., None, :] if A.ndim == 3 else P - b)
    parts = [_proj(Q0) - obs.l0, _proj(Q0 @ obs.R_rl.T + obs.t_rl) - obs.r0,
             _proj(P1) - obs.l1, _proj(P1 @ obs.R_rl.T + obs.t_rl) - obs.r1]
    return np.concatenate(parts, axis=-1)


def _worst_px(res: np.ndarray, f: float) -> np.ndarray:
    r = res.reshape(res.shape[:-1] + (4, 2))
    err = np.linalg.norm(r, axis=-1).max(axis=-1) * f
    return np.where(np.isfinite(err), err, np.inf)


def robust_step(p_l_prev: np.ndarray, p_r_prev: np.ndarray, p_l_cur: np.ndarray,
                p_r_cur: np.ndarray, R: np.ndarray, t: np.ndarray, f_px: float,
                settings: RobustSettings = RobustSettings()) -> StepEstimate | None:
    """Robust motion of one step (same inputs as ``paper_step`` plus the focal length in px).

    Returns None when fewer than ``settings.min_inliers`` points agree on a motion.
    """
    P = triangulate_optimal(p_l_prev, p_r_prev, R, t)
    Q = triangulate_optimal(p_l_cur, p_r_cur, R, t)
    ok = np.all(np.isfinite(P), axis=1) & np.all(np.isfinite(Q), axis=1) & (P[:, 2] > 0) & (Q[:, 2] > 0)
    P, Q = P[ok], Q[ok]
    k = len(P)
    if k < max(settings.min_inliers, 3):
        return None
    R_rl, t_rl = opencv_from_paper(R, t)
    obs = _Obs(p_l_prev[ok, :2], p_r_prev[ok, :2], p_l_cur[ok, :2], p_r_cur[ok, :2], R_rl, t_rl)
    rng = np.random.default_rng(settings.seed)
    samples = np.argpartition(rng.random((settings.hypotheses, k)), 3, axis=1)[:, :3]
    A, b = kabsch(P[samples], Q[samples])                           # (H,3,3), (H,3)
    worst = _worst_px(residuals(A, b, P, Q, obs), f_px)             # (H,k)
    score = (worst <= settings.inlier_px).sum(axis=1)
    best = int(np.argmax(score))
    A, b, inl = A[best], b[best], worst[best] <= settings.inlier_px
    if inl.sum() < settings.min_inliers:
        return None
    for _ in range(2):                                              # refit on the consensus
        A1, b1 = kabsch(P[inl], Q[inl], 1.0 / (P[inl, 2] ** 2 + Q[inl, 2] ** 2))
        new = _worst_px(residuals(A1, b1, P, Q, obs), f_px) <= settings.inlier_px
        if new.sum() < settings.min_inliers:
            break
        A, b, inl = A1, b1, new
    if settings.refine:
        A, b = _refine(A, b, P[inl], Q[inl], _subset(obs, inl), f_px)
        inl = _worst_px(residuals(A, b, P, Q, obs), f_px) <= settings.inlier_px
        if inl.sum() < settings.min_inliers:
            return None
        A, b = _refine(A, b, P[inl], Q[inl], _subset(obs, inl), f_px)
    return StepEstimate(A.T, b, P[inl], inl, k)


def _subset(obs: _Obs, m: np.ndarray) -> _Obs:
    return _Obs(obs.l0[m], obs.r0[m], obs.l1[m], obs.r1[m], obs.R_rl, obs.t_rl)


def _refine(A0: np.ndarray, b0: np.ndarray, P: np.ndarray, Q: np.ndarray, obs: _Obs,
            f_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Minimise the inliers' reprojection error (px, Huber at 1 px) over the 6 pose parameters."""
    def fun(x):
        A = Rotation.from_rotvec(x[:3]).as_matrix() @ A0
        r = residuals(A, b0 + x[3:], P, Q, obs) * f_px
        return np.nan_to_num(r.ravel(), nan=1e3)

    sol = least_squares(fun, np.zeros(6), loss="huber", f_scale=1.0, x_scale=[1e-3] * 3 + [1e-2] * 3)
    return Rotation.from_rotvec(sol.x[:3]).as_matrix() @ A0, b0 + sol.x[3:]
