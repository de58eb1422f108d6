"""A fast ellipse Hough transform over the parametrisation of eqs 1-3, in three small votes.

The naive Hough transform votes every edge point into a 5-D accumulator (u0, v0, a, b, theta):
hundreds of millions of cells. We decompose the five parameters instead:

1. **Centre (u0, v0): chord-midpoint voting with edge polarity.** On any ellipse the two points
   whose tangents are parallel are the ends of a diameter, so their midpoint is the centre. The
   gradient direction gives the tangent: edge pixels are binned by gradient direction, and each
   pixel is paired only with pixels in the *opposite* bin (antiparallel gradients). A pair votes
   only if the partner lies in the direction of the gradient (bright inside: the polarity of the
   rim flange against the dark tyre) and the chord is within 33 degrees of the gradient (true for
   every ellipse with b/a >= 0.55, a wheel seen up to ~55 degrees off its axis). Only the
   MAX_VOTERS strongest edge pixels vote. The midpoints go into a 2-D accumulator (2 px cells): a single
   O(sum_k n_k n_{k+K/2}) pass, with no per-point loop. Every concentric contour of the wheel
   with the same polarity votes for the same centre.
2. **Shape (theta, b/a): one linear solve.** With the centre known, write the ellipse as
   x^T M x = rho^2 (x = p - c). The normal at p is M x, parallel to the gradient g: the
   constraint g x (M x) = 0 is *linear and homogeneous* in (M11, M12, M22) and independent of the
   size rho, so every edge point that voted for the centre constrains the shape of all the
   similar concentric ellipses at once. A robust (IRLS) smallest singular vector gives M.
3. **Size (a): a 1-D histogram.** Every polarity-consistent edge point gives its own rho;
   peaks of the rho histogram are the concentric ellipses (rim flange, disc, hub, ...).

Each (centre, shape, size) triple is then refined by an algebraic fit of its own inliers.
Costs on a 426x341 image (1280x1024 / 3) with 4000 voters: ~5 ms, the per-pixel tests compiled
(``hough_loops``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from station.rim import hough_loops
from station.rim.edges import EdgeSet
from station.rim.ellipse import Ellipse
from station.rim.ellipse_fit import ransac_ellipse
from station.rim.npfast import median, row_norms, rows

N_DIR_BINS = 64             # gradient-direction bins for pairing (5.6 degrees)
MIN_CHORD_COS = 0.84        # chord within 33 degrees of the gradient (b/a >= 0.55)
MAX_VOTERS = 4000           # strongest edge pixels that vote for centres (time ~ N^2)
CELL_PX = 2.0               # centre accumulator cell
NORMAL_COS = 0.9            # gradient within 25 degrees of the ellipse normal
MIN_AXIS_RATIO = 0.55
BAND_SHARE = 0.5           # of the gap to the next concentric size: a candidate's band at most
MIN_BAND_PX = 1.5
MAX_SIZE_PEAKS = 5          # concentric sizes per centre: flange, lip highlight, spoke ring, hub, tyre
                            # (4 lost the flange of a small rim at 960x768 to its weaker contours)


@dataclass
class Candidate:
    """One ellipse found by the vote (in the coordinates of the edges it came from)."""

    ellipse: Ellipse
    centre_votes: float          # accumulator height at its centre
    coverage: float              # fraction of the visible perimeter with polarity-consistent edges
    n_inliers: int


def pair_midpoints(edges: EdgeSet, d_min: float, d_max: float, max_pairs: int = 3_000_000):
    """Midpoints of polarity-consistent antiparallel edge pairs.

    Returns (mid (P,2), ia (P,), ib (P,)): the midpoint of each accepted pair and the indices
    of its two edge pixels into ``edges``.
    """
    phi = np.arctan2(edges.grad[:, 1], edges.grad[:, 0])
    k = ((phi + np.pi) * (N_DIR_BINS / (2 * np.pi))).astype(np.int64) % N_DIR_BINS
    order = np.argsort(k, kind="stable")
    starts = np.concatenate([[0], np.cumsum(np.bincount(k, minlength=N_DIR_BINS))])
    # (N,) float32 columns in bin order: each bin's pixels are a slice, no gather per bin
    u, v = np.ascontiguousarray(rows(edges.points, order).T, dtype=np.float32)
    gu, gv = np.ascontiguousarray(rows(edges.grad, order).T, dtype=np.float32)
    f32 = np.float32
    i, j = hough_loops.antiparallel_pairs(u, v, gu, gv, starts, N_DIR_BINS // 2, f32(d_min * d_min),
                                          f32(d_max * d_max), f32(MIN_CHORD_COS**2), max_pairs)
    if len(i) == 0:
        return np.empty((0, 2)), np.empty(0, np.int64), np.empty(0, np.int64)
    ia, ib = order[i], order[j]
    return 0.5 * (rows(edges.points, ia) + rows(edges.points, ib)), ia, ib


def centre_peaks(mid: np.ndarray, shape: tuple[int, int], max_peaks: int = 6,
                 min_separation_px: float = 10.0) -> list[tuple[np.ndarray, float]]:
    """Local maxima of the midpoint accumulator: [(centre (2,), height), ...], highest first."""
    h, w = shape
    gw, gh = int(np.ceil(w / CELL_PX)), int(np.ceil(h / CELL_PX))
    cu = np.floor(mid[:, 0] / CELL_PX + 0.5 / CELL_PX).astype(np.int64)
    cv = np.floor(mid[:, 1] / CELL_PX + 0.5 / CELL_PX).astype(np.int64)
    inside = (cu >= 0) & (cu < gw) & (cv >= 0) & (cv < gh)
    acc = np.bincount(cv[inside] * gw + cu[inside], minlength=gw * gh).astype(np.float32).reshape(gh, gw)
    acc = cv2.GaussianBlur(acc, (0, 0), 1.0)
    r = max(1, int(round(min_separation_px / CELL_PX)))
    dil = cv2.dilate(acc, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    top = float(acc.max())
    if top <= 0:
        return []
    peaks = np.flatnonzero((acc >= dil) & (acc >= 0.15 * top))  # (np.argwhere's 2-D scan is slow)
    heights = acc.ravel()[peaks]
    pv, pu = np.divmod(peaks, gw)
    order = np.argsort(-heights)[:max_peaks]
    return [(np.array([(pu[i] + 0.5) * CELL_PX - 0.5, (pv[i] + 0.5) * CELL_PX - 0.5]),
             float(heights[i])) for i in order]


def estimate_shape(x: np.ndarray, g: np.ndarray, iterations: int = 4) -> np.ndarray | None:
    """Shape matrix M (2,2), smallest eigenvalue 1, from points x (N,2) relative to the centre
    and unit gradients g (N,2), by the size-free constraint g x (M x) = 0 (robust IRLS).
    None when the points do not define an ellipse with b/a >= MIN_AXIS_RATIO."""
    if len(x) < 8:
        return None
    rn = row_norms(x)[:, None]
    xn = x / np.maximum(rn, 1e-9)
    # g_x (M12 x + M22 y) - g_y (M11 x + M12 y) = 0 for m = (M11, M12, M22)
    A = np.stack([-g[:, 1] * xn[:, 0], g[:, 0] * xn[:, 0] - g[:, 1] * xn[:, 1], g[:, 0] * xn[:, 1]], axis=1)
    w = np.ones(len(A))
    m = np.array([1.0, 0.0, 1.0])
    for _ in range(iterations):
        _, _, Vt = np.linalg.svd(A * w[:, None], full_matrices=False)
        m = Vt[-1]
        r = A @ m
        s = 1.4826 * median(np.abs(r)) + 1e-12
        w = 1.0 / (1.0 + (r / (2.5 * s)) ** 2)
    M = np.array([[m[0], m[1]], [m[1], m[2]]])
    if M[0, 0] < 0:
        M = -M
    ev = np.linalg.eigvalsh(M)
    if ev[0] <= 0 or ev[0] / ev[1] < MIN_AXIS_RATIO**2:
        return None
    return M / ev[0]


def coverage_of(ellipse: Ellipse, pts: np.ndarray, shape: tuple[int, int], n_bins: int = 90,
                margin: float = 2.0) -> float:
    """Fraction of the ellipse's visible angular bins holding at least one of ``pts`` (N,2)."""
    if len(pts) == 0:
        return 0.0
    x, y = ellipse.local_xy(pts)
    a, b = ellipse.axes_px
    t = np.arctan2(y / b, x / a)
    k = ((t + np.pi) * (n_bins / (2 * np.pi))).astype(np.int64) % n_bins
    occupied = np.bincount(k, minlength=n_bins) > 0
    pc = ellipse.point_from_cos_sin(*_bin_centres(n_bins))
    h, w = shape
    visible = (pc[:, 0] >= margin) & (pc[:, 0] <= w - 1 - margin) & (pc[:, 1] >= margin) & (pc[:, 1] <= h - 1 - margin)
    if visible.sum() < n_bins // 4:  # less than a quarter of the ellipse in the image
        return 0.0
    return float((occupied & visible).sum() / visible.sum())


