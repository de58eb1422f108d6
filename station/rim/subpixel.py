"""Sub-pixel rim-edge points: intensity profiles along the ellipse normals, blurred-step fits.

Each profile I(s) (s along the outward normal, in px) is sampled in the ORIGINAL image (no
equalisation: it is a spatially varying non-linear map that would move the edge) and fitted by a
blurred step on a sloping background,

    I(s) = m + k s + h erf((s - s0) / (sqrt(2) w))

(5 parameters, batched Gauss-Newton over all profiles at once). ``s0`` is the 50 % crossing of
the step, which is where an area-sampling sensor puts a step edge blurred by any symmetric
point-spread function: unbiased, unlike the peak of a discrete gradient, and it uses every
sample of the profile against the noise. The rim flange is bright inside, dark outside: h < 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import erf

from station.rim.ellipse import Ellipse
from station.rim.preprocess import PixelMap

SQRT2 = np.sqrt(2.0)
TWO_OVER_SQRT_PI = 2.0 / np.sqrt(np.pi)


@dataclass
class EdgeSamples:
    """Sub-pixel edge points along one ellipse.

    points_px: (N,2) distorted image pixels; t: (N,) ellipse parameter of each sample;
    contrast: (N,) |h| step height (grey levels); width: (N,) blur w (px);
    rms: (N,) profile fit residual (grey levels); ok: (N,) bool, profile accepted.
    """

    points_px: np.ndarray
    t: np.ndarray
    contrast: np.ndarray
    width: np.ndarray
    rms: np.ndarray
    ok: np.ndarray


def sample_profiles(grey: np.ndarray, base_px: np.ndarray, normal_px: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``grey`` (H,W) float32 at base + s * normal: (N,S)."""
    coords = base_px[:, None, :] + s[None, :, None] * normal_px[:, None, :]
    mx = np.ascontiguousarray(coords[..., 0], dtype=np.float32)
    my = np.ascontiguousarray(coords[..., 1], dtype=np.float32)
    return cv2.remap(grey, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)


