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

from station.compute.bounded_cache import BoundedCache
from station.rim import profile_loops
from station.rim.ellipse import Ellipse
from station.rim.npfast import finite_rows, median, rows
from station.rim.preprocess import PixelMap

SQRT2 = np.sqrt(2.0)
TWO_OVER_SQRT_PI = 2.0 / np.sqrt(np.pi)
INTERPOLATION = cv2.INTER_LINEAR    # the passes' profiles (their decisions were measured with it)
POSITION_INTERPOLATION = cv2.INTER_LANCZOS4  # the final positions' (see ``repositioned``)


@dataclass
class EdgeSamples:
    """Sub-pixel edge points along one ellipse.

    points_px: (N,2) distorted image pixels; t: (N,) ellipse parameter of each sample;
    contrast: (N,) |h| step height (grey levels); width: (N,) blur w (px);
    rms: (N,) profile fit residual (grey levels); ok: (N,) bool, profile accepted;
    along: the ellipse (ideal pixels) the profiles were taken along (t is on it), or None.
    """

    points_px: np.ndarray
    t: np.ndarray
    contrast: np.ndarray
    width: np.ndarray
    rms: np.ndarray
    ok: np.ndarray
    along: Ellipse | None = None


def step_modulation(t: np.ndarray, contrast: np.ndarray) -> float:
    """How unevenly the edge's step is lit round the rim: the amplitude of the once-round
    harmonic of the step heights ``contrast`` (N,) against the ellipse parameter ``t`` (N,), rad
    (least squares, so that a gap in the turn reads as no modulation), over their mean; at most
    pi/2, a step lit on one half of the turn and none on the other (a fit over a short arc can
    extrapolate beyond it). A lamp on one side lights the lip's rounding on that side and shades
    it on the other: about 0.6-1.0 under the simulator's lamps, 0.03-0.12 under diffuse panels
    (docs/measurement.md, "Uncertainty of every angle"). 0 for fewer than 8 points."""
    c = np.asarray(contrast, float)
    if len(c) < 8 or not np.mean(c) > 0:
        return 0.0
    t = np.asarray(t, float)
    A = np.column_stack([np.ones_like(t), np.cos(t), np.sin(t)])  # (N,3)
    coef, *_ = np.linalg.lstsq(A, c, rcond=None)
    return float(min(np.hypot(coef[1], coef[2]) / np.mean(c), np.pi / 2))


def sample_profiles(grey: np.ndarray, base_px: np.ndarray, normal_px: np.ndarray, s: np.ndarray,
                    interpolation: int = INTERPOLATION) -> np.ndarray:
    """Samples of ``grey`` (H,W) float32 at base + s * normal (bilinear unless told): (N,S)."""
    # (N,S) sample coordinates, x and y apart (no (N,S,2) array to split)
    mx = (base_px[:, 0:1] + s[None, :] * normal_px[:, 0:1]).astype(np.float32)
    my = (base_px[:, 1:2] + s[None, :] * normal_px[:, 1:2]).astype(np.float32)
    return cv2.remap(grey, mx, my, interpolation, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)


def fit_steps(prof: np.ndarray, s: np.ndarray, polarity: float = -1.0, iterations: int = 8):
    """Fit the blurred step to each row of ``prof`` (N,S) at abscissae ``s`` (S,).

    Returns params (N,5) = (m, k, h, s0, w), residual rms (N,), converged (N,) bool.
    ``polarity`` -1: intensity falls with s (bright inside), +1: rises.
    """
    n, S = prof.shape
    p = initial_steps(prof, s, polarity)
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
    return p, rms, _step_found(p, s, polarity)


def _step_found(p: np.ndarray, s: np.ndarray, polarity: float) -> np.ndarray:
    """(N,) bool: a finite step of the expected polarity, not at the window's end (params p (N,5))."""
    return finite_rows(p) & (np.abs(p[:, 3]) < s[-1] - 0.75) & (p[:, 2] * polarity > 0)


