"""The rim detector's compiled loops (station/rim/fit_loops.py, profile_loops.py,
hough_loops.py) against the numpy forms they replaced (commit ee2aaf8), kept here as short
references: the same masks, indices and draws, and the same numbers to rounding."""

import numpy as np
import pytest
from scipy.special import erf

from station.rim import ellipse_fit, fit_loops, hough, profile_loops, subpixel
from station.rim.edges import EdgeSet
from station.rim.ellipse import Ellipse, Feet

RIM = Ellipse((640.4, 511.7), (300.0, 290.0), 0.3)
S_NARROW = np.arange(-3, 4.75, 0.5)   # 16 samples: the final pass's window
S_WIDE = np.arange(-7.5, 7.75, 0.5)   # 31
S_LONG = np.arange(-10, 10.25, 0.5)   # 41: the levels' means of 8 samples (numpy's pairwise sum)


# --- the numpy forms (ee2aaf8) --------------------------------------------------------------

def _feet_ref(e, pts, iterations=4, t0=None):
    """Ellipse.feet: Newton on the foot parameter."""
    x, y = e.local_xy(pts)
    a, b = e.axes_px
    t = np.arctan2(a * y, b * x) if t0 is None else t0
    for _ in range(iterations):
        ct, st = np.cos(t), np.sin(t)
        ex, ey, dx, dy = a * ct, b * st, -a * st, b * ct
        rx, ry = x - ex, y - ey
        t = t - (rx * dx + ry * dy) / (-(dx * dx + dy * dy) - rx * ex - ry * ey)
    ct, st = np.cos(t), np.sin(t)
    nx, ny = b * ct, a * st
    nn = np.hypot(nx, ny)
    return Feet(((x - a * ct) * nx + (y - b * st) * ny) / nn, t, ct, st, nx / nn, ny / nn)


def _fit_geometric_ref(pts, e, iterations=12, huber_k=1.5, reject_sigma=3.5):
    """fit_geometric: (ellipse, cov, inliers, residuals, iterations)."""
    p, lam, inl = e.params, 1e-4, np.ones(len(pts), bool)
    feet, it = _feet_ref(e, pts), 0
    for it in range(1, iterations + 1):
        d = feet.d
        sig = 1.4826 * np.median(np.abs(d[inl])) + 1e-6
        inl = np.abs(d) < max(reject_sigma * sig, 1e-3)
        ad = np.abs(d) / sig
        w = np.where(ad < huber_k, 1.0, huber_k / np.maximum(ad, 1e-12)) * inl
        J = ellipse_fit._jacobian(e, feet)
        H, g, cost = (J.T * w) @ J, (J.T * w) @ d, (w * d * d).sum()
        while True:
            step = -np.linalg.solve(H + lam * (np.diag(np.diag(H)) + 1e-12 * np.eye(5)), g)
            e_new = Ellipse.from_params(p + step)
            feet_new = _feet_ref(e_new, pts, 2, feet.t)
            if (w * feet_new.d ** 2).sum() <= cost or lam > 1e6:
                break
            lam *= 10
        lam = max(lam * 0.1, 1e-7)
        e, feet, p = e_new, feet_new, e_new.params
        if np.all(np.abs(step[:4]) < 1e-4) and abs(step[4] * (p[2] - p[3])) < 1e-4:
            break
    d = feet.d
    inl = np.abs(d) < reject_sigma * (1.4826 * np.median(np.abs(d[inl])) + 1e-9)
    J = ellipse_fit._jacobian(e, feet)[inl]
    cov = np.linalg.pinv(J.T @ J) * (d[inl] ** 2).sum() / max(int(inl.sum()) - 5, 1)
    return e, cov * ellipse_fit.COV_CORRELATION_FACTOR, inl, d, it


def _sampson_ref(Q, x, y):
    """|Sampson distance| (M,N) of points (x, y) (N,) to conics Q (M,6)."""
    one, zero = np.ones_like(x), np.zeros_like(x)
    f = np.stack([x * x, x * y, y * y, x, y, one]).T @ Q.T
    gx = np.stack([2 * x, y, zero, one, zero, zero]).T @ Q.T
    gy = np.stack([zero, x, 2 * y, zero, one, zero]).T @ Q.T
    return (np.abs(f) / np.sqrt(gx * gx + gy * gy + 1e-30)).T


def _minimal_conics_ref(xs, ys):
    """Conics (I,6) with F = -1 through each row of 5 points (I,5), and (I,) whether each is a
    usable ellipse (|det| > 1e-12, B^2 < 4AC)."""
    M = np.stack([xs * xs, xs * ys, ys * ys, xs, ys], axis=2)
    ok = np.abs(np.linalg.det(M)) > 1e-12
    Q = np.full((len(M), 6), -1.0)
    if ok.any():
        Q[ok, :5] = np.linalg.solve(M[ok], np.ones((int(ok.sum()), 5, 1)))[:, :, 0]
    return Q, ok & (Q[:, 1] ** 2 - 4 * Q[:, 0] * Q[:, 2] < 0)


