"""The paper's visual odometry, exactly as published (section 3.3, eqs 43-48).

Per step i: the common keypoints of the four images are triangulated by eq. 24 in the left
camera at step i-1 (``P_k``) and at step i (``Q_k``), stacked as homogeneous 4xk matrices
(eqs 43-44), and related by ``M = P Q^+`` (eq. 45, the Moore-Penrose pseudo-inverse), whose
blocks are ``[[R_bar^T, t_bar], [0, 1]]`` (eq. 46). So ``P_k = R_bar^T Q_k + t_bar``:
``t_bar`` is the camera's position at step i in the camera frame of step i-1 and ``R_bar^T``
turns step-i coordinates into step-(i-1) ones. ``M`` is a least-squares *affine* map: its
3x3 block is generally not a rotation, and the paper composes it as it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.triangulation import triangulate_paper


def homogeneous_matrix(points: np.ndarray) -> np.ndarray:
    """Eqs 43-44: (k,3) points -> the (4,k) matrix [[P_1 ... P_k], [1 ... 1]]."""
    points = np.asarray(points, float)
    return np.vstack([points.T, np.ones(len(points))])


def transform_matrix(P_hat: np.ndarray, Q_hat: np.ndarray) -> np.ndarray:
    """Eq. 45: M = P Q^+ (4,4), with P, Q the (4,k) homogeneous matrices."""
    return P_hat @ np.linalg.pinv(Q_hat)


def split_transform(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 46: M = [[R_bar^T, t_bar], [0, 1]] -> (R_bar (3,3), t_bar (3,))."""
    return M[:3, :3].T.copy(), M[:3, 3].copy()


@dataclass
class StepEstimate:
    """One step's motion: ``P = R_bar^T Q + t_bar`` (frame i -> frame i-1).

    points_prev: (k,3) the points used, in the left camera frame of step i-1.
    inliers: (k,) bool of the points the estimate kept (all, for the paper's method).
    """

    R_bar: np.ndarray
    t_bar: np.ndarray
    points_prev: np.ndarray
    inliers: np.ndarray
    n_common: int


def paper_step(p_l_prev: np.ndarray, p_r_prev: np.ndarray, p_l_cur: np.ndarray,
               p_r_cur: np.ndarray, R: np.ndarray, t: np.ndarray) -> StepEstimate:
    """The paper's motion of one step from k common keypoints.

    p_*_prev, p_*_cur: (k,3) normalised homogeneous points of the same keypoints in the four
    images; R, t: the paper's stereo pair (eq. 25).
    """
    P = triangulate_paper(p_l_prev, p_r_prev, R, t)      # eq. 24 at step i-1
    Q = triangulate_paper(p_l_cur, p_r_cur, R, t)        # eq. 24 at step i
    ok = np.all(np.isfinite(P), axis=1) & np.all(np.isfinite(Q), axis=1)
    M = transform_matrix(homogeneous_matrix(P[ok]), homogeneous_matrix(Q[ok]))
    R_bar, t_bar = split_transform(M)
    return StepEstimate(R_bar, t_bar, P[ok], np.ones(int(ok.sum()), bool), len(P))


def compose_positions(R_bars: np.ndarray, t_bars: np.ndarray,
                      B0: np.ndarray = np.zeros(3)) -> np.ndarray:
    """Eqs 47-48: robot positions B_0..B_n (n+1, 3) from steps 1..n.

    R_bars, t_bars: (n,3,3), (n,3) for steps 1..n. With R_bar_0 = I,
    ``B_i = B_{i-1} + (R_bar_0^T R_bar_1^T ... R_bar_{i-1}^T) t_bar_i``; the product is taken
    left to right in increasing n (the orientation of step i-1 in the world frame).
    """
    B = [np.asarray(B0, float)]
    acc = np.eye(3)                      # prod_{n=0}^{i-1} R_bar_n^T
    for R_bar, t_bar in zip(R_bars, t_bars):
        B.append(B[-1] + acc @ t_bar)
        acc = acc @ R_bar.T
    return np.array(B)
