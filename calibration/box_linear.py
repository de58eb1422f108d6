"""The paper's closed-form box calibration (section 2.3, eqs 4-22), exactly as published.

Model (eq. 4): ``z_k p̂_k = K (R B_k + t)`` for box points ``B_k`` (box frame, metres) and their
pixels ``p̂_k = (u, v, 1)``. Steps, each named by its equation:

* triplets of points a, b, c (eqs 6-9): ``B_I = .5 B_a - B_b + .5 B_c``,
  ``B_II = -B_a + .5 B_b + .5 B_c``, ``P̂_I = [.5 p̂_a, -p̂_b, .5 p̂_c]``,
  ``P̂_II = [-p̂_a, .5 p̂_b, .5 p̂_c]``. The weights of each sum add to zero, so ``t``
  cancels: ``K_R B_I = P̂_I z`` and ``K_R B_II = P̂_II z`` with ``z = (z_a, z_b, z_c)``,
  hence ``K_R B_I = P̂_I P̂_II^-1 K_R B_II``;
* with ``vec(A X B) = (B^T ⊗ A) vec(X)`` (column stacking) this is eq. 5,
  ``[B_I^T ⊗ I - B_II^T ⊗ P̂_I P̂_II^-1] vec(K_R) = 0``, three rows per triplet; n >= 3
  triplets stacked give eq. 11, ``P x = 0``;
* ``x`` = the right singular vector of ``P`` for the smallest singular value, reshaped
  (column-major, the inverse of vec) into ``K̄_R`` (eq. 12);
* ``K̃`` from ``K̄_R K̄_R^T`` normalised to a 1 in its (3,3) element (eqs 13-18);
* ``R̄ = U V^T`` from the SVD of ``K̃^-1 K̄_R`` (eqs 19-20);
* depths ``λ`` and ``t`` from the linear system of eq. 21 (least squares, eq. 22).

Sign and scale (the paper leaves them implicit): ``x`` is defined up to a non-zero factor.
We scale ``K̄_R`` so that its third row has unit norm -- the paper's normalisation of
``K̄_R K̄_R^T`` to a 1 in element (3,3), applied to ``K̄_R`` itself because eq. 21 uses
``K̄_R B_k`` at true scale (the third row of ``K R`` is the third row of ``R``) -- and choose
the sign that makes ``det K̄_R > 0`` (``det(K R) = fx fy > 0``); then ``R̄`` is a proper
rotation and the depths come out positive for points in front of the camera.

Pixel coordinates enter unscaled, as in the paper. ``precondition=True`` (an addition,
off by default) first maps pixels by a similarity ``T`` (centre, unit mean distance); the
equations then give ``T K`` and ``K = T^-1 (T K)``. It changes nothing on exact data and
keeps the matrix entries O(1); with noise we measured no systematic accuracy gain (test),
so the published form stays the default.

Degenerate input is refused with :class:`CalibrationError`: fewer than 4 points, all points
on one plane (``P`` then has a null space of dimension > 1: nothing fixes the column of ``K_R``
along the plane's normal), image points of a triplet on one line, or a ``K̃ K̃^T`` that is not
positive definite.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from calibration.errors import CalibrationError


@dataclass(frozen=True)
class LinearCalibration:
    """Result of :func:`paper_box_calibration`.

    K: (3,3) eq. 14. R: (3,3) eq. 20. t: (3,) eq. 21 (x_cam = R B + t). depths: (N,) eq. 22.
    K_R: (3,3) normalised K̄_R (eq. 12). singular_values: (9,) of P (eq. 11).
    triplets: (n,3) point indices used.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    depths: np.ndarray
    K_R: np.ndarray
    singular_values: np.ndarray
    triplets: np.ndarray