def _centred(pts):
    mean = pts.mean(axis=0)
    scale = np.sqrt(((pts - mean) ** 2).sum(axis=1).mean()) + 1e-12
    return (pts[:, 0] - mean[0]) / scale, (pts[:, 1] - mean[1]) / scale, scale


def _ransac_ref(pts, threshold_px, iterations=160, seed=0, batch=32, confidence=0.9999, stop=True):
    """ransac_ellipse: (inlier mask or None, best conic, each batch's best support)."""
    x, y, scale = _centred(pts)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(pts), (iterations, 5))
    probe = rng.choice(len(pts), min(len(pts), 400), replace=False)
    best_q, best_support, supports = None, -1, []
    for k in range(0, iterations, batch):
        Q, use = _minimal_conics_ref(x[idx[k:k + batch]], y[idx[k:k + batch]])
        supports.append(-1)
        if use.any():
            support = (_sampson_ref(Q[use], x[probe], y[probe]) * scale < threshold_px).sum(axis=1)
            j = int(np.argmax(support))
            supports[-1] = int(support[j])
            if support[j] > best_support:
                best_q, best_support = Q[use][j], int(support[j])
        w = max(best_support, 0) / len(probe)
        if stop and w > 0 and min(k + batch, iterations) * np.log1p(-min(w ** 5, 1 - 1e-12)) <= np.log(1 - confidence):
            break
    if best_q is None:
        return None, None, supports
    return _sampson_ref(best_q[None], x, y)[0] * scale < threshold_px, best_q, supports


def _parabola_ref(y0, y1, y2):
    with np.errstate(invalid="ignore", over="ignore"):
        y0, y2 = np.where(np.isfinite(y0), y0, y1), np.where(np.isfinite(y2), y2, y1)
        den = y0 - 2 * y1 + y2
        off = np.where(den > 1e-12, 0.5 * (y0 - y2) / np.where(den > 1e-12, den, 1.0), 0.0)
        return np.where(np.isnan(off), 0.0, np.clip(off, -1.0, 1.0))


def _grid_search_ref(prof, Q, H, G, polarity):
    """fit_kinks' grid search: (g, parabola offset, res, h at g, finite) (N,)."""
    n, r = len(prof), np.arange(len(prof))
    proj = (prof @ Q).reshape(n, G, -1)
    res = np.einsum("ns,ns->n", prof, prof)[:, None] - np.einsum("ngk,ngk->ng", proj, proj)
    h_all = prof @ H
    res[h_all * polarity <= 0] = np.inf
    g = np.argmin(res, axis=1)
    ok = np.isfinite(res[r, g])
    g = np.clip(g, 1, G - 2)
    return g, _parabola_ref(res[r, g - 1], res[r, g], res[r, g + 1]), res[r, g], h_all[r, g], ok


def _fit_kinks_ref(prof, s, sigma, polarity=-1.0, grid_step=0.25, curvature=None):
    """fit_kinks(..., refine=False): (s0, h, rms, ok) (N,)."""
    grid = np.arange(s[0] + 1.0, s[-1] - 1.0 + 1e-9, grid_step)
    Q, H = subpixel._kink_projector(s, grid, sigma, curvature)
    g, off, res, h, ok = _grid_search_ref(prof, Q, H, len(grid), polarity)
    return grid[g] + off * grid_step, h, np.sqrt(np.maximum(res, 0) / len(s)), ok