@lru_cache(maxsize=4)
def _bin_centres(n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """cos, sin (n_bins,) (read-only) of coverage_of's bin-centre parameters."""
    tc = (np.arange(n_bins) + 0.5) * (2 * np.pi / n_bins) - np.pi
    ct, st = np.cos(tc), np.sin(tc)
    ct.flags.writeable = st.flags.writeable = False
    return ct, st


def polarity_inliers(ellipse: Ellipse, edges: EdgeSet, tol_px: float, inward: bool = True) -> np.ndarray:
    """Indices of edge pixels within ``tol_px`` of the ellipse whose gradient agrees with its
    normal (inward = brighter inside)."""
    (cx, cy), (a, b), (c, s) = ellipse.center_px, ellipse.axes_px, ellipse.cos_sin
    return hough_loops.polarity_inliers(*edges.columns(), cx, cy, a, b, c, s, tol_px, inward, NORMAL_COS)


def size_peaks(edges: EdgeSet, centre: np.ndarray, M: np.ndarray, r_min: float, r_max: float,
               max_peaks: int = MAX_SIZE_PEAKS) -> list[float]:
    """Semi-major axes of concentric similar ellipses with polarity-consistent support."""
    x = edges.points - centre
    Mx = x @ M
    rho = np.sqrt(np.maximum(np.einsum("ij,ij->i", x, Mx), 0))
    n = Mx / np.maximum(row_norms(Mx)[:, None], 1e-9)
    inward = -np.einsum("ij,ij->i", n, edges.grad) > NORMAL_COS
    sel = inward & (rho >= r_min) & (rho <= r_max)
    if sel.sum() < 10:
        return []
    nb = int(np.ceil(r_max)) + 2
    hist = np.bincount(np.round(rho[sel]).astype(np.int64), minlength=nb)[:nb].astype(np.float64)
    hist = np.convolve(hist, [1, 2, 3, 2, 1], mode="same") / 3.0
    # expected count for full support: ~ the perimeter in px (one edge pixel per px of arc)
    ev = np.linalg.eigvalsh(M)
    q = np.sqrt(ev[0] / ev[1])
    r = np.arange(nb)
    frac = hist / np.maximum(np.pi * r * (1 + q), 1.0)
    is_peak = (hist >= np.roll(hist, 1)) & (hist > np.roll(hist, -1)) & (frac > 0.15) & (r >= r_min)
    idx = np.nonzero(is_peak)[0]
    idx = idx[np.argsort(-frac[idx])][:max_peaks]
    return [float(i) for i in idx]


def find_candidates(edges: EdgeSet, r_min: float, r_max: float, max_centres: int = 5,
                    max_candidates: int = 12) -> list[Candidate]:
    """All plausible bright-inside ellipses with semi-major axis in [r_min, r_max] (px)."""
    if len(edges) < 20:
        return []
    voters = edges
    if len(edges) > MAX_VOTERS:
        keep = np.sort(np.argpartition(-edges.mag, MAX_VOTERS)[:MAX_VOTERS])
        voters = edges.subset(keep)
    else:
        keep = np.arange(len(edges))
    mid, ia, ib = pair_midpoints(voters, 2 * r_min * MIN_AXIS_RATIO, 2 * r_max)
    ia, ib = keep[ia], keep[ib]
    if len(mid) == 0:
        return []
    out: list[Candidate] = []
    for c0, height in centre_peaks(mid, edges.shape, max_centres, min_separation_px=max(6.0, 0.3 * r_min)):
        near = row_norms(mid - c0) < 1.6 * CELL_PX
        if near.sum() < 6:
            continue
        c = rows(mid, near).mean(axis=0)
        idx = np.unique(np.concatenate([ia[near], ib[near]]))
        M = estimate_shape(rows(edges.points, idx) - c, rows(edges.grad, idx))
        if M is None:
            continue
        w, V = np.linalg.eigh(M)
        q = np.sqrt(w[0] / w[1])
        theta = np.arctan2(V[1, 0], V[0, 0])
        sizes = size_peaks(edges, c, M, r_min, r_max)
        for a in sizes:
            e0 = Ellipse(c, (a, a * q), theta)
            wide = max(3.0, 0.05 * a)  # the band: 5 % of the size, at least 3 px
            # a band reaching the next concentric size takes in its contour too (a narrow lip's
            # flange edge and inner edge lie 5 coarse px apart): then also one reaching halfway
            gap = min([abs(a - o) for o in sizes if o != a], default=np.inf)
            for band in (wide, max(MIN_BAND_PX, BAND_SHARE * gap)) if gap <= wide else (wide,):
                cand = _refine(e0, edges, height, band_px=band)
                if cand is not None:
                    out.append(cand)
    out.sort(key=lambda cd: -cd.coverage)
    return _dedupe(out)[:max_candidates]


def _refine(e0: Ellipse, edges: EdgeSet, height: float, band_px: float) -> Candidate | None:
    """Fit a voted ellipse to its own polarity-consistent edge pixels within ``band_px`` of it:
    consensus (RANSAC) on that band first, so that two concentric contours (flange edge, lip's
    inner edge) are not merged into a compromise, then an algebraic fit of the consensus set."""
    idx = polarity_inliers(e0, edges, band_px)
    if len(idx) < 12:
        return None
    inl = ransac_ellipse(rows(edges.points, idx), threshold_px=1.0, iterations=96, seed=len(idx))
    if inl is None or inl.sum() < 12:
        return None
    e = e0
    for tol in (None, 1.5):
        sel = idx[inl] if tol is None else polarity_inliers(e, edges, tol)
        if len(sel) < 12:
            return None
        try:
            (cx, cy), (d1, d2), ang = cv2.fitEllipseDirect(rows(edges.points, sel).astype(np.float32))
        except cv2.error:
            return None
        if not (np.isfinite(d1) and np.isfinite(d2)) or min(d1, d2) <= 0:
            return None
        e_new = Ellipse((cx, cy), (d1 / 2, d2 / 2), np.radians(ang))
        if np.linalg.norm(e_new.center_px - e0.center_px) > 0.3 * e0.axes_px[1] or \
                abs(e_new.axes_px[0] / e0.axes_px[0] - 1) > 0.3 or e_new.axes_px[1] / e_new.axes_px[0] < MIN_AXIS_RATIO:
            return None
        e = e_new
    idx = polarity_inliers(e, edges, 1.5)
    return Candidate(e, height, coverage_of(e, rows(edges.points, idx), edges.shape), len(idx))


def _dedupe(cands: list[Candidate]) -> list[Candidate]:
    kept: list[Candidate] = []
    for cd in cands:
        if not any(np.linalg.norm(cd.ellipse.center_px - k.ellipse.center_px) < 3
                   and abs(cd.ellipse.axes_px[0] - k.ellipse.axes_px[0]) < 3 for k in kept):
            kept.append(cd)
    return kept