def default_triplets(n_points: int, max_triplets: int = 400, seed: int = 0) -> np.ndarray:
    """(n,3) index triplets: all of them for few points (8 vertices: 56), else a fixed sample."""
    if n_points < 3:
        return np.zeros((0, 3), int)
    total = n_points * (n_points - 1) * (n_points - 2) // 6
    if total <= max_triplets:
        return np.array(list(combinations(range(n_points), 3)), int)
    rng = np.random.default_rng(seed)
    tri = np.sort(np.array([rng.choice(n_points, 3, replace=False) for _ in range(max_triplets)]), axis=1)
    return np.unique(tri, axis=0)


def triplet_system(points_box: np.ndarray, pixels_h: np.ndarray, triplets: np.ndarray) -> np.ndarray:
    """Eq. 11: the (3n, 9) matrix P with ``P vec(K_R) = 0``.

    points_box: (N,3). pixels_h: (N,3) homogeneous pixels. triplets: (n,3) indices a, b, c.
    Triplets whose image points are (nearly) collinear are dropped (``P̂_II`` singular).
    """
    a, b, c = triplets.T
    Ba, Bb, Bc = points_box[a], points_box[b], points_box[c]
    B_I = 0.5 * Ba - Bb + 0.5 * Bc                                     # eq. 6  (n,3)
    B_II = -Ba + 0.5 * Bb + 0.5 * Bc                                   # eq. 7  (n,3)
    pa, pb, pc = pixels_h[a], pixels_h[b], pixels_h[c]
    P_I = np.stack([0.5 * pa, -pb, 0.5 * pc], axis=2)                  # eq. 8  (n,3,3) columns
    P_II = np.stack([-pa, 0.5 * pb, 0.5 * pc], axis=2)                 # eq. 9
    # keep triplets whose image points are not collinear (P_II well conditioned)
    cond = np.linalg.cond(P_II)
    keep = np.isfinite(cond) & (cond < 1e12)
    B_I, B_II, P_I, P_II = B_I[keep], B_II[keep], P_I[keep], P_II[keep]
    M = P_I @ np.linalg.inv(P_II)                                      # P̂_I P̂_II^-1 (n,3,3)
    eye = np.eye(3)
    # Kronecker products B^T ⊗ A, shape (n, 3, 9): block j (columns 3j..3j+2) is B[j] * A
    kron_I = np.einsum("nj,ab->najb", B_I, eye).reshape(-1, 3, 9)
    kron_II = np.einsum("nj,nab->najb", B_II, M).reshape(-1, 3, 9)
    return (kron_I - kron_II).reshape(-1, 9)                            # eq. 5 stacked: eq. 11


def _check_geometry(points_box: np.ndarray, pixels: np.ndarray) -> None:
    if points_box.ndim != 2 or points_box.shape[1] != 3 or pixels.shape != (len(points_box), 2):
        raise CalibrationError(f"box calibration needs (N,3) box points and (N,2) pixels, got "
                               f"{points_box.shape} and {pixels.shape}")
    if not (np.all(np.isfinite(points_box)) and np.all(np.isfinite(pixels))):
        raise CalibrationError("box calibration: the points contain NaN or infinity")
    if len(points_box) < 4:
        raise CalibrationError(f"box calibration needs at least 4 points not in one plane, got {len(points_box)}",
                               hint="show the camera at least two faces of the box")
    centred = points_box - points_box.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[2] < 1e-6 * s[0]:
        raise CalibrationError("box calibration: all points lie in one plane, which leaves the paper's "
                               "linear system (eq. 11) without a unique solution",
                               hint="turn the box so that the camera sees two of its faces")


def _precondition(pixels: np.ndarray) -> np.ndarray:
    c = pixels.mean(axis=0)
    s = np.sqrt(2) / np.mean(np.linalg.norm(pixels - c, axis=1))
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])