def _initial_steps_ref(prof, s, polarity=-1.0):
    n, S = prof.shape
    r = np.arange(n)
    d = np.gradient(prof, s, axis=1) * polarity
    j = np.clip(np.argmax(d, axis=1), 1, S - 2)
    y0, y1, y2 = d[r, j - 1], d[r, j], d[r, j + 1]
    den = y0 - 2 * y1 + y2
    off = np.where(np.abs(den) > 1e-12, 0.5 * (y0 - y2) / np.where(den == 0, 1, den), 0.0)
    q = max(2, S // 5)
    lo, hi = prof[:, :q].mean(axis=1), prof[:, -q:].mean(axis=1)
    s0 = s[j] + np.clip(off, -1, 1) * (s[1] - s[0])
    return np.stack([(lo + hi) / 2, np.zeros(n), (hi - lo) / 2, s0, np.ones(n)], axis=1)


def _tyre_rise_ref(prof, s, s0, sigma):
    """_tyre_side_flat's rise (N,): the highest sample beyond 1.5 sigma of s0 above the mean of
    those within 1.01 px further (of the last sample where none are)."""
    x = s[None, :] - s0[:, None]
    far = x > 1.5 * sigma
    near = far & (x < 1.5 * sigma + 1.01)
    n_near = near.sum(axis=1)
    low = np.where(n_near > 0, np.where(near, prof, 0.0).sum(axis=1) / np.maximum(n_near, 1), prof[:, -1])
    top = np.where(far, prof, -np.inf).max(axis=1)
    return np.where(np.isfinite(top), top, low) - low


def _pair_midpoints_ref(edges, d_min, d_max, max_pairs=3_000_000):
    """pair_midpoints: (mid, ia, ib) and the pairs found per direction-bin pair."""
    phi = np.arctan2(edges.grad[:, 1], edges.grad[:, 0])
    k = ((phi + np.pi) * (hough.N_DIR_BINS / (2 * np.pi))).astype(np.int64) % hough.N_DIR_BINS
    order = np.argsort(k, kind="stable")
    starts = np.concatenate([[0], np.cumsum(np.bincount(k, minlength=hough.N_DIR_BINS))])
    u, v = edges.points[order].T.astype(np.float32)
    gu, gv = edges.grad[order].T.astype(np.float32)
    half, c2 = hough.N_DIR_BINS // 2, hough.MIN_CHORD_COS ** 2
    ias, ibs = [], []
    for b in range(half):
        A, B = slice(starts[b], starts[b + 1]), slice(starts[b + half], starts[b + half + 1])
        du, dv = u[None, B] - u[A, None], v[None, B] - v[A, None]
        dist2 = du * du + dv * dv
        dot_a, dot_b = du * gu[A, None] + dv * gv[A, None], du * gu[None, B] + dv * gv[None, B]
        lim = c2 * dist2
        i, j = np.nonzero((dist2 > d_min * d_min) & (dist2 < d_max * d_max) & (dot_a > 0) & (dot_b < 0)
                          & (dot_a * dot_a > lim) & (dot_b * dot_b > lim))
        ias.append(order[A][i])
        ibs.append(order[B][j])
        if sum(map(len, ias)) > max_pairs:
            break
    ia, ib = np.concatenate(ias), np.concatenate(ibs)
    return 0.5 * (edges.points[ia] + edges.points[ib]), ia, ib, [len(i) for i in ias]


def _polarity_ref(e, edges, tol, inward=True):
    """polarity_inliers by brute force: every pixel's approximate distance and gradient cosine."""
    x, y = e.local_xy(edges.points)               # the removed Ellipse.approx_distance_grad
    a, b = e.axes_px
    gx, gy = x / (a * a), y / (b * b)
    r, g = np.sqrt(x * gx + y * gy), np.maximum(np.hypot(gx, gy), 1e-12)
    d = (r - 1.0) * r / g
    c, s = e.cos_sin
    cosg = -((c * gx - s * gy) / g * edges.grad[:, 0] + (s * gx + c * gy) / g * edges.grad[:, 1])
    return np.flatnonzero((np.abs(d) < tol) & ((cosg if inward else np.abs(cosg)) > hough.NORMAL_COS))


# --- synthetic data -------------------------------------------------------------------------

def _rim_points(rng, n=1000, outlier_share=0.1, noise=0.1, outer_px=6.0):
    """(N,2) points on RIM with noise, a share of them on the concentric ellipse outer_px outside;
    and (N,) which those are."""
    t = rng.uniform(0, 2 * np.pi, n)
    out = rng.random(n) < outlier_share
    outer = Ellipse(RIM.center_px, RIM.axes_px + outer_px, RIM.angle_rad)
    pts = np.where(out[:, None], outer.point_at(t), RIM.point_at(t))
    return pts + rng.normal(0, noise, (n, 1)) * RIM.normal_at(t), out


def _kink_profiles(rng, s, n, sigma=1.0, noise=1.5, polarity=-1.0, wrong=0):
    """(N+wrong, S) blurred step-and-kink profiles with noise (the fit_kinks model), the last
    ``wrong`` with the jump against the polarity; and the N + wrong edge positions."""
    m = n + wrong
    s0 = rng.uniform(s[0] + 2, s[-1] - 2.5, m)
    h = polarity * rng.uniform(20, 90, m) * np.where(np.arange(m) < n, 1, -1)
    x = s[None, :] - s0[:, None]
    Phi, phi = 0.5 * (1 + erf(x / (sigma * np.sqrt(2)))), np.exp(-0.5 * (x / sigma) ** 2) / np.sqrt(2 * np.pi)
    A, B, k = rng.uniform(90, 180, (m, 1)), rng.normal(0, 3, (m, 1)), rng.normal(0, 4, (m, 1))
    return A + h[:, None] * Phi + B * x + k * (x * Phi + sigma * phi) + rng.normal(0, noise, x.shape), s0


def _rim_edges(rng, inner_px=20.0, clutter=1200, shape=(1024, 1280)):
    """EdgeSet of RIM and a concentric contour inner_px inside (pixel a pixel apart, rounded,
    gradient inward within ~5 deg), and clutter pixels with random gradients."""
    pts, grad = [], []
    for dr in (0.0, -inner_px):
        e = Ellipse(RIM.center_px, RIM.axes_px + dr, RIM.angle_rad)
        t = np.arange(0, 2 * np.pi, 1.0 / e.axes_px[0])
        pts.append(np.round(e.point_at(t)))
        inward = -e.normal_at(t)
        ang = np.arctan2(inward[:, 1], inward[:, 0]) + rng.normal(0, 0.08, len(t))
        grad.append(np.stack([np.cos(ang), np.sin(ang)], axis=1))
    ang = rng.uniform(-np.pi, np.pi, clutter)
    pts.append(np.floor(rng.random((clutter, 2)) * shape[::-1]))
    grad.append(np.stack([np.cos(ang), np.sin(ang)], axis=1))
    p = np.concatenate(pts)
    return EdgeSet(p, np.concatenate(grad), np.full(len(p), 50.0), shape)


# --- fit_loops ------------------------------------------------------------------------------

def test_normalised_is_from_params():
    rng = np.random.default_rng(1)
    for p in np.column_stack([rng.uniform(0, 1000, (400, 2)), rng.uniform(-300, 300, (400, 2)),
                              rng.uniform(-10, 10, 400)]):
        assert np.array_equal(fit_loops.normalised(p), Ellipse.from_params(p).params)


@pytest.mark.parametrize("iterations, start", [(4, False), (2, True)])
def test_feet_are_the_newton_feet(iterations, start):
    rng = np.random.default_rng(2)
    pts, _ = _rim_points(rng, 1000, noise=2.0)
    e = Ellipse(RIM.center_px + 0.7, RIM.axes_px * 1.01, RIM.angle_rad + 0.05)
    t0 = _feet_ref(RIM, pts).t if start else None
    want = _feet_ref(e, pts, iterations, t0)
    got = [np.empty(len(pts)) for _ in range(6)]
    fit_loops.feet(pts[:, 0].copy(), pts[:, 1].copy(), e.params, t0 if start else got[1], iterations, start, *got)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-11)


