"""The ellipse fits' inner loops, compiled (numba).

The rim detector's time went into some 10^4 small numpy calls per image, not into arithmetic
(docs/speed.md, "Why it is this fast"): the geometric fit's Levenberg-Marquardt loop (Newton foot
points, Jacobian, normal equations, twelve times over ~1000 points) and the consensus search's
minimal conics and their support cost a few microseconds of call overhead per operation. Here
each is one compiled loop over the points. They compute what ``ellipse_fit``'s numpy forms
computed, in the same order of steps; sums may differ in the last bits (another summation
order), never in meaning (tests/test_rim_loops.py compares them).

Ellipse parameters p (5,) are (cx, cy, a, b, theta) as in ``station.rim.ellipse``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

TWO_PI = 2.0 * np.pi


@njit(cache=True, nogil=True)
def normalised(p):
    """(5,) p with a >= b > 0 and theta in [-pi/2, pi/2), as ``Ellipse.from_params`` keeps it."""
    q = p.copy()
    q[2], q[3] = abs(q[2]), abs(q[3])
    if q[3] > q[2]:
        q[2], q[3] = q[3], q[2]
        q[4] += np.pi / 2
    q[4] = (q[4] + np.pi / 2) % np.pi - np.pi / 2
    return q


@njit(cache=True, nogil=True)
def _turned(c, s, delta, t):
    """cos and sin of t = t_before + delta from c, s of t_before: a Newton step near the foot
    turns by little, and a rotation by its Taylor series (|delta| < 1e-3: exact to the last
    bit's order) costs a tenth of a new cos and sin."""
    if abs(delta) >= 1e-3:
        return np.cos(t), np.sin(t)
    d2 = delta * delta
    sd = delta * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0))
    cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0)
    return c * cd - s * sd, s * cd + c * sd


@njit(cache=True, nogil=True)
def feet(px, py, p, t0, iterations, use_t0, d, t, ct, st, nx, ny):
    """Foot points of the points (px, py) (N,) on ellipse p, as ``Ellipse.feet``: Newton on the
    foot parameter from the point's angle (or from ``t0`` (N,) when ``use_t0``), then the signed
    distance d, the parameter t, its cos / sin and the unit normal in the ellipse frame, written
    into the (N,) output arrays."""
    c, s = np.cos(p[4]), np.sin(p[4])
    a, b = p[2], p[3]
    for i in range(px.size):
        du, dv = px[i] - p[0], py[i] - p[1]
        x, y = du * c + dv * s, -du * s + dv * c
        ti = t0[i] if use_t0 else np.arctan2(a * y, b * x)
        cti, sti = np.cos(ti), np.sin(ti)
        for _ in range(iterations):
            ex, ey = a * cti, b * sti
            dx, dy = -a * sti, b * cti
            rx, ry = x - ex, y - ey
            f = rx * dx + ry * dy
            df = -(dx * dx + dy * dy) - rx * ex - ry * ey
            delta = -f / df
            ti = ti + delta
            cti, sti = _turned(cti, sti, delta, ti)
        rx, ry = x - a * cti, y - b * sti
        mx, my = b * cti, a * sti
        nn = np.hypot(mx, my)
        d[i] = (rx * mx + ry * my) / nn
        t[i] = ti
        ct[i], st[i] = cti, sti
        nx[i], ny[i] = mx / nn, my / nn


@njit(cache=True, nogil=True)
def _normal_equations(p, d, ct, st, nx, ny, w):
    """H (5,5), g (5,) of the weighted distances d (N,) at their feet on ellipse p, and the
    weighted cost: J^T W J, J^T W d, sum w d^2 with J the distance's derivative (``_jacobian``)."""
    c, s = np.cos(p[4]), np.sin(p[4])
    a, b = p[2], p[3]
    H = np.zeros((5, 5))
    g = np.zeros(5)
    cost = 0.0
    j = np.empty(5)
    for i in range(d.size):
        wi = w[i]
        if wi == 0.0:
            continue
        j[0] = -(c * nx[i] - s * ny[i])
        j[1] = -(s * nx[i] + c * ny[i])
        j[2] = -nx[i] * ct[i]
        j[3] = -ny[i] * st[i]
        j[4] = nx[i] * b * st[i] - ny[i] * a * ct[i]
        for r in range(5):
            wr = wi * j[r]
            g[r] += wr * d[i]
            for q in range(r, 5):
                H[r, q] += wr * j[q]
        cost += wi * d[i] * d[i]
    for r in range(5):
        for q in range(r):
            H[r, q] = H[q, r]
    return H, g, cost