def paper_box_calibration(points_box: np.ndarray, pixels: np.ndarray, triplets: np.ndarray | None = None,
                          precondition: bool = False) -> LinearCalibration:
    """Closed-form K, R, t of one camera from one view of the box (eqs 4-22).

    points_box: (N,3) box-frame points (the paper: the eight vertices B_k; any points of
    known position work). pixels: (N,2) their pixels (distortion is not modelled here).
    triplets: (n,3) indices for eqs 6-9 (default: :func:`default_triplets`).
    """
    B = np.asarray(points_box, float)
    uv = np.asarray(pixels, float)
    _check_geometry(B, uv)
    T = _precondition(uv) if precondition else np.eye(3)
    p_h = np.c_[uv, np.ones(len(uv))] @ T.T
    tri = default_triplets(len(B)) if triplets is None else np.asarray(triplets, int)
    P = triplet_system(B, p_h, tri)
    if P.shape[0] < 9:
        raise CalibrationError(f"box calibration: only {P.shape[0] // 3} usable point triplets, the paper's "
                               "eq. 11 needs at least 3", hint="show the camera more of the box")
    _, sv, Vt = np.linalg.svd(P)
    if sv[-2] <= 1e-9 * sv[0]:
        raise CalibrationError("box calibration: the paper's system (eq. 11) has no unique solution "
                               "(degenerate pose: points coplanar or on few lines)",
                               hint="turn the box so that the camera sees two of its faces")
    x = Vt[-1]
    K_R = x.reshape(3, 3, order="F")                                   # eq. 12 (vec stacks columns)
    K_R = K_R / np.linalg.norm(K_R[2])                                 # scale: (K_R K_R^T)[2,2] = 1
    if np.linalg.det(K_R) < 0:                                         # sign: det(K R) = fx fy > 0
        K_R = -K_R
    KK = K_R @ K_R.T                                                   # eq. 13, normalised
    u0, v0 = KK[0, 2], KK[1, 2]                                        # eqs 15, 16
    fx2, fy2 = KK[0, 0] - u0 ** 2, KK[1, 1] - v0 ** 2
    if fx2 <= 0 or fy2 <= 0:
        raise CalibrationError("box calibration: K_R K_R^T is not consistent with a camera "
                               "(negative focal length squared); the points or their pixels are wrong")
    K_T = np.array([[np.sqrt(fx2), 0, u0], [0, np.sqrt(fy2), v0], [0, 0, 1.0]])   # eqs 14, 17, 18
    U, _, Vt2 = np.linalg.svd(np.linalg.solve(K_T, K_R))               # eq. 19
    R = U @ Vt2                                                        # eq. 20
    # eq. 21: [blockdiag(p̂_k) | -K̃] [λ; t] = K̄_R B_k  (3N equations, N + 3 unknowns).
    # Its least-squares solution, with the block-diagonal λ eliminated exactly (Schur
    # complement): for fixed t, z_k = p̂_k^T (K̄_R B_k + K̃ t) / |p̂_k|^2, and t minimises
    # sum_k |M_k (K̄_R B_k + K̃ t)|^2 with M_k = I - p̂_k p̂_k^T / |p̂_k|^2. Same answer as a dense
    # lstsq of eq. 21, in O(N) instead of O(N^3).
    q = B @ K_R.T                                                      # (N,3) K̄_R B_k
    M = np.eye(3) - np.einsum("ni,nj->nij", p_h, p_h) / np.einsum("ni,ni->n", p_h, p_h)[:, None, None]
    MK = M @ K_T                                                       # (N,3,3)
    lhs = np.einsum("nki,nkj->ij", MK, MK)
    rhs = -np.einsum("nki,nk->i", MK, np.einsum("nij,nj->ni", M, q))
    t = np.linalg.solve(lhs, rhs)
    depths = np.einsum("ni,ni->n", p_h, q + K_T @ t) / np.einsum("ni,ni->n", p_h, p_h)   # eq. 22
    K = np.linalg.solve(T, K_T)
    K = K / K[2, 2]
    return LinearCalibration(K=K, R=R, t=t, depths=depths, K_R=np.linalg.solve(T, K_R),
                             singular_values=sv, triplets=tri)