def initial_steps(prof: np.ndarray, s: np.ndarray, polarity: float = -1.0) -> np.ndarray:
    """Step parameters (N,5) (m, k, h, s0, w) of each profile (N,S) without any fit: s0 at the
    strongest derivative of the expected sign (parabolic peak), levels from the window's ends,
    w = 1 px (fit_steps' start, and all the kink model needs of it)."""
    return profile_loops.initial_steps(np.ascontiguousarray(prof), np.asarray(s, float), float(polarity))


def _kink_basis(x: np.ndarray, sigma: float, curvature: bool = False) -> np.ndarray:
    """(..., S, nb) basis of the blurred step-and-kink at offsets x = s - s0 (..., S):
    [1, Phi, x, x Phi + sigma phi] for (A, h, B, k) in I = A + h Phi + B x + k (x Phi + sigma phi),
    and with ``curvature`` the metal side's blurred x^2 (nb = 5)."""
    z = x / sigma
    Phi = 0.5 * (1 + erf(z / SQRT2))
    phi = np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi)
    cols = [np.ones_like(x), Phi, x, x * Phi + sigma * phi]
    if curvature:  # blurred x^2 on the metal side (x < 0): E[u^2 1(u<0)], u ~ N(x, sigma^2)
        cols.append((x * x + sigma * sigma) * (1 - Phi) - x * sigma * phi)
    return np.stack(cols, axis=-1)


def fit_kinks(prof: np.ndarray, s: np.ndarray, sigma: float, polarity: float = -1.0,
              grid_step: float = 0.25, margin: float = 1.0, refine: bool = True, curvature: bool = False):
    """Locate the edge in each profile (N,S) by a blurred step-and-kink model.

    The profile is one straight line on the metal side and another on the tyre side, meeting
    at ``s0`` with a jump ``h``, blurred by a Gaussian of ``sigma`` (the image's PSF with the
    pixel box): I(s) = A + h Phi(x/sigma) + B x + k (x Phi + sigma phi), x = s - s0.
    Unlike a plain step it stays unbiased when the rim's rounded lip is shaded as a ramp up to
    the edge, and it locates the edge even when the jump is small. The four linear
    coefficients are eliminated (variable projection); s0 is searched on a grid over the
    window, then refined by two parabolic steps. Only jumps of the given polarity count.

    Returns s0 (N,), h (N,), residual rms (N,), ok (N,) bool.
    """
    S = prof.shape[1]
    grid = np.arange(s[0] + margin, s[-1] - margin + 1e-9, grid_step)
    G = len(grid)
    Q, H = _kink_projector(s, grid, sigma, curvature)                # (S,G*nb), (S,G)
    nb = Q.shape[1] // G
    ss = np.einsum("ns,ns->n", prof, prof)
    found = profile_loops.grid_minima(prof @ Q, prof @ H, ss, 1, G, nb, polarity)  # (N,G*nb): one BLAS call
    s0, h, rms, ok = _located(grid, S, *(a[:, 0] for a in found))
    if not refine:  # the grid's best residual only (for the blur estimate)
        return s0, h, rms, ok
    # one refinement with per-profile bases at s0 - d, s0, s0 + d and a parabola
    step = 0.05
    cand = s0[:, None] + np.array([-step, 0.0, step])[None, :]          # (N,3)
    Bc = _kink_basis(s[None, None, :] - cand[:, :, None], sigma, curvature)  # (N,3,S,nb)
    Bt = np.swapaxes(Bc, 2, 3)
    c = np.linalg.solve(Bt @ Bc + 1e-9 * np.eye(nb), Bt @ prof[:, None, :, None])  # (N,3,nb,1)
    rr = ((prof[:, None, :] - (Bc @ c)[..., 0]) ** 2).sum(axis=2)   # (N,3)
    s0 = s0 + _parabola(rr[:, 0], rr[:, 1], rr[:, 2]) * step
    h = c[:, 1, 1, 0]
    rms = np.sqrt(np.maximum(rr[:, 1], 0) / S)
    ok &= (s0 <= s[-1] - margin) & (s0 >= s[0] + margin) & (h * polarity > 0) & np.isfinite(s0)
    return s0, h, rms, ok


