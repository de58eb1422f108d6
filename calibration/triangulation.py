"""Two-view triangulation: the paper's eq. 24, and optimal alternatives to compare with it.

Conventions (docs/conventions.md, "Stereo pair"): normalised homogeneous image points
``p = (x, y, 1)`` (focal length 1, distortion removed), and the paper's pair relation

    P_l = R^T P_r + t                                                    (eq. 25)

so a point seen at depth ``z_l`` along ``p_l`` and ``z_r`` along ``p_r`` satisfies
``z_l p_l - z_r R^T p_r - t = e`` (eq. 23) with ``e = 0`` for exact rays. OpenCV keeps the
same pair as ``x_right = R_rl x_left + t_rl``; :func:`paper_from_opencv` and
:func:`opencv_from_paper` convert (``R = R_rl``, ``t = -R_rl^T t_rl``).

Every function is vectorised over N points; shapes are in the docstrings. Points come back in
the LEFT camera frame, in the unit of ``t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def paper_from_opencv(R_rl: np.ndarray, t_rl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV ``x_r = R_rl x_l + t_rl`` -> the paper's ``(R, t)`` with ``P_l = R^T P_r + t``."""
    R_rl = np.asarray(R_rl, float)
    return R_rl.copy(), -R_rl.T @ np.asarray(t_rl, float)


