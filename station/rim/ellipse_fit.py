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

from station.rim.ellipse import Ellipse
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


_TINY_EYE = 1e-12 * np.eye(5)  # keeps the damped normal equations regular


def fit_geometric(pts: np.ndarray, init: Ellipse | None = None, iterations: int = 12,
                  huber_k: float = 1.5, reject_sigma: float = 3.5,
                  corr: float | None = None) -> GeometricFit:
    """Robust orthogonal-distance ellipse fit of pts (N,2) (N >= 6), from ``init`` or the
    direct fit. Raises ValueError if it cannot fit."""
    pts = np.asarray(pts, float)
    if len(pts) < 6:
        raise ValueError("too few points for a geometric ellipse fit")
    e = init if init is not None else fit_direct(pts)
    p = e.params
    lam = 1e-4
    w = np.ones(len(pts))
    inl = np.ones(len(pts), bool)

    def evaluate(ell, t0=None):  # from the last feet: the step moved the ellipse by little
        return ell.feet(pts) if t0 is None else ell.feet(pts, iterations=2, t0=t0)

    feet = evaluate(e)
    d, t = feet.d, feet.t
    it = 0
    for it in range(1, iterations + 1):
        sig = 1.4826 * median(np.abs(d[inl])) + 1e-6
        inl = np.abs(d) < max(reject_sigma * sig, 1e-3)
        ad = np.abs(d) / sig
        w = np.where(ad < huber_k, 1.0, huber_k / np.maximum(ad, 1e-12)) * inl
        J = _jacobian(e, feet)
        JtW = J.T * w
        H = JtW @ J
        g = JtW @ d
        cost = (w * d * d).sum()
        while True:
            step = -np.linalg.solve(H + lam * (np.diag(np.diag(H)) + _TINY_EYE), g)
            e_new = Ellipse.from_params(p + step)
            feet_new = evaluate(e_new, t)
            d_new = feet_new.d
            if (w * d_new * d_new).sum() <= cost or lam > 1e6:
                break
            lam *= 10
        lam = max(lam * 0.1, 1e-7)
        e, feet = e_new, feet_new
        d, t = feet.d, feet.t
        p = e.params
        if np.all(np.abs(step[:4]) < 1e-4) and abs(step[4] * (p[2] - p[3])) < 1e-4:
            # every point moved < 1e-4 px (far below the noise, 0.05-0.2 px); a near-circle's
            # angle moves its curve by (a - b) per radian
            break
    sig = 1.4826 * median(np.abs(d[inl])) + 1e-9
    inl = np.abs(d) < reject_sigma * sig
    J = rows(_jacobian(e, feet), inl)
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    dof = max(int(inl.sum()) - 5, 1)
    s2 = float((d[inl] ** 2).sum() / dof)
    factor = COV_CORRELATION_FACTOR if corr is None else corr
    cov = np.linalg.pinv(J.T @ J) * s2 * factor
    return GeometricFit(e, cov, inl, d, rms, it)


def _sampson(Q: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """|Sampson distance| of points (x, y) (N,) to conics Q (M,6): (M,N)."""
    one, zero = np.ones_like(x), np.zeros_like(x)
    f = np.stack([x * x, x * y, y * y, x, y, one]).T @ Q.T          # (N,M): three small matrix
    gx = np.stack([2 * x, y, zero, one, zero, zero]).T @ Q.T        # products instead of a dozen
    gy = np.stack([zero, x, 2 * y, zero, one, zero]).T @ Q.T        # (M,N) temporaries
    return (np.abs(f) / np.sqrt(gx * gx + gy * gy + 1e-30)).T


def ransac_ellipse(pts: np.ndarray, threshold_px: float, iterations: int = 160,
                   seed: int = 0, batch: int = 32, confidence: float = 0.9999) -> np.ndarray | None:
    """(N,) bool inliers of the ellipse with the largest support among 5-point conics.

    Two concentric edges (the flange edge on one arc, the lip's inner edge on another) make a
    least-squares fit a compromise that matches neither; the consensus of minimal samples
    picks one curve. Vectorised: ``batch`` minimal conics and their distances at once; it
    stops when, at the best support fraction w found so far, the samples drawn contain an
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
    best_q, best_support = None, -1
    for k in range(0, iterations, batch):
        Q = _minimal_conics(x[idx[k:k + batch]], y[idx[k:k + batch]])
        if len(Q):
            support = (_sampson(Q, x[probe], y[probe]) * scale < threshold_px).sum(axis=1)
            j = int(np.argmax(support))
            if support[j] > best_support:
                best_q, best_support = Q[j:j + 1], int(support[j])
        w = max(best_support, 0) / len(probe)
        drawn = min(k + batch, iterations)
        if w > 0 and drawn * np.log1p(-min(w ** 5, 1 - 1e-12)) <= np.log(1 - confidence):
            break
    if best_q is None:
        return None
    return _sampson(best_q, x, y)[0] * scale < threshold_px


def _minimal_conics(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """The ellipses through each row of 5 points (I,5) of centred, scaled coordinates: (M,6)
    conics, M <= I (degenerate samples and non-ellipses dropped).

    With the points centred on the data, an ellipse around them does not pass through the
    origin, so F = -1 normalises it and 5x5 solves replace SVDs."""
    M = np.stack([xs * xs, xs * ys, ys * ys, xs, ys], axis=2)                    # (I,5,5)
    ok = np.abs(np.linalg.det(M)) > 1e-12
    if not ok.any():
        return np.empty((0, 6))
    q = np.linalg.solve(M[ok], np.ones((int(ok.sum()), 5, 1)))[:, :, 0]
    Q = np.concatenate([q, -np.ones((len(q), 1))], axis=1)                      # (I,6) conics
    return Q[Q[:, 1] ** 2 - 4 * Q[:, 0] * Q[:, 2] < 0]