def _located(grid: np.ndarray, n_samples: int, g, off, res, h, ok):
    """(s0, h, rms, ok) (N,) of profiles of ``n_samples`` samples from ``profile_loops``'
    grid minima: position g on ``grid`` moved by the parabola's offset, residual res."""
    return grid[g] + off * (grid[1] - grid[0]), h, np.sqrt(np.maximum(res, 0) / n_samples), ok


def fit_kinks_straight_and_curved(prof: np.ndarray, s: np.ndarray, sigma: float, grid_step: float = 0.125,
                                  margin: float = 1.0, polarity: float = -1.0):
    """``fit_kinks(..., refine=False)`` of the straight model and of the curved one
    (``curvature=True``) from one product: the curved model's orthonormal basis at each s0
    begins with an orthonormal basis of the straight one's (QR keeps the span of the leading
    columns), so one projection gives both residuals. Returns (straight, curved), each
    (s0, h, rms, ok) (N,)."""
    grid = np.arange(s[0] + margin, s[-1] - margin + 1e-9, grid_step)
    straight, curved = _kink_minima(prof, s, sigma, grid, polarity)
    return _located(grid, len(s), *straight), _located(grid, len(s), *curved)


def _kink_minima(prof: np.ndarray, s: np.ndarray, sigma: float, grid: np.ndarray, polarity: float):
    """Each profile's (N,S) best position on ``grid`` under the straight and the curved kink
    model, from one product: ``profile_loops.grid_minima_nested``'s (g, offset, res, h,
    finite) (N,) each, straight first."""
    Q, H_straight, H_curved = _kink_pair_projector(s, grid, sigma)   # (S,G*nb), (S,G), (S,G)
    ss = np.einsum("ns,ns->n", prof, prof)
    return profile_loops.grid_minima_nested(prof @ Q, prof @ H_straight, prof @ H_curved, ss, len(grid), 4, polarity)


def _model_edges(prof: np.ndarray, s: np.ndarray, sigma: float, straight, curved):
    """The edges (s0, h, rms, ok) (N,) from both models' (s0, h, rms, ok): the curved lip where
    ``_curved_where_needed`` takes it, the straight model elsewhere."""
    return _curved_where_needed(prof, s, sigma, *straight, curved=curved)


def _kink_pair_projector(s: np.ndarray, grid: np.ndarray, sigma: float):
    """The curved model's orthonormal bases at every grid s0, stacked (S, G*nb), and the (S,G)
    maps from a profile to the straight and to the curved model's jump h at every s0 (cached
    as ``_kink_projector``)."""
    sigma = round(float(sigma), 6)
    key = ("straight and curved", s.tobytes(), grid.tobytes(), sigma)

    def make():
        B = _kink_basis(s[None, :] - grid[:, None], sigma, True)     # (G,S,nb), straight first
        Q, R = np.linalg.qr(B)                                       # (G,S,nb), (G,nb,nb)
        # h = R^-1 Q^T prof, row 1: the straight model's from the leading 4 x 4 block of R
        H_straight = np.einsum("gsk,gk->sg", Q[:, :, :4], np.linalg.inv(R[:, :4, :4])[:, 1, :])
        H_curved = np.einsum("gsk,gk->sg", Q, np.linalg.inv(R)[:, 1, :])
        return (np.ascontiguousarray(Q.transpose(1, 0, 2).reshape(len(s), -1)),
                np.ascontiguousarray(H_straight), np.ascontiguousarray(H_curved))

    return _PROJECTORS.get(key, make)


_PROJECTORS = BoundedCache(64)   # per (window, grid, blur): every camera's blur differs a little
_BLUR_STACKS = BoundedCache(16)  # per (window, grid): all candidate blurs stacked