@pytest.mark.parametrize("seed, turn, iterations", [(3, None, 12), (9, 0.3, 12), (5, 0.6, 3)])
def test_geometric_fit_is_the_numpy_levenberg_marquardt(seed, turn, iterations):
    """From the direct fit; from a start 2 px and ``turn`` rad off (seed 9: the angle's step
    keeps it going one iteration after the others' fell below 1e-4); cut at 3 iterations."""
    pts, out = _rim_points(np.random.default_rng(seed))
    init = (ellipse_fit.fit_direct(pts) if turn is None else
            Ellipse(RIM.center_px + 2.0, RIM.axes_px * 1.01, RIM.angle_rad + turn))
    fit = ellipse_fit.fit_geometric(pts, init=init, iterations=iterations)
    e, cov, inl, d, it = _fit_geometric_ref(pts, init, iterations)
    np.testing.assert_allclose(fit.ellipse.params, e.params, rtol=0, atol=1e-10)
    np.testing.assert_allclose(fit.residuals, d, rtol=0, atol=1e-10)
    assert np.array_equal(fit.inliers, inl) and fit.iterations == it
    np.testing.assert_allclose(fit.cov, cov, rtol=1e-8, atol=0)
    assert fit.sigma_px == pytest.approx(np.sqrt(np.mean(d[inl] ** 2)), rel=1e-9)
    if iterations == 12:  # converged, the outer contour rejected
        assert it < 12 and not inl[out].any() and inl[~out].mean() > 0.98


def test_conic_through_solves_the_5x5_system():
    """Samples of the rim; with a repeated point; random points (mostly hyperbolas); clusters
    0.01 wide (|det| around the 1e-12 bound); hyperbolas 1e-5 from a parabola."""
    rng = np.random.default_rng(6)
    pts, _ = _rim_points(rng, 1000)
    x, y, _ = _centred(pts)
    idx = rng.integers(0, len(pts), (600, 5))
    idx[:40, 1] = idx[:40, 0]
    xs, ys = x[idx], y[idx]
    xs[40:80], ys[40:80] = rng.normal(size=(40, 5)), rng.normal(size=(40, 5))
    xs[80:120], ys[80:120] = (rng.normal(size=(2, 40, 1)) * 0.7 + 0.01 * rng.normal(size=(2, 40, 5)))
    eps = rng.uniform(1e-6, 1e-5, (5, 1))       # x^2 - eps y^2 - y + 0.5 = 0: B^2 - 4AC = 16 eps (F = -1)
    xs[120:125] = rng.uniform(-1, 1, (5, 5))
    ys[120:125] = (np.sqrt(1 + 4 * eps * (xs[120:125] ** 2 + 0.5)) - 1) / (2 * eps)
    Q, use = _minimal_conics_ref(xs, ys)
    det = np.abs(np.linalg.det(np.stack([xs * xs, xs * ys, ys * ys, xs, ys], axis=2)))
    q, M = np.empty(6), np.empty((5, 6))
    for k in range(len(idx)):
        assert fit_loops._conic_through(xs[k].copy(), ys[k].copy(), q, M) == use[k]
        if use[k]:
            np.testing.assert_allclose(q, Q[k], rtol=1e-9 if det[k] > 1e-9 else 1e-6, atol=1e-12)
    assert not use[:40].any() and 0 < use[40:80].sum() < 40 and use[125:].mean() > 0.9
    assert (det[80:120] < 1e-12).sum() >= 10 and use[80:120].sum() >= 5 and not use[120:125].any()


