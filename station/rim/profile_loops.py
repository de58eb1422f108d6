"""The edge-profile model's grid search, compiled (numba).

The step-and-kink model (``subpixel.fit_kinks``) projects every profile onto its orthonormal
bases at every trial edge position by one BLAS product; what follows (the residual at each
position, the jumps of the wrong polarity ruled out, the best position, its neighbours and the
parabola through them) took six numpy passes over (N, G) and (N, G, nb) arrays, and more time
than the product. Here it is one pass over the product, per profile and per blur candidate.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def parabola(y0, y1, y2):
    """Vertex offset (grid steps, clipped to +/-1) of the parabola through three values, a
    non-finite neighbour taken as y1; 0 where it opens downward (``subpixel._parabola``)."""
    if not np.isfinite(y0):
        y0 = y1
    if not np.isfinite(y2):
        y2 = y1
    den = y0 - 2 * y1 + y2
    if not den > 1e-12:
        return 0.0
    off = 0.5 * (y0 - y2) / den
    if np.isnan(off):
        return 0.0
    return min(max(off, -1.0), 1.0)


@njit(cache=True, nogil=True)
def _pick(res):
    """The grid's best of residuals res (G,): its first minimum (np.argmin's, index 0 if all
    are infinite), clipped to [1, G-2] as the parabola needs two neighbours. Returns (g,
    parabola offset at g, res at g, whether the unclipped minimum was finite)."""
    best, k_best = np.inf, 0
    for g in range(res.size):
        if res[g] < best:
            best, k_best = res[g], g
    g = min(max(k_best, 1), res.size - 2)
    return g, parabola(res[g - 1], res[g], res[g + 1]), res[g], np.isfinite(res[k_best])


@njit(cache=True, nogil=True)
def grid_minima(proj, h_all, ss, n_models, n_grid, nb, polarity):
    """Best trial edge position of each profile under each model.

    proj (N, M*G*nb): each profile's coordinates in the orthonormal bases of M models (blur
    candidates) at G grid positions; h_all (N, M*G) the jump at each; ss (N,) each profile's
    sum of squares. Residual res = ss - |proj|^2, infinite where the jump is against
    ``polarity``. Per profile and model, ``_pick``'s (g, parabola offset, res at g, finite)
    and the jump h at g, each (N, M): (g, offset, res, h, finite)."""
    n = proj.shape[0]
    g_out = np.empty((n, n_models), np.int64)
    off, res_g, h_g = np.empty((n, n_models)), np.empty((n, n_models)), np.empty((n, n_models))
    finite = np.empty((n, n_models), np.bool_)
    res = np.empty(n_grid)
    for i in range(n):
        for m in range(n_models):
            for g in range(n_grid):
                col = (m * n_grid + g) * nb
                acc = 0.0
                for k in range(nb):
                    acc += proj[i, col + k] * proj[i, col + k]
                res[g] = ss[i] - acc if h_all[i, m * n_grid + g] * polarity > 0 else np.inf
            g, off[i, m], res_g[i, m], finite[i, m] = _pick(res)
            g_out[i, m], h_g[i, m] = g, h_all[i, m * n_grid + g]
    return g_out, off, res_g, h_g, finite


@njit(cache=True, nogil=True)
def grid_minima_nested(proj, h_inner, h_outer, ss, n_grid, nb_inner, polarity):
    """``grid_minima`` of two models at once whose bases are nested: at each of the G grid
    positions proj (N, G*nb) holds the outer model's nb coordinates, the inner model's its
    first ``nb_inner`` (the straight and the curved kink model share one product). h_inner,
    h_outer (N,G) their jumps. Returns the inner's then the outer's (g, offset, res, h,
    finite), each (N,)."""
    n = proj.shape[0]
    nb = proj.shape[1] // n_grid
    g_in, g_out = np.empty(n, np.int64), np.empty(n, np.int64)
    off_in, res_in, hg_in, fin_in = np.empty(n), np.empty(n), np.empty(n), np.empty(n, np.bool_)
    off_out, res_out, hg_out, fin_out = np.empty(n), np.empty(n), np.empty(n), np.empty(n, np.bool_)
    r_in, r_out = np.empty(n_grid), np.empty(n_grid)
    for i in range(n):
        for g in range(n_grid):
            col = g * nb
            acc = 0.0
            for k in range(nb_inner):
                acc += proj[i, col + k] * proj[i, col + k]
            r_in[g] = ss[i] - acc if h_inner[i, g] * polarity > 0 else np.inf
            for k in range(nb_inner, nb):
                acc += proj[i, col + k] * proj[i, col + k]
            r_out[g] = ss[i] - acc if h_outer[i, g] * polarity > 0 else np.inf
        g, off_in[i], res_in[i], fin_in[i] = _pick(r_in)
        g_in[i], hg_in[i] = g, h_inner[i, g]
        g, off_out[i], res_out[i], fin_out[i] = _pick(r_out)
        g_out[i], hg_out[i] = g, h_outer[i, g]
    return (g_in, off_in, res_in, hg_in, fin_in), (g_out, off_out, res_out, hg_out, fin_out)


@njit(cache=True, nogil=True)
def initial_steps(prof, s, polarity):
    """Step parameters (N,5) (m, k, h, s0, w) of profiles (N,S) sampled at s (S,) without a fit
    (``subpixel.initial_steps``): s0 at the first strongest derivative of the expected sign
    (np.gradient's differences, its peak moved by a parabola, at most a sample), the levels
    from the means of the window's first and last fifth (at least 2 samples), w = 1."""
    n, S = prof.shape
    uniform = True
    for k in range(1, S - 1):
        uniform &= (s[k + 1] - s[k]) == (s[1] - s[0])
    step = s[1] - s[0]
    q = max(2, S // 5)
    out = np.empty((n, 5))
    d = np.empty(S)
    for i in range(n):
        f = prof[i]
        d[0] = (f[1] - f[0]) / (s[1] - s[0])
        d[S - 1] = (f[S - 1] - f[S - 2]) / (s[S - 1] - s[S - 2])
        for k in range(1, S - 1):
            if uniform:
                d[k] = (f[k + 1] - f[k - 1]) / (2.0 * step)
            else:  # np.gradient's second-order differences on an uneven grid
                hs, hd = s[k] - s[k - 1], s[k + 1] - s[k]
                d[k] = (hs * hs * f[k + 1] + (hd * hd - hs * hs) * f[k] - hd * hd * f[k - 1]) / (hs * hd * (hd + hs))
        j = 0
        for k in range(1, S):
            if d[k] * polarity > d[j] * polarity:
                j = k
        j = min(max(j, 1), S - 2)
        y0, y1, y2 = d[j - 1] * polarity, d[j] * polarity, d[j + 1] * polarity
        den = y0 - 2 * y1 + y2
        off = 0.5 * (y0 - y2) / den if abs(den) > 1e-12 else 0.0
        lo, hi = 0.0, 0.0
        for k in range(q):
            lo += f[k]
            hi += f[S - q + k]
        lo, hi = lo / q, hi / q
        out[i, 0], out[i, 1], out[i, 2] = (lo + hi) / 2, 0.0, (hi - lo) / 2
        out[i, 3], out[i, 4] = s[j] + min(max(off, -1.0), 1.0) * step, 1.0
    return out


@njit(cache=True, nogil=True)
def tyre_side_flat(prof, s, s0, h, sigma, max_rise):
    """(N,) bool: beyond the step at s0 (N,) each profile (N,S) climbs back by less than
    ``max_rise`` of its jump h (N,) (``subpixel._tyre_side_flat``): the highest sample beyond
    1.5 sigma of the edge against the mean of those within 1.01 px further (the last sample
    where there are none)."""
    n, S = prof.shape
    out = np.empty(n, np.bool_)
    near_from = 1.5 * sigma
    for i in range(n):
        total, count, top = 0.0, 0, -np.inf
        for k in range(S):
            x = s[k] - s0[i]
            if x > near_from:
                v = prof[i, k]
                top = max(top, v)
                if x < near_from + 1.01:
                    total += v
                    count += 1
        low = total / count if count > 0 else prof[i, S - 1]
        if not np.isfinite(top):
            top = low
        out[i] = (top - low) < max_rise * abs(h[i])
    return out
