"""The ellipse Hough's per-pixel tests, compiled (numba).

``hough.pair_midpoints`` tested every pixel of one gradient-direction bin against every pixel of
the opposite bin with a dozen numpy operations per bin pair, on (n_a, n_b) temporaries;
``hough.polarity_inliers`` gathered the pixels near a candidate ellipse through a grid of cells
before testing their distance and gradient. Each is one loop here, with the same arithmetic
(float32 where the pair test was float32) and the same order of results.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _pair_ok(du, dv, gua, gva, gub, gvb, d_min2, d_max2, c2):
    """The pair test of ``hough.pair_midpoints`` (all float32): the partner at a chord length
    within (d_min, d_max), along this pixel's gradient, this pixel along the reverse of the
    partner's, each within acos(sqrt(c2))."""
    dist2 = du * du + dv * dv
    if not (dist2 > d_min2 and dist2 < d_max2):
        return False
    dot_a = du * gua + dv * gva
    dot_b = du * gub + dv * gvb
    lim = c2 * dist2
    return dot_a > 0 and dot_b < 0 and dot_a * dot_a > lim and dot_b * dot_b > lim


@njit(cache=True, nogil=True)
def antiparallel_pairs(u, v, gu, gv, starts, half, d_min2, d_max2, c2, max_pairs):
    """Pairs (i, j) of positions in bin order (u, v, gu, gv (N,) float32 sorted by direction
    bin, ``starts`` (2*half + 1,) the bins' bounds) between each bin b < half and bin b + half
    that pass ``_pair_ok``: bin pair by bin pair, i then j ascending; after the bin pair that
    takes the count beyond ``max_pairs`` no more. Returns (ia (P,), ib (P,))."""
    size, largest = 0, 0
    for b in range(half):
        n_ab = (starts[b + 1] - starts[b]) * (starts[b + half + 1] - starts[b + half])
        size += n_ab
        largest = max(largest, n_ab)
    size = min(size, max_pairs + largest)  # room for every pair up to the bin pair that stops it
    ia = np.empty(size, np.int32)
    ib = np.empty(size, np.int32)
    p = 0
    for b in range(half):
        a0, a1, b0, b1 = starts[b], starts[b + 1], starts[b + half], starts[b + half + 1]
        for i in range(a0, a1):
            for j in range(b0, b1):
                if _pair_ok(u[j] - u[i], v[j] - v[i], gu[i], gv[i], gu[j], gv[j], d_min2, d_max2, c2):
                    ia[p], ib[p] = i, j
                    p += 1
        if p > max_pairs:
            break
    return ia[:p], ib[:p]


@njit(cache=True, nogil=True)
def polarity_inliers(px, py, gu, gv, cx, cy, a, b, c, s, tol, inward, normal_cos):
    """Indices (ascending) of the pixels (px, py) (N,) within ``tol`` of the ellipse (centre
    (cx, cy), semi-axes a, b, cos / sin of its angle c, s) whose unit gradient (gu, gv) (N,)
    meets the ellipse's outward normal at a cosine below -``normal_cos`` (brighter inside;
    with ``inward`` False, either way). Distance and normal are first-order, of the concentric
    similar ellipse through the pixel: d = (r - 1) / |grad r| with r the radius ratio
    sqrt(x^2/a^2 + y^2/b^2); within a few px of an ellipse of semi-axes >> 1 px it differs from
    the orthogonal distance by O(d^2 / a), and needs no iterations."""
    out = np.empty(px.size, np.int64)
    k = 0
    # the approximate distance |d| = |r - 1| r / |grad r| >= |r - 1| b with r between rho / a
    # and rho / b (rho the distance from the centre): a point nearer the centre than b - tol
    # or farther than a + tol a / b has |d| > tol, and this annulus test needs no root
    inner = max(b - tol, 0.0) ** 2
    outer = (a + tol * a / b) ** 2
    for i in range(px.size):
        du, dv = px[i] - cx, py[i] - cy
        rr = du * du + dv * dv
        if rr < inner or rr > outer:
            continue
        x, y = du * c + dv * s, -du * s + dv * c
        gx, gy = x / (a * a), y / (b * b)
        r = np.sqrt(x * gx + y * gy)
        g = max(np.hypot(gx, gy), 1e-12)
        if not abs((r - 1.0) * r / g) < tol:
            continue
        cosg = -((c * gx - s * gy) / g * gu[i] + (s * gx + c * gy) / g * gv[i])
        if not inward:
            cosg = abs(cosg)
        if cosg > normal_cos:
            out[k] = i
            k += 1
    return out[:k]


@njit(cache=True, nogil=True)
def concentric_radii(px, py, gu, gv, cx, cy, a, b, c, s, lo, hi, normal_cos):
    """Of the pixels (px, py) (N,) between the concentric similar ellipses ``lo`` and ``hi``
    times the ellipse (centre (cx, cy), semi-axes a, b, cos / sin of its angle c, s): how many
    there are, and the semi-major axis (K,) of the concentric ellipse through each whose unit
    gradient (gu, gv) lies along that ellipse's normal, either way (cosine above
    ``normal_cos``) - ``choice.outer_contour``'s support of a tyre outline."""
    radii = np.empty(px.size)
    n_between, k = 0, 0
    near, far = max(b * lo - 1.0, 0.0) ** 2, (a * hi + 1.0) ** 2  # (a bound that needs no root)
    for i in range(px.size):
        du, dv = px[i] - cx, py[i] - cy
        if not near < du * du + dv * dv < far:  # rr = lo lies at b lo .. a lo from the centre
            continue
        x, y = du * c + dv * s, -du * s + dv * c
        rr = np.sqrt((x / a) ** 2 + (y / b) ** 2)
        if not (rr > lo and rr < hi):
            continue
        n_between += 1
        nx, ny = x / a ** 2, y / b ** 2
        nx, ny = c * nx - s * ny, s * nx + c * ny
        norm = np.sqrt(nx * nx + ny * ny)
        if abs(nx / norm * gu[i] + ny / norm * gv[i]) > normal_cos:
            radii[k] = rr * a
            k += 1
    return n_between, radii[:k]