def opencv_from_paper(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's ``(R, t)`` -> OpenCV ``(R_rl, t_rl)`` with ``x_r = R_rl x_l + t_rl``."""
    R = np.asarray(R, float)
    return R.copy(), -R @ np.asarray(t, float)


def homogeneous(xy: np.ndarray) -> np.ndarray:
    """(N,2) normalised coordinates -> (N,3) homogeneous ``(x, y, 1)``."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    return np.concatenate([xy, np.ones((len(xy), 1))], axis=1)


def _check(p_l, p_r, R, t):
    p_l = np.asarray(p_l, float)
    p_r = np.asarray(p_r, float)
    if p_l.ndim != 2 or p_l.shape[1] != 3 or p_l.shape != p_r.shape:
        raise ValueError(f"p_l and p_r must both be (N,3), got {p_l.shape} and {p_r.shape}")
    R = np.asarray(R, float).reshape(3, 3)
    t = np.asarray(t, float).reshape(3)
    return p_l, p_r, R, t


@dataclass(frozen=True)
class Triangulated:
    """Result of :func:`triangulate_paper_full`.

    points_l: (N,3) the paper's reconstruction ``z_l p_l`` (on the left ray), left frame.
    midpoint_l: (N,3) the midpoint of the shortest segment between the rays, left frame.
    z_l, z_r: (N,) depths along ``p_l`` and ``p_r`` (eq. 24).
    gap: (N,) ``|e|`` of eq. 23, the distance between the two rays at the solution.
    """

    points_l: np.ndarray
    midpoint_l: np.ndarray
    z_l: np.ndarray
    z_r: np.ndarray
    gap: np.ndarray


def triangulate_paper_full(p_l: np.ndarray, p_r: np.ndarray, R: np.ndarray,
                           t: np.ndarray) -> Triangulated:
    """The paper's eq. 24: least-squares depths of two rays, with the gap of eq. 23.

    p_l, p_r: (N,3) homogeneous normalised points ``(x, y, 1)`` in the left/right images.
    R (3,3), t (3,): the paper's pair, ``P_l = R^T P_r + t``.
    Rays that are parallel (a point at infinity, or the same ray) give NaN.
    """
    p_l, p_r, R, t = _check(p_l, p_r, R, t)
    q = p_r @ R                      # rows are R^T p_r, the right ray in the left frame
    a = np.einsum("ij,ij->i", p_l, p_l)
    b = np.einsum("ij,ij->i", p_l, q)          # p_l^T R^T p_r
    c = np.einsum("ij,ij->i", p_r, p_r)        # p_r^T R R^T p_r = p_r^T p_r
    d1 = p_l @ t                               # p_l^T t
    d2 = -(q @ t)                              # -p_r^T R t
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        det = np.where(np.abs(det) > 1e-14 * a * c, det, np.nan)
        # [[a, -b], [-b, c]]^-1 = [[c, b], [b, a]] / det
        z_l = (c * d1 + b * d2) / det
        z_r = (b * d1 + a * d2) / det
    on_left = z_l[:, None] * p_l
    on_right = z_r[:, None] * q + t
    e = on_left - on_right
    return Triangulated(points_l=on_left, midpoint_l=0.5 * (on_left + on_right), z_l=z_l,
                        z_r=z_r, gap=np.linalg.norm(e, axis=1))


def triangulate_paper(p_l: np.ndarray, p_r: np.ndarray, R: np.ndarray, t: np.ndarray,
                      return_gap: bool = False):
    """The paper's eq. 24. Returns (N,3) points ``z_l p_l`` in the left frame.

    With ``return_gap=True`` returns ``(points (N,3), gap (N,))`` where gap is ``|e|`` (eq. 23).
    """
    res = triangulate_paper_full(p_l, p_r, R, t)
    return (res.points_l, res.gap) if return_gap else res.points_l


def triangulate_dlt(p_l: np.ndarray, p_r: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation, as cv2.triangulatePoints, vectorised. (N,3) left frame.

    Minimises an algebraic error: for reference, not better than the midpoint in general.
    """
    p_l, p_r, R, t = _check(p_l, p_r, R, t)
    R_rl, t_rl = opencv_from_paper(R, t)
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([R_rl, t_rl[:, None]])
    A = np.stack([p_l[:, :1] * P1[2] - P1[0], p_l[:, 1:2] * P1[2] - P1[1],
                  p_r[:, :1] * P2[2] - P2[0], p_r[:, 1:2] * P2[2] - P2[1]], axis=1)  # (N,4,4)
    _, _, Vt = np.linalg.svd(A)
    X = Vt[:, -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        return X[:, :3] / X[:, 3:]


def essential_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """E with ``p_r^T E p_l = 0`` for the paper's pair: ``E = [t_rl]x R_rl`` (3,3)."""
    R_rl, t_rl = opencv_from_paper(R, t)
    tx = np.array([[0, -t_rl[2], t_rl[1]], [t_rl[2], 0, -t_rl[0]], [-t_rl[1], t_rl[0], 0]])
    return tx @ R_rl


def correct_matches(p_l: np.ndarray, p_r: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Optimal correction of a match onto the epipolar constraint (Lindstrom 2010, niter2).

    Moves ``p_l``, ``p_r`` (N,3) by the smallest total squared displacement in the image
    planes so that ``p_r^T E p_l = 0`` exactly; the same optimum as Hartley-Sturm
    (cv2.correctMatches) without solving a sextic. Returns corrected (N,3), (N,3).
    """
    p_l = np.asarray(p_l, float)
    p_r = np.asarray(p_r, float)
    # Lindstrom's form is x^T F x' = 0; take x = p_l, x' = p_r, F = E^T.
    F = np.asarray(E, float).T
    Fs = F[:2, :2]
    n = (p_r @ F.T)[:, :2]           # S F x'
    n2 = (p_l @ F)[:, :2]            # S F^T x
    a = np.einsum("ij,ij->i", n @ Fs, n2)
    b = 0.5 * (np.einsum("ij,ij->i", n, n) + np.einsum("ij,ij->i", n2, n2))
    c = np.einsum("ij,ij->i", p_l @ F, p_r)
    d = np.sqrt(np.maximum(b * b - a * c, 0.0))
    lam = c / (b + d)
    dx = lam[:, None] * n
    dx2 = lam[:, None] * n2
    n = n - dx2 @ Fs.T
    n2 = n2 - dx @ Fs
    lam = lam * 2.0 * d / (np.einsum("ij,ij->i", n, n) + np.einsum("ij,ij->i", n2, n2))
    out_l = p_l.copy()
    out_r = p_r.copy()
    out_l[:, :2] -= lam[:, None] * n
    out_r[:, :2] -= lam[:, None] * n2
    return out_l, out_r


def triangulate_optimal(p_l: np.ndarray, p_r: np.ndarray, R: np.ndarray, t: np.ndarray,
                        return_gap: bool = False):
    """Optimal triangulation: correct the match onto its epipolar lines (Lindstrom), then
    intersect the rays (eq. 24, whose gap is then zero up to rounding).

    Under equal isotropic image noise in both normalised images this is the maximum-likelihood
    point, where the paper's eq. 24 minimises a 3-D distance that weighs far points less.
    Returns (N,3) left-frame points (and the gap (N,) of the uncorrected rays if asked).
    """
    p_l, p_r, R, t = _check(p_l, p_r, R, t)
    cl, cr = correct_matches(p_l, p_r, essential_matrix(R, t))
    points = triangulate_paper_full(cl, cr, R, t).midpoint_l
    if return_gap:
        return points, triangulate_paper_full(p_l, p_r, R, t).gap
    return points


def reprojection_error(points_l: np.ndarray, p_l: np.ndarray, p_r: np.ndarray, R: np.ndarray,
                       t: np.ndarray) -> np.ndarray:
    """(N,) RMS over both images of the normalised-coordinate error of (N,3) left-frame points."""
    R_rl, t_rl = opencv_from_paper(R, t)
    X = np.asarray(points_l, float)
    Xr = X @ R_rl.T + t_rl
    el = X[:, :2] / X[:, 2:] - p_l[:, :2] / p_l[:, 2:]
    er = Xr[:, :2] / Xr[:, 2:] - p_r[:, :2] / p_r[:, 2:]
    return np.sqrt(0.5 * (np.einsum("ij,ij->i", el, el) + np.einsum("ij,ij->i", er, er)))