def test_sampson_below_is_the_sampson_mask():
    rng = np.random.default_rng(7)
    pts, _ = _rim_points(rng, 1000, noise=0.5)
    x, y, scale = _centred(pts)
    Q, use = _minimal_conics_ref(*(c[rng.integers(0, len(pts), (200, 5))] for c in (x, y)))
    dist = _sampson_ref(Q[use], x, y) * scale
    for q, dq in zip(Q[use], dist):
        for threshold in (0.3, 1.0, 3.0):
            assert np.array_equal(fit_loops.sampson_below(q, x, y, scale, threshold), dq < threshold)


@pytest.mark.parametrize("seed", [8, 9, 10])
def test_consensus_takes_the_references_conic(seed):
    pts, _ = _rim_points(np.random.default_rng(seed))
    x, y, scale = _centred(pts)
    rng = np.random.default_rng(seed)
    idx, probe = rng.integers(0, len(pts), (160, 5)), rng.choice(len(pts), 400, replace=False)
    q, found = fit_loops.consensus(x, y, idx, probe, scale, 1.0, 32, np.log(1 - 0.9999))
    _, q_ref, _ = _ransac_ref(pts, 1.0, seed=seed)
    assert found
    np.testing.assert_allclose(q, q_ref, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_ransac_inliers_are_the_references_and_the_flange(seed):
    pts, out = _rim_points(np.random.default_rng(seed))
    inl = ellipse_fit.ransac_ellipse(pts, threshold_px=1.0, seed=seed)
    want, _, _ = _ransac_ref(pts, 1.0, seed=seed)
    assert np.array_equal(inl, want)
    assert not inl[out].any() and inl[~out].mean() > 0.99


def test_ransac_stops_where_the_reference_stops():
    """Two contours with 65 / 35 % of the points: the search stops at the confidence rule
    after 3 of 5 batches; a search over all 160 samples finds another best conic."""
    pts, out = _rim_points(np.random.default_rng(14), 800, outlier_share=0.35, noise=0.3)
    want, _, supports = _ransac_ref(pts, 1.0, seed=24)
    every, _, _ = _ransac_ref(pts, 1.0, seed=24, stop=False)
    assert len(supports) == 3 and not np.array_equal(want, every) and not want[out].any()
    assert np.array_equal(ellipse_fit.ransac_ellipse(pts, 1.0, seed=24), want)


def test_ransac_keeps_the_first_of_equally_supported_conics():
    pts, _ = _rim_points(np.random.default_rng(14), 800, outlier_share=0.35, noise=0.3)
    want, _, supports = _ransac_ref(pts, 1.0, seed=49)
    assert supports[0] == supports[1] == max(supports)    # batch 2's best ties batch 1's
    assert np.array_equal(ellipse_fit.ransac_ellipse(pts, 1.0, seed=49), want)


def test_ransac_without_an_ellipse_is_none():
    t = np.linspace(-2, 2, 60)
    line = np.stack([100 + 30 * t, 50 + 10 * t], axis=1)
    hyperbola = np.stack([40 * np.cosh(t), 25 * np.sinh(t)], axis=1)
    for pts in (line, hyperbola):
        assert ellipse_fit.ransac_ellipse(pts, 1.0, seed=3) is None and _ransac_ref(pts, 1.0, seed=3)[0] is None


# --- profile_loops --------------------------------------------------------------------------

def test_parabola_is_numpys():
    inf, nan = np.inf, np.nan
    rng = np.random.default_rng(15)
    cases = [(1, 0, 1), (2, 0, 1), (1, 0, 5), (5, 0, 1), (0, 0, 0), (1, 2, 1), (1, 1 - 1e-13, 1),
             (1, 1 - 2e-13, 1 - 1e-13), (1, 1 - 1e-12, 1 + 1e-12),    # den <= 1e-12: no offset
             (inf, 0, 1), (1, 0, inf), (inf, 0, inf), (inf, inf, inf), (inf, inf, 3), (nan, 0, 1), (1, nan, 1),
             (-inf, 0, 1), (1e300, -1e300, 1e300)] + [tuple(v) for v in rng.normal(size=(200, 3))]
    y = np.array(cases, float).T
    want = _parabola_ref(*y)
    got = np.array([profile_loops.parabola(*c) for c in np.array(cases, float)])
    assert np.array_equal(got, want)


def _assert_kinks_equal(got, want, s):
    """(s0, h, rms, ok) alike: ok the same, s0 to 1e-9 px (1e-8 in a wide window, where the
    parabola through residual sums of squares of ~6e5 that agree to 1e-10 moves by 3e-9 px
    on the flattest minima), h and rms to 1e-9 (rms inf where every position is ruled out)."""
    assert np.array_equal(got[3], want[3])
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-9 if len(s) <= 16 else 1e-8)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-9, atol=0)
    np.testing.assert_allclose(got[2], want[2], rtol=1e-9, atol=0)