def _kink_projector(s: np.ndarray, grid: np.ndarray, sigma: float, curvature: bool = False):
    """Orthonormal bases of the kink model at every grid s0, stacked (S, G*nb), and the (S,G)
    map from a profile to its jump coefficient h at every s0 (cached: the same window and blur
    serve every profile of an image and the next image)."""
    # built at the blur it is kept under: from the exact blur, the projector of a later blur
    # with the same key would depend on which blur came first, and so the detection on the
    # images the process saw before (a point more or less reseeds the consensus search)
    sigma = round(float(sigma), 6)
    key = (s.tobytes(), grid.tobytes(), sigma, curvature)

    def make():
        B = _kink_basis(s[None, :] - grid[:, None], sigma, curvature)  # (G,S,nb)
        Q, R = np.linalg.qr(B)                                       # (G,S,nb), (G,nb,nb)
        H = np.einsum("gsk,gk->sg", Q, np.linalg.inv(R)[:, 1, :])    # h = R^-1 Q^T prof, row 1
        return np.ascontiguousarray(Q.transpose(1, 0, 2).reshape(len(s), -1)), np.ascontiguousarray(H)

    return _PROJECTORS.get(key, make)


def _parabola(y0, y1, y2):
    """Vertex offset (in grid steps, clipped to +/-1) of the parabola through three values."""
    with np.errstate(invalid="ignore", over="ignore"):
        y0 = np.where(np.isfinite(y0), y0, y1)
        y2 = np.where(np.isfinite(y2), y2, y1)
        den = y0 - 2 * y1 + y2
        up = den > 1e-12
        off = np.where(up, 0.5 * (y0 - y2) / np.where(up, den, 1.0), 0.0)
        # np.clip(np.nan_to_num(off), -1, 1), without nan_to_num's overhead (half the time here)
        return np.where(np.isnan(off), 0.0, np.minimum(np.maximum(off, -1.0), 1.0))


WIDE_BLUR_PX = 1.1  # edge blur (px) above which the windows grow with it (window_scale)
BLUR_GRID_PX = np.geomspace(0.4, 2.8, 13)  # blur candidates, 17.6 % apart (cached projectors)
BLUR_PROFILES = 200                          # profiles spread round the rim that estimate it


def estimate_blur(prof: np.ndarray, s: np.ndarray, polarity: float = -1.0, grid_step: float = 0.25) -> float:
    """The image's effective edge blur sigma (px): the median, over profiles (N,S), of each
    profile's own best blur for the step-and-kink model.

    A profile whose metal side carries a shading ramp or a specular highlight up to the edge
    looks like a broader step, never a sharper one; round a rim many profiles are clean, so
    the median of the per-profile values is the PSF, where a least-squares blur over all of
    them is pulled toward the contaminated ones (they have the most contrast). Per profile:
    the least residual over ``BLUR_GRID_PX``, then a parabola in log sigma, each at the best
    edge position on a grid of ``grid_step`` px (an edge between grid points fits best as a
    broader step: a coarse grid reads the blur high by where the edge falls on it)."""
    rms = _blur_rms(prof, s, polarity, grid_step)                                    # (N,G)
    G, r = len(BLUR_GRID_PX), np.arange(len(prof))
    k = np.clip(np.argmin(rms, axis=1), 1, G - 2)
    at = k + _parabola(rms[r, k - 1], rms[r, k], rms[r, k + 1])
    return float(np.exp(median(np.interp(at, np.arange(G), np.log(BLUR_GRID_PX)))))