def fit_steps(prof: np.ndarray, s: np.ndarray, polarity: float = -1.0, iterations: int = 8):
    """Fit the blurred step to each row of ``prof`` (N,S) at abscissae ``s`` (S,).

    Returns params (N,5) = (m, k, h, s0, w), residual rms (N,), converged (N,) bool.
    ``polarity`` -1: intensity falls with s (bright inside), +1: rises.
    """
    n, S = prof.shape
    # initial step position: the strongest derivative of the expected sign (parabolic peak)
    d = np.gradient(prof, s, axis=1) * polarity
    j = np.clip(np.argmax(d, axis=1), 1, S - 2)
    r = np.arange(n)
    y0, y1, y2 = d[r, j - 1], d[r, j], d[r, j + 1]
    den = y0 - 2 * y1 + y2
    off = np.where(np.abs(den) > 1e-12, 0.5 * (y0 - y2) / np.where(den == 0, 1, den), 0.0)
    step = s[1] - s[0]
    s0 = s[j] + np.clip(off, -1, 1) * step
    q = max(2, S // 5)
    lo, hi = prof[:, :q].mean(axis=1), prof[:, -q:].mean(axis=1)
    p = np.stack([(lo + hi) / 2, np.zeros(n), (hi - lo) / 2, s0, np.full(n, 1.0)], axis=1)
    lam = np.full(n, 1e-3)

    def model(p):
        z = (s[None, :] - p[:, 3:4]) / (SQRT2 * p[:, 4:5])
        e = erf(z)
        f = p[:, 0:1] + p[:, 1:2] * s[None, :] + p[:, 2:3] * e
        return f, z, e

    f, z, e = model(p)
    cost = ((prof - f) ** 2).sum(axis=1)
    for _ in range(iterations):
        g = TWO_OVER_SQRT_PI * np.exp(-z * z)
        J = np.empty((n, S, 5))
        J[:, :, 0] = 1.0
        J[:, :, 1] = s[None, :]
        J[:, :, 2] = e
        J[:, :, 3] = -p[:, 2:3] * g / (SQRT2 * p[:, 4:5])
        J[:, :, 4] = -p[:, 2:3] * g * z / p[:, 4:5]
        Jt = J.transpose(0, 2, 1)
        JtJ = Jt @ J
        Jtr = (Jt @ (prof - f)[:, :, None])[:, :, 0]
        A = JtJ + lam[:, None, None] * (np.eye(5)[None] * np.diagonal(JtJ, axis1=1, axis2=2)[:, None, :] + 1e-9 * np.eye(5)[None])
        try:
            dp = np.linalg.solve(A, Jtr[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:  # a singular profile somewhere: solve one by one
            dp = np.stack([np.linalg.lstsq(Ai, bi, rcond=None)[0] for Ai, bi in zip(A, Jtr)])
        p_new = p + dp
        p_new[:, 4] = np.clip(p_new[:, 4], 0.2, 5.0)
        f_new, z_new, e_new = model(p_new)
        cost_new = ((prof - f_new) ** 2).sum(axis=1)
        better = cost_new < cost
        p = np.where(better[:, None], p_new, p)
        f = np.where(better[:, None], f_new, f)
        z = np.where(better[:, None], z_new, z)
        e = np.where(better[:, None], e_new, e)
        cost = np.where(better, cost_new, cost)
        lam = np.where(better, lam * 0.3, lam * 10)
    rms = np.sqrt(cost / S)
    converged = np.isfinite(p).all(axis=1) & (np.abs(p[:, 3]) < s[-1] - 0.75) & (p[:, 2] * polarity > 0)
    return p, rms, converged


def edge_points(grey: np.ndarray, ellipse: Ellipse, pmap: PixelMap | None = None, n: int | None = None,
                half_width_px: float = 4.0, step_px: float = 0.5, spacing_px: float = 1.5,
                method: str = "erf") -> EdgeSamples:
    """Sub-pixel rim points along ``ellipse`` (in ideal pinhole pixels when ``pmap`` has a
    camera, else image pixels), searched within +/- ``half_width_px`` along the normals.

    method: "erf" - the blurred-step fit (final pass); "peak" - the parabolic peak of the
    profile derivative only (a cheaper first pass from a coarse ellipse)."""
    pmap = pmap or PixelMap(None)
    if n is None:
        n = int(np.clip(ellipse.perimeter() / spacing_px, 64, 4096))
    t = (np.arange(n) + 0.5) * (2 * np.pi / n)
    p_ideal = ellipse.point_at(t)
    n_ideal = ellipse.normal_at(t)
    base = pmap.distort(p_ideal)
    if pmap.identity:
        nrm = n_ideal
    else:
        tip = pmap.distort(p_ideal + n_ideal)
        nrm = tip - base
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    s = np.arange(-half_width_px, half_width_px + step_px / 2, step_px)
    h, w = grey.shape
    ends = [base + s[0] * nrm, base + s[-1] * nrm]
    inside = np.ones(n, bool)
    for e in ends:
        inside &= (e[:, 0] >= 0) & (e[:, 0] <= w - 1) & (e[:, 1] >= 0) & (e[:, 1] <= h - 1)
    inside &= np.isfinite(base).all(axis=1)
    pts = np.full((n, 2), np.nan)
    contrast = np.zeros(n)
    width = np.zeros(n)
    rms = np.full(n, np.inf)
    ok = np.zeros(n, bool)
    if inside.any():
        prof = sample_profiles(grey, base[inside], nrm[inside], s)
        p, r, conv = fit_steps(prof, s, iterations=8 if method == "erf" else 0)
        idx = np.nonzero(inside)[0]
        pts[idx] = base[inside] + p[:, 3:4] * nrm[inside]
        contrast[idx] = np.abs(2 * p[:, 2])
        width[idx] = p[:, 4]
        rms[idx] = r
        ok[idx] = conv
    # reject weak or badly fitting steps relative to the typical profile of this ellipse
    if ok.sum() >= 8:
        c_med = np.median(contrast[ok])
        r_med = np.median(rms[ok])
        w_med = np.median(width[ok])
        ok &= (contrast > 0.35 * c_med) & (rms < 3.0 * r_med + 1e-6) & (width < 2.5 * w_med + 0.3) & (width > 0.25)
    return EdgeSamples(pts, t, contrast, width, rms, ok)