@njit(cache=True, nogil=True)
def geometric_lm(px, py, p0, iterations, huber_k, reject_sigma):
    """The robust orthogonal-distance fit's Levenberg-Marquardt loop (``fit_geometric``):
    Huber weights at the MAD scale, points beyond ``reject_sigma`` of it out, damping from
    1e-4, feet from the last ones after each step, stop when every point moved < 1e-4 px.

    Returns (p (5,), d, t, ct, st, nx, ny (N,) at p's feet, inliers (N,) of the last
    iteration, iterations taken)."""
    n = px.size
    p = normalised(p0)
    d, t, ct, st = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    nx, ny = np.empty(n), np.empty(n)
    feet(px, py, p, t, 4, False, d, t, ct, st, nx, ny)
    d2, t2, ct2, st2 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    nx2, ny2 = np.empty(n), np.empty(n)
    inl = np.ones(n, np.bool_)
    w = np.empty(n)
    lam = 1e-4
    it = 0
    for it in range(1, iterations + 1):
        sig = 1.4826 * np.median(np.abs(d[inl])) + 1e-6
        bound = max(reject_sigma * sig, 1e-3)
        for i in range(n):
            ad = abs(d[i])
            inl[i] = ad < bound
            r = ad / sig
            w[i] = (1.0 if r < huber_k else huber_k / max(r, 1e-12)) if inl[i] else 0.0
        H, g, cost = _normal_equations(p, d, ct, st, nx, ny, w)
        while True:
            A = H.copy()
            for r in range(5):
                A[r, r] += lam * (H[r, r] + 1e-12)
            step = -np.linalg.solve(A, g)
            p_new = normalised(p + step)
            feet(px, py, p_new, t, 2, True, d2, t2, ct2, st2, nx2, ny2)
            cost_new = 0.0
            for i in range(n):
                cost_new += w[i] * d2[i] * d2[i]
            if cost_new <= cost or lam > 1e6:
                break
            lam *= 10
        lam = max(lam * 0.1, 1e-7)
        p = p_new
        d, d2 = d2, d
        t, t2 = t2, t
        ct, ct2 = ct2, ct
        st, st2 = st2, st
        nx, nx2 = nx2, nx
        ny, ny2 = ny2, ny
        small = True
        for r in range(4):
            small &= abs(step[r]) < 1e-4
        if small and abs(step[4] * (p[2] - p[3])) < 1e-4:
            break
    return p, d, t, ct, st, nx, ny, inl, it


@njit(cache=True, nogil=True)
def _conic_through(x5, y5, q, M):
    """The conic (6,) through 5 centred, scaled points with F = -1 into ``q``; False when the
    points are degenerate (|det| <= 1e-12) or the conic is no ellipse (``_minimal_conics``).
    M (5,6): room for the augmented system, solved by Gaussian elimination with partial
    pivoting (LAPACK's getrf / getrs, without their calls' overhead)."""
    for k in range(5):
        xk, yk = x5[k], y5[k]
        M[k, 0], M[k, 1], M[k, 2], M[k, 3], M[k, 4], M[k, 5] = xk * xk, xk * yk, yk * yk, xk, yk, 1.0
    det = 1.0
    for c in range(5):
        piv = c
        for r in range(c + 1, 5):
            if abs(M[r, c]) > abs(M[piv, c]):
                piv = r
        if piv != c:
            det = -det
            for k in range(c, 6):
                M[c, k], M[piv, k] = M[piv, k], M[c, k]
        det *= M[c, c]
        if M[c, c] == 0.0:
            return False
        for r in range(c + 1, 5):
            f = M[r, c] / M[c, c]
            for k in range(c, 6):
                M[r, k] -= f * M[c, k]
    if abs(det) <= 1e-12:
        return False
    for c in range(4, -1, -1):
        acc = M[c, 5]
        for k in range(c + 1, 5):
            acc -= M[c, k] * q[k]
        q[c] = acc / M[c, c]
    q[5] = -1.0
    return q[1] * q[1] - 4 * q[0] * q[2] < 0


@njit(cache=True, nogil=True)
def sampson_below(q, x, y, scale, threshold):
    """(N,) bool: |Sampson distance| of (x, y) (N,) to conic q (6,) times ``scale`` below
    ``threshold`` (``_sampson``)."""
    out = np.empty(x.size, np.bool_)
    for i in range(x.size):
        xi, yi = x[i], y[i]
        f = q[0] * xi * xi + q[1] * xi * yi + q[2] * yi * yi + q[3] * xi + q[4] * yi + q[5]
        gx = 2 * q[0] * xi + q[1] * yi + q[3]
        gy = q[1] * xi + 2 * q[2] * yi + q[4]
        out[i] = abs(f) / np.sqrt(gx * gx + gy * gy + 1e-30) * scale < threshold
    return out


@njit(cache=True, nogil=True)
def consensus(x, y, idx, probe, scale, threshold, batch, log_miss):
    """The best-supported minimal conic of ``ransac_ellipse``: hypotheses from the rows of idx
    (I,5) in batches of ``batch``, support counted on the points ``probe``; stops after the
    batch where, at the best support share w, I_drawn * log(1 - w^5) <= ``log_miss``.
    Returns (conic (6,), found)."""
    best = np.zeros(6)
    best_support = -1
    q = np.empty(6)
    xp, yp = x[probe], y[probe]
    x5, y5 = np.empty(5), np.empty(5)
    M = np.empty((5, 6))
    iterations = idx.shape[0]
    for k in range(0, iterations, batch):
        batch_best, batch_q = -1, np.zeros(6)
        for h in range(k, min(k + batch, iterations)):
            for m in range(5):
                x5[m], y5[m] = x[idx[h, m]], y[idx[h, m]]
            if not _conic_through(x5, y5, q, M):
                continue
            support = int(sampson_below(q, xp, yp, scale, threshold).sum())
            if support > batch_best:
                batch_best, batch_q = support, q.copy()
        if batch_best > best_support:
            best, best_support = batch_q, batch_best
        w = max(best_support, 0) / probe.size
        drawn = min(k + batch, iterations)
        if w > 0 and drawn * np.log1p(-min(w ** 5, 1 - 1e-12)) <= log_miss:
            break
    return best, best_support >= 0
