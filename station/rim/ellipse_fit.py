"""Ellipse fits: algebraic (Fitzgibbon direct, Halir-Flusser form) then robust geometric.

The geometric fit minimises the orthogonal distances of the points to the ellipse over the five
parameters (cx, cy, a, b, theta) of eqs 1-3 by Levenberg-Marquardt with Huber weights (scale
from the MAD) and a final hard rejection of points beyond 3.5 sigma. The foot point of each
point is found by Newton's method, and by the envelope theorem the derivative of a distance is
``-n . dx/dparams`` at the foot point (n the unit normal). The covariance of the parameters is
``sigma^2 (J^T W J)^-1`` times ``corr``, the noise-correlation factor of neighbouring edge
samples (profiles 1.5 px apart share pixels), measured in tests/test_rim_subpixel.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.rim import fit_loops
from station.rim.ellipse import Ellipse, Feet
from station.rim.npfast import median, row_sq_sums, rows

COV_CORRELATION_FACTOR = 1.0  # replaced by the measured value below (see module docstring)


def fit_direct(pts: np.ndarray) -> Ellipse:
    """Fitzgibbon's direct least-squares ellipse fit (numerically stable Halir-Flusser form).

    pts: (N,2), N >= 5. Raises ValueError when the points define no ellipse.
    """
    pts = np.asarray(pts, float)
    if len(pts) < 5:
        raise ValueError("an ellipse needs at least 5 points")
    mean = pts.mean(axis=0)
    scale = np.sqrt(row_sq_sums(pts - mean).mean()) + 1e-12
    x, y = (pts[:, 0] - mean[0]) / scale, (pts[:, 1] - mean[1]) / scale  # contiguous (N,) each
    D1 = np.stack([x * x, x * y, y * y], axis=1)
    D2 = np.stack([x, y, np.ones_like(x)], axis=1)
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    T = -np.linalg.solve(S3, S2.T)
    M = S1 + S2 @ T
    M = np.array([M[2] / 2, -M[1], M[0] / 2])
    _, V = np.linalg.eig(M)
    V = np.real(V)
    cond = 4 * V[0] * V[2] - V[1] ** 2
    if not np.any(cond > 0):
        raise ValueError("the points define no ellipse")
    a1 = V[:, np.argmax(cond)]
    A, B, C, D, E, F = np.concatenate([a1, T @ a1])
    # undo the normalisation: x = (u - mu)/s
    s, (mu, mv) = scale, mean
    A2, B2, C2 = A / s**2, B / s**2, C / s**2
    D2_ = D / s - 2 * A2 * mu - B2 * mv
    E2 = E / s - 2 * C2 * mv - B2 * mu
    F2 = F + A2 * mu * mu + B2 * mu * mv + C2 * mv * mv - D / s * mu - E / s * mv
    return Ellipse.from_conic([A2, B2, C2, D2_, E2, F2])


@dataclass
class GeometricFit:
    """ellipse; cov: (5,5) of (cx, cy, a, b, theta); inliers: (N,) bool; residuals: (N,) px;
    sigma_px: robust rms distance of the inliers; iterations: LM steps taken."""

    ellipse: Ellipse
    cov: np.ndarray
    inliers: np.ndarray
    residuals: np.ndarray
    sigma_px: float
    iterations: int


def _jacobian(e: Ellipse, feet) -> np.ndarray:
    """d(distance)/d(cx, cy, a, b, theta) at the feet of :meth:`Ellipse.feet` on ``e``: (N,5).

    The foot point is x = c + R(theta) (a cos t, b sin t); the derivative of the distance is
    -n . dx/dparam with n the unit normal, R(theta) (b cos t, a sin t) / norm (``feet`` holds
    cos t, sin t and the normal in the ellipse's frame). Written per column in the ellipse's
    own frame, where the dot products are one product each."""
    a, b = e.axes_px
    c, s = e.cos_sin
    ct, st, nlx, nly = feet.ct, feet.st, feet.nx, feet.ny
    J = np.empty((len(ct), 5))
    J[:, 0] = -(c * nlx - s * nly)
    J[:, 1] = -(s * nlx + c * nly)
    J[:, 2] = -nlx * ct
    J[:, 3] = -nly * st
    J[:, 4] = nlx * b * st - nly * a * ct
    return J


def fit_geometric(pts: np.ndarray, init: Ellipse | None = None, iterations: int = 12,
                  huber_k: float = 1.5, reject_sigma: float = 3.5,
                  corr: float | None = None, reject_floor_px: float = 0.0) -> GeometricFit:
    """Robust orthogonal-distance ellipse fit of pts (N,2) (N >= 6), from ``init`` or the
    direct fit. The inliers it returns are the points within ``reject_sigma`` robust sigmas
    of the fit, or within ``reject_floor_px`` if that is more. Raises ValueError if it cannot fit."""
    pts = np.asarray(pts, float)
    if len(pts) < 6:
        raise ValueError("too few points for a geometric ellipse fit")
    e = init if init is not None else fit_direct(pts)
    x, y = np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])
    p, d, t, ct, st, nx, ny, inl, it = fit_loops.geometric_lm(x, y, e.params, iterations, huber_k, reject_sigma)
    e, feet = Ellipse.from_params(p), Feet(d, t, ct, st, nx, ny)
    sig = 1.4826 * median(np.abs(d[inl])) + 1e-9
    inl = np.abs(d) < max(reject_sigma * sig, reject_floor_px)
    J = rows(_jacobian(e, feet), inl)
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    dof = max(int(inl.sum()) - 5, 1)
    s2 = float((d[inl] ** 2).sum() / dof)
    factor = COV_CORRELATION_FACTOR if corr is None else corr
    cov = np.linalg.pinv(J.T @ J) * s2 * factor
    return GeometricFit(e, cov, inl, d, rms, it)


def ransac_ellipse(pts: np.ndarray, threshold_px: float, iterations: int = 160,
                   seed: int = 0, batch: int = 32, confidence: float = 0.9999) -> np.ndarray | None:
    """(N,) bool inliers of the ellipse with the largest support among 5-point conics.

    Two concentric edges (the flange edge on one arc, the lip's inner edge on another) make a
    least-squares fit a compromise that matches neither; the consensus of minimal samples
    picks one curve. The hypotheses are drawn here (the same draws for the same seed) and
    scored in one compiled loop (``fit_loops.consensus``), ``batch`` at a time; it stops
    when, at the best support fraction w found so far, the samples drawn contain an
    all-inlier one with probability ``confidence`` (1 - (1 - w^5)^k: one batch of 32 samples
    for w >= 0.76, two for w >= 0.67, five for w >= 0.56). None if no sample gives an ellipse."""
    pts = np.asarray(pts, float)
    n = len(pts)
    if n < 10:
        return None
    mean = pts.mean(axis=0)
    scale = np.sqrt(row_sq_sums(pts - mean).mean()) + 1e-12
    x, y = (pts[:, 0] - mean[0]) / scale, (pts[:, 1] - mean[1]) / scale  # contiguous (N,) each
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, (iterations, 5))  # (a repeated index gives a degenerate conic that loses)
    probe = rng.choice(n, min(n, 400), replace=False)  # score the hypotheses on a sample
    q, found = fit_loops.consensus(x, y, idx, probe, scale, threshold_px, batch, np.log(1 - confidence))
    return fit_loops.sampson_below(q, x, y, scale, threshold_px) if found else None