def _blur_rms(prof: np.ndarray, s: np.ndarray, polarity: float, grid_step: float = 0.25,
              margin: float = 1.0) -> np.ndarray:
    """(N, len(BLUR_GRID_PX)): for every profile (N,S) and candidate blur, the residual rms of
    the step-and-kink model at its best edge position on the grid, as ``fit_kinks(...,
    refine=False)`` gives it, for all candidate blurs by one product with their stacked
    projectors (cached)."""
    S = prof.shape[1]
    grid = np.arange(s[0] + margin, s[-1] - margin + 1e-9, grid_step)
    G, B = len(grid), len(BLUR_GRID_PX)
    key = (s.tobytes(), grid.tobytes())

    def make():  # one per window of the passes: kept apart from the per-blur projectors
        parts = [_kink_projector(s, grid, sg) for sg in BLUR_GRID_PX]
        return (np.ascontiguousarray(np.concatenate([q for q, _ in parts], axis=1)),
                np.ascontiguousarray(np.concatenate([h for _, h in parts], axis=1)))

    Q, H = _BLUR_STACKS.get(key, make)                               # (S, B*G*nb), (S, B*G)
    nb = Q.shape[1] // (B * G)
    ss = np.einsum("ns,ns->n", prof, prof)
    _, _, best, _, _ = profile_loops.grid_minima(prof @ Q, prof @ H, ss, B, G, nb, polarity)  # (N,B) each
    return np.sqrt(np.maximum(best, 0) / S)


def _estimate_blur_any(prof: np.ndarray, s: np.ndarray, s0: np.ndarray, hint: float | None) -> float:
    """The edge blur (px) of profiles (N,S) with first step estimates s0 (N,), sharp or soft.

    Cut to +/-3 px, a soft step's tails fall outside and the model's straight sides mimic a
    sharper step (a blur of 1.5-2 px came out as 0.75-1.1). So whether the image is soft is
    asked of a wider cut (+/-5 px) or of ``hint`` (an earlier pass's blur); a soft image's blur
    is then the fixed point of cuts at +/-3.5 sigma (two rounds), a sharp one's the +/-3 px
    estimate as before."""
    sigma = estimate_blur(*_centred(prof, s, s0))
    if hint is not None:
        soft = hint > WIDE_BLUR_PX
    else:  # a yes or no: a third of the profiles tell it
        soft = sigma > WIDE_BLUR_PX or estimate_blur(*_centred(prof[::3], s, s0[::3], half_px=5.0)) > WIDE_BLUR_PX
    if soft:
        sigma = max(sigma, WIDE_BLUR_PX)
        for _ in range(2):
            sigma = estimate_blur(*_centred(prof, s, s0, half_px=3.5 * sigma))
    return sigma


def window_scale(sigma: float | None) -> float:
    """Factor for profile windows made for the station's edges (blur <= WIDE_BLUR_PX): 1
    there, else sqrt(sigma / WIDE_BLUR_PX) rounded up to a quarter (so that the cached
    projectors of a camera serve it cycle after cycle). The step-and-kink model needs the
    step's tails inside the window to tell them from the straight sides around it: with a soft
    focus (sigma 1.7-2.2 px) the fixed windows put synthetic rims 0.06-0.3 px off. But the
    rim's neighbouring contours (the lip's inner edge, the tyre) come no farther away as the
    blur grows; windows in proportion to the blur (1.5-2x) took them in and worsened the
    simulated station's camber, the square root did not (docs/rim-detection.md)."""
    if sigma is None or not np.isfinite(sigma) or sigma <= WIDE_BLUR_PX:
        return 1.0
    return float(np.ceil(4 * np.sqrt(sigma / WIDE_BLUR_PX)) / 4)