@pytest.mark.parametrize("s, sigma, polarity, curvature, grid_step, ruled_out",
                         [(S_NARROW, 1.0, -1.0, False, 0.125, 15), (S_NARROW, 0.8, -1.0, True, 0.125, 0),
                          (S_WIDE, 1.6, -1.0, False, 0.25, 0), (S_NARROW, 1.0, 1.0, False, 0.25, 15)])
def test_fit_kinks_grid_search_is_numpys(s, sigma, polarity, curvature, grid_step, ruled_out):
    """600 profiles and 100 with the jump against the polarity: of these, in the narrow window,
    about a fifth have it so at every position (the curved model or a wide window find a
    position of the expected sign in nearly all)."""
    prof, _ = _kink_profiles(np.random.default_rng(16), s, 600, sigma, polarity=polarity, wrong=100)
    got = subpixel.fit_kinks(prof, s, sigma, polarity, grid_step=grid_step, refine=False, curvature=curvature)
    s0, h, rms, ok = _fit_kinks_ref(prof, s, sigma, polarity, grid_step, curvature)
    assert ok[:600].all() and (~ok).sum() >= ruled_out
    _assert_kinks_equal(got, (s0, h, rms, ok), s)
    assert np.array_equal(got[0][~ok], s0[~ok]) and (s0[~ok] == s[0] + 1 + grid_step).all()


@pytest.mark.parametrize("s, sigma", [(S_NARROW, 0.9), (S_WIDE, 1.7)])
def test_straight_and_curved_from_one_product_are_two_fit_kinks(s, sigma):
    prof, _ = _kink_profiles(np.random.default_rng(17), s, 600, sigma, wrong=100)
    straight, curved = subpixel.fit_kinks_straight_and_curved(prof, s, sigma, grid_step=0.125)
    for got, curvature in ((straight, False), (curved, True)):
        s0, h, rms, ok = _fit_kinks_ref(prof, s, sigma, grid_step=0.125, curvature=curvature)
        assert (~ok).sum() >= (10 if len(s) == 16 and not curvature else 0)
        _assert_kinks_equal(got, (s0, h, rms, ok), s)


def test_curved_where_needed_from_the_shared_product_is_from_two_fit_kinks():
    """edge_points' path (both models from one product) and the former one (the curved model
    by its own fit_kinks), on profiles whose first half has a rounded lip: the curved model
    taken on most of it, the straight one kept on some arcs of the rest."""
    rng = np.random.default_rng(25)
    prof, s0 = _kink_profiles(rng, S_NARROW, 720, sigma=0.9)
    x, z = S_NARROW[None, :] - s0[:, None], (S_NARROW[None, :] - s0[:, None]) / 0.9
    Phi, phi = 0.5 * (1 + erf(z / np.sqrt(2))), np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi)
    prof[:360] -= 8 * ((x * x + 0.81) * (1 - Phi) - x * 0.9 * phi)[:360]   # the metal side's curvature
    straight, curved = subpixel.fit_kinks_straight_and_curved(prof, S_NARROW, 0.9)
    got = subpixel._curved_where_needed(prof, S_NARROW, 0.9, *straight, curved=curved)
    ref_straight = _fit_kinks_ref(prof, S_NARROW, 0.9, grid_step=0.125, curvature=False)
    want = subpixel._curved_where_needed(prof, S_NARROW, 0.9, *ref_straight)
    _assert_kinks_equal(got, want, S_NARROW)
    taken = got[0] != ref_straight[0]
    assert taken[:360].mean() > 0.8 and 0.1 < taken[360:].mean() < 0.9


@pytest.mark.parametrize("s, polarity", [(S_NARROW, -1.0), (S_WIDE, -1.0), (S_NARROW, 1.0)])
def test_blur_rms_is_fit_kinks_rms_per_blur(s, polarity):
    prof, _ = _kink_profiles(np.random.default_rng(18), s, 200, 1.1, polarity=polarity, wrong=30)
    want = np.stack([_fit_kinks_ref(prof, s, sg, polarity)[2] for sg in subpixel.BLUR_GRID_PX], axis=1)
    got = subpixel._blur_rms(prof, s, polarity)
    assert np.isinf(want).sum() >= 10 and np.array_equal(np.isinf(got), np.isinf(want))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=0)