def _centred(prof: np.ndarray, s: np.ndarray, s0: np.ndarray, half_px: float = 3.0):
    """Each profile (N,S) cut to +/-``half_px`` around its first step estimate s0 (N,), so
    that no neighbouring edge of a wide window enters the blur estimate: ((N,K), (K,))."""
    step = s[1] - s[0]
    h = min(int(round(half_px / step)), (len(s) - 1) // 2)
    j0 = np.clip(np.round((s0 - s[0]) / step).astype(int), h, len(s) - 1 - h)
    idx = j0[:, None] + np.arange(-h, h + 1)[None, :]
    return np.take_along_axis(prof, idx, axis=1), np.arange(-h, h + 1) * step


def _blur_profiles(p: np.ndarray, conv: np.ndarray) -> np.ndarray:
    """Indices of up to ``BLUR_PROFILES`` profiles for the blur estimate, spread evenly round
    the rim: fitted, with at least half the median contrast (params p (N,5) of fit_steps)."""
    h = np.abs(p[:, 2])
    use = conv & (h > 0.5 * median(h[conv])) if conv.sum() >= 10 else np.ones(len(h), bool)
    idx = np.nonzero(use)[0]
    return idx[np.linspace(0, len(idx) - 1, min(BLUR_PROFILES, len(idx))).astype(int)]


CURVED_LIP_F = 10.0    # F(1, S - 6) the curvature term must reach: its 99 % point for the final window
CURVED_ARC_DEG = 10.0  # and on the majority of each arc this wide


def _curved_where_needed(prof: np.ndarray, s: np.ndarray, sigma: float, s0, h, rms, ok, curved=None):
    """Per profile (N,S) in order round the rim, the step-and-kink model with the metal side's
    curvature (a blurred x^2 term, ``_kink_basis``) where it fits significantly better, the straight
    one elsewhere; (s0, h, rms, ok) (N,) are the straight model's, returned with the curved
    model's values where it is taken; ``curved`` the curved model's (s0, h, rms, ok) where
    they were found already (``fit_kinks_straight_and_curved``).

    A lip shaded as rounded across the window (a narrow lip, 4-8 mm, is 2-4 px wide in an
    oblique view; a dark rim's lip lit from above) makes the profile rise to the lip's top and
    fall to the edge: no straight metal side fits it, and the straight model put the edge 1-2
    px inside over whole arcs (simulated narrow lips: toe 0.15, camber 0.27 deg RMS). The
    curved model everywhere fixes that but is noisier on an ordinary lip (~330 vehicles of the
    usual sets: toe 0.036 -> 0.054 deg). So a profile takes it where its residual falls by an
    F statistic above ``CURVED_LIP_F``, and only where most profiles of the arc of
    ``CURVED_ARC_DEG`` around it do: the lip's shape and light change slowly round the rim, and
    a model switching from profile to profile by chance mixed two edge definitions along one
    arc (on a simulated station with other mounts and lenses, camber 0.030 -> 0.082 deg
    without the arc majority, 0.033 with it). The rule is in docs/rim-detection.md, its
    measurements in docs/history/rim-detection.md."""
    S = len(s)
    s0c, hc, rmsc, okc = curved or fit_kinks(prof, s, sigma, grid_step=0.125, refine=False, curvature=True)
    rss, rssc = rms ** 2 * S, rmsc ** 2 * S
    with np.errstate(divide="ignore", invalid="ignore"):
        f = (rss - rssc) / (rssc / max(S - 6, 1))
    use = okc & (f > CURVED_LIP_F)
    if CURVED_ARC_DEG:
        w = max(1, int(round(len(use) * CURVED_ARC_DEG / 360)))
        k = np.ones(w) / w
        frac = np.convolve(np.concatenate([use[-w:], use, use[:w]]).astype(float), k, mode="same")[w:-w]
        use = okc & (frac > 0.5)
    return (np.where(use, s0c, s0), np.where(use, hc, h), np.where(use, rmsc, rms), np.where(use, okc, ok))


def _tyre_side_flat(prof: np.ndarray, s: np.ndarray, s0: np.ndarray, h: np.ndarray, sigma: float,
                    max_rise: float = 0.25) -> np.ndarray:
    """(N,) bool: beyond the step the profile does not climb back by more than ``max_rise`` of
    the jump. Where the lit tyre bead is brighter than a lip shaded dark at its edge, the only
    bright-inside feature along the normal is the lip's shading ramp, not the flange edge."""
    return profile_loops.tyre_side_flat(np.ascontiguousarray(prof), np.asarray(s, float), s0, h, float(sigma),
                                        float(max_rise))


def edge_points(grey: np.ndarray, ellipse: Ellipse, pmap: PixelMap | None = None, n: int | None = None,
                window_px: tuple[float, float] = (-4.0, 4.0), step_px: float = 0.5, spacing_px: float = 1.5,
                method: str = "kink", sigma: float | None = None,
                blur_hint: float | None = None, misfit_floor: float = 0.0) -> tuple[EdgeSamples, float | None]:
    """Sub-pixel rim points along ``ellipse`` (in ideal pinhole pixels when ``pmap`` has a
    camera, else image pixels), searched in ``window_px`` (inside, outside) along the normals.

    method: "kink" - the blurred step-and-kink model (final pass; ``sigma`` the image blur,
    estimated from the profiles when None, ``blur_hint`` an earlier pass's estimate, which says
    whether the image is soft); "erf" - a blurred step on a sloping background;
    "peak" - the parabolic peak of the profile derivative (a cheap first pass).
    Returns (samples, sigma used or None)."""
    pmap = pmap or PixelMap(None)
    if n is None:
        n = int(np.clip(ellipse.perimeter() / spacing_px, 64, 4096))
    t = (np.arange(n) + 0.5) * (2 * np.pi / n)
    p_ideal = ellipse.point_at(t)
    n_ideal = ellipse.normal_at(t)
    base, nrm, _ = pmap.along_normals(p_ideal, n_ideal)
    s = np.arange(window_px[0], window_px[1] + step_px / 2, step_px)
    h, w = grey.shape
    inside = finite_rows(base)
    for e in (base + s[0] * nrm, base + s[-1] * nrm):
        inside &= (e[:, 0] >= 0) & (e[:, 0] <= w - 1) & (e[:, 1] >= 0) & (e[:, 1] <= h - 1)
    pts = np.full((n, 2), np.nan)
    contrast = np.zeros(n)
    width = np.zeros(n)
    rms = np.full(n, np.inf)
    ok = np.zeros(n, bool)
    idx = np.nonzero(inside)[0]
    if len(idx):
        base_in, nrm_in = rows(base, idx), rows(nrm, idx)  # (M,2) the profiles inside the image
        prof = sample_profiles(grey, base_in, nrm_in, s)
        if method == "kink":
            if sigma is None:  # from the profiles' plain step positions
                p = initial_steps(prof, s)
                sel = _blur_profiles(p, _step_found(p, s, -1.0))
                sigma = _estimate_blur_any(rows(prof, sel), s, p[:, 3][sel], blur_hint)
            # parabola on a fine grid: < 0.003 px
            s0, hh, r, conv = _model_edges(prof, s, sigma, *fit_kinks_straight_and_curved(prof, s, sigma, grid_step=0.125))
            conv &= _tyre_side_flat(prof, s, s0, hh, sigma)
            p = np.zeros((len(idx), 5))
            p[:, 3], p[:, 2], p[:, 4] = s0, hh / 2, sigma
        else:
            p, r, conv = fit_steps(prof, s, iterations=8 if method == "erf" else 0)
        pts[idx] = base_in + p[:, 3:4] * nrm_in
        contrast[idx] = np.abs(2 * p[:, 2])
        width[idx] = p[:, 4]
        rms[idx] = r
        ok[idx] = conv
    # reject weak or badly fitting edges relative to the typical profile of this ellipse
    if ok.sum() >= 8:
        c_med = median(contrast[ok])
        r_med = median(rms[ok])
        w_med = median(width[ok])
        ok &= (contrast > 0.2 * c_med) & (contrast > 4 * r_med) & (rms < 3.0 * max(r_med, misfit_floor) + 1e-6) \
            & (width < 2.5 * w_med + 0.3) & (width > 0.25)
    return EdgeSamples(pts, t, contrast, width, rms, ok, ellipse), sigma


REPOSITION_REACH_PX = 1.0  # how far from the fitted ellipse ``repositioned`` searches (px)
REPOSITION_ARCS = 36       # arcs whose averaged profiles give ``repositioned`` its blur
STACK_GRID_PX = 0.125      # their edge positions' grid in the blur estimate (finer than the passes')


def repositioned(grey: np.ndarray, anchors_px: np.ndarray, normals_px: np.ndarray,
                 window_px: tuple[float, float] = (-3.0, 4.5), step_px: float = 0.5):
    """The rim edge located again in profiles sampled with the Lanczos kernel
    (``POSITION_INTERPOLATION``) through ``anchors_px`` (N,2), the passes' points' feet on
    the fitted ellipse in order round the rim, along unit normals (N,2), searched within
    ``REPOSITION_REACH_PX`` of the anchors. Returns ((N,) offsets of the edge from the anchors
    along the normals, px; (N,) bool found (not at the search's end); the blur used, px).

    Bilinear interpolation blurs a sample by f(1 - f) px^2 more along each axis, f its
    fraction between pixels: by up to 1/4 px^2, and by a different amount from profile to
    profile as the rim turns across the pixel grid. Against the kink model at the image's
    blur, an edge whose metal side is shaded as a ramp (slope change k, step h) then moves by
    about k sigma dsigma / h: 0.06 px for an ordinary shaded lip (tests), enough to turn a
    rim's ellipse by what reads as 0.01-0.02 deg of camber at 1.3 Mpx. The Lanczos kernel
    reproduces an image blurred over about a pixel without adding blur of its own.

    The model is the passes' (the curved lip where ``_curved_where_needed`` says so), at the
    blur of these profiles: ``estimate_blur`` of the profiles averaged over each of
    ``REPOSITION_ARCS`` arcs. Averaged, the noise falls by the square root of their number;
    aligned on the ellipse, not on each point (whose position came from the same noise), the
    average is not sharpened by the alignment. On the simulated station's rims the median of
    each profile's own best blur, as the passes take it, comes out 1-2 % low at a noise of 2
    grey levels and 10 % low at 5; the arcs' averages 1 % and 2 % low (docs/rim-detection.md,
    "Final positions from Lanczos profiles"); a blur 10 % too small made the toe error 5x
    larger (docs/history/accuracy.md).

    Only the positions move: which points, and which contour, the passes chose with bilinear
    profiles as they were measured (sampled with Lanczos, the passes changed decisions on
    borderline harsh-light cameras)."""
    n = len(anchors_px)
    if n < 8:
        return np.zeros(n), np.zeros(n, bool), float("nan")
    s = np.arange(window_px[0], window_px[1] + step_px / 2, step_px)
    grid = np.arange(-REPOSITION_REACH_PX, REPOSITION_REACH_PX + 1e-9, 0.125)
    prof = sample_profiles(grey, anchors_px, normals_px, s, POSITION_INTERPOLATION)
    n_arcs = int(min(REPOSITION_ARCS, n // 8))
    starts = (np.arange(n_arcs) * n) // n_arcs                           # arcs of (almost) equal count
    stacks = np.add.reduceat(prof, starts, axis=0) / np.diff(np.append(starts, n))[:, None]
    # each average cut round its own edge (the anchors' curve may run a little off it)
    sigma = estimate_blur(*_centred(stacks, s, initial_steps(stacks, s)[:, 3]), grid_step=STACK_GRID_PX)
    # an edge at either end of the search is not found
    straight, curved = (_located(grid, len(s), g, off, res, h, ok & (g > 0) & (g < len(grid) - 1))
                        for g, off, res, h, ok in _kink_minima(prof, s, sigma, grid, -1.0))
    d, _, _, ok = _model_edges(prof, s, sigma, straight, curved)   # the passes' choice of model
    return d, ok & np.isfinite(d), sigma