def test_grid_minima_of_rows_ruled_out_or_best_at_the_ends():
    """Every position ruled out: index 0 clipped to 1, residual inf, not finite; a best first or
    last position: clipped inward and finite, the parabola through its neighbours."""
    G, nb = 9, 4
    proj = np.zeros((3, G * nb))
    res = np.array([[5., 6, 7, 8, 9, 9, 9, 9, 9], [9., 9, 9, 9, 9, 8, 7, 6, 5]])
    proj[1:, ::nb] = np.sqrt(10 - res)                  # res = ss - proj^2 with ss = 10
    h = np.array([[1.0] * G, [-1.0] * G, [-1.0] * G])
    g, off, r, hg, fin = profile_loops.grid_minima(proj, h, np.full(3, 10.0), 1, G, nb, -1.0)
    assert list(g[:, 0]) == [1, 1, G - 2] and list(fin[:, 0]) == [False, True, True]
    assert np.isinf(r[0, 0]) and off[0, 0] == 0 and hg[0, 0] == 1.0
    np.testing.assert_allclose(r[1:, 0], [6.0, 6.0], rtol=1e-12)
    assert list(off[1:, 0]) == list(_parabola_ref(np.array([5., 7]), np.array([6., 6]), np.array([7., 5])))


@pytest.mark.parametrize("s, polarity, grey_levels", [(S_NARROW, -1.0, False), (S_WIDE, -1.0, False),
                                                     (S_LONG, -1.0, False), (S_NARROW, 1.0, False),
                                                     (S_NARROW, -1.0, True)])
def test_initial_steps_is_numpys(s, polarity, grey_levels):
    """Also of whole grey levels: equal derivatives, the first of them taken."""
    prof, _ = _kink_profiles(np.random.default_rng(19), s, 600, polarity=polarity, wrong=40)
    prof = np.round(prof) if grey_levels else prof
    np.testing.assert_allclose(subpixel.initial_steps(prof, s, polarity), _initial_steps_ref(prof, s, polarity),
                               rtol=1e-13, atol=1e-11)


def test_initial_steps_on_an_uneven_grid_take_np_gradients_differences():
    rng = np.random.default_rng(20)
    s = np.cumsum(np.r_[-4.0, rng.uniform(0.3, 0.8, 17)])
    prof, _ = _kink_profiles(rng, s, 600)
    got, want = subpixel.initial_steps(prof, s), _initial_steps_ref(prof, s)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-11)
    uniform = np.linspace(s[0], s[-1], len(s))  # (the uneven grid's steps do matter)
    assert np.abs(_initial_steps_ref(prof, uniform)[:, 3] - want[:, 3]).max() > 0.1


@pytest.mark.parametrize("s", [S_NARROW, S_WIDE, np.r_[np.arange(-3, 2.1, 0.5), 3.5, 4.0]])
def test_tyre_side_flat_is_numpys(s):
    """The mask of the fits' own jumps, and the rise itself: with each row's jump set to just
    above and below four times its reference rise, max_rise 0.25 tells it to 1e-9."""
    rng = np.random.default_rng(21)
    prof, s_true = _kink_profiles(rng, s, 600, sigma=1.0)
    s0 = np.r_[s_true[:550], rng.uniform(s[-1] - 1.8, s[-1] + 0.5, 50)]  # nothing or one sample beyond
    h = -rng.uniform(5, 60, len(s0))
    rise = _tyre_rise_ref(prof, s, s0, 1.0)
    flat = subpixel._tyre_side_flat(prof, s, s0, h, 1.0)
    assert np.array_equal(flat, rise < 0.25 * np.abs(h)) and 0.1 < flat.mean() < 0.95
    pos = rise > 0
    assert np.array_equal(subpixel._tyre_side_flat(prof, s, s0, 4 * rise * (1 + 1e-9), 1.0), pos)
    assert not subpixel._tyre_side_flat(prof, s, s0, 4 * rise * (1 - 1e-9), 1.0).any()
    assert (~pos).sum() >= 10


# --- hough_loops ----------------------------------------------------------------------------

def test_pair_midpoints_is_the_numpy_pair_test():
    edges = _rim_edges(np.random.default_rng(22))
    mid, ia, ib = hough.pair_midpoints(edges, 2 * 51.2 * hough.MIN_AXIS_RATIO, 2 * 896.0)
    want_mid, want_a, want_b, _ = _pair_midpoints_ref(edges, 2 * 51.2 * hough.MIN_AXIS_RATIO, 2 * 896.0)
    assert len(ia) > 10000 and np.array_equal(ia, want_a) and np.array_equal(ib, want_b)
    assert np.array_equal(mid, want_mid)
    assert (np.linalg.norm(mid - RIM.center_px, axis=1) < 2.0).sum() > 3000  # the rim's pairs


@pytest.mark.parametrize("d_min, d_max, n_pairs", [(50.0, 60.0, 0), (49.99, 60.01, 4), (50.0, 60.01, 2),
                                                   (49.99, 60.0, 2)])
def test_pair_midpoints_exclude_chords_at_the_bounds(d_min, d_max, n_pairs):
    """Two diametral pairs 60 px apart, two 50 px apart (gradients inward, exactly opposite)."""
    offsets = np.array([[30, 0], [-30, 0], [0, 30], [0, -30], [15, 20], [-15, -20], [-15, 20], [15, -20]], float)
    edges = EdgeSet(100 + offsets, -offsets / np.linalg.norm(offsets, axis=1)[:, None], np.ones(8), (200, 200))
    mid, ia, ib = hough.pair_midpoints(edges, d_min, d_max)
    want_mid, want_a, want_b, _ = _pair_midpoints_ref(edges, d_min, d_max)
    assert len(ia) == n_pairs and np.array_equal(ia, want_a) and np.array_equal(ib, want_b)
    assert np.array_equal(mid, want_mid.reshape(-1, 2)) and (mid == 100).all()


@pytest.mark.parametrize("cut", ["inside a bin pair", "at a bin pair's end"])
def test_pair_midpoints_stop_after_the_bin_pair_over_max_pairs(cut):
    edges = _rim_edges(np.random.default_rng(23))
    d_min, d_max = 60.0, 1800.0
    *_, counts = _pair_midpoints_ref(edges, d_min, d_max)
    ends = np.cumsum(counts)
    k = 9
    max_pairs = int(ends[k] - counts[k] // 2) if cut == "inside a bin pair" else int(ends[k])
    want_mid, want_a, want_b, _ = _pair_midpoints_ref(edges, d_min, d_max, max_pairs)
    mid, ia, ib = hough.pair_midpoints(edges, d_min, d_max, max_pairs)
    assert len(want_a) == (ends[k] if cut == "inside a bin pair" else ends[k + 1]) and counts[k] > 0
    assert np.array_equal(ia, want_a) and np.array_equal(ib, want_b) and np.array_equal(mid, want_mid)


@pytest.mark.parametrize("tol", [1.5, 4.0, 16.5])
@pytest.mark.parametrize("inward", [True, False])
def test_polarity_inliers_of_an_eccentric_ellipse_are_brute_forces(tol, inward):
    """b/a = 0.55; pixels over the whole image and in a band of +-25 px round the ellipse,
    their gradients along either normal or anywhere."""
    rng = np.random.default_rng(24)
    e = Ellipse((512.3, 400.8), (330.0, 181.5), 0.4)
    t = rng.uniform(0, 2 * np.pi, 6000)
    band = e.point_at(t) + rng.uniform(-25, 25, (6000, 1)) * e.normal_at(t)
    sign = np.where(rng.random(6000) < 0.7, -1.0, 1.0)[:, None]
    nrm = e.normal_at(t) * sign + rng.normal(0, 0.25, (6000, 2))
    spread = rng.random((4000, 2)) * (1280, 1024)
    ang = rng.uniform(-np.pi, np.pi, 4000)
    pts = np.concatenate([band, spread, [e.center_px]])
    grad = np.concatenate([nrm / np.linalg.norm(nrm, axis=1)[:, None], np.stack([np.cos(ang), np.sin(ang)], 1),
                           [[1.0, 0.0]]])
    edges = EdgeSet(pts, grad, np.ones(len(pts)), (1024, 1280))
    got = hough.polarity_inliers(e, edges, tol, inward=inward)
    want = _polarity_ref(e, edges, tol, inward)
    assert np.array_equal(got, want) and len(want) > 100
    assert got.dtype == np.int64


def _outer_contour_ref(edges, e):
    """choice.outer_contour (ee2aaf8): the support of a concentric contour 1.15-2 times larger."""
    x, y = e.local_xy(edges.points)
    a, b = e.axes_px
    rr = np.sqrt((x / a) ** 2 + (y / b) ** 2)
    sel = np.flatnonzero((rr > 1.15) & (rr < 2.0))
    if len(sel) < 10:
        return 0.0
    nx, ny = x[sel] / a**2, y[sel] / b**2
    c, s = e.cos_sin
    nx, ny = c * nx - s * ny, s * nx + c * ny
    norm = np.sqrt(nx * nx + ny * ny)
    aligned = np.abs(nx / norm * edges.grad[sel, 0] + ny / norm * edges.grad[sel, 1]) > hough.NORMAL_COS
    r = rr[sel][aligned] * a
    if len(r) < 10:
        return 0.0
    hist = np.convolve(np.bincount(np.round(r).astype(int)), np.ones(5), mode="same")
    frac = hist / np.maximum(np.pi * np.arange(len(hist)) * (1 + b / a), 1)
    return float(np.clip(frac.max() / 0.4, 0, 1))


@pytest.mark.parametrize("scale", [1.0, 0.6, 0.35])
def test_outer_contour_is_the_numpy_annulus_test(scale):
    """Round the rim (clutter alone in the annulus 1.15-2x), round a contour 0.6 of it (the rim
    is its outline) and round a hub 0.35 of it (the rim lies beyond the annulus)."""
    from station.rim.choice import outer_contour

    class Scene:
        edges = _rim_edges(np.random.default_rng(24))

    e = Ellipse(RIM.center_px, RIM.axes_px * scale, RIM.angle_rad)
    want = _outer_contour_ref(Scene.edges, e)
    assert outer_contour(Scene, e) == want
    assert (want > 0.5) == (scale == 0.6)
