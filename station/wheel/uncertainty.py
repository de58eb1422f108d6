"""The uncertainty of a 3-D circle fit (``station.wheel.circle_fit.refine_circle``).

* the normal's parametrisation, n = n0 + a e1 + b e2 normalised (:func:`axis_basis`,
  :func:`normal_from`), and the axis covariance from that of (a, b) (:func:`axis_covariance`);
* :func:`noise_covariance` - from the residuals' noise, inflated by their correlation along the
  rim (:func:`correlation_factor`);
* :func:`bias_covariance` - from slowly varying edge biases (Fourier modes 0-2 of the rim
  angle, :func:`sector_bias_rms`, :func:`high_mode_amplitude`).

How two fits of one wheel compare is in station/wheel/fit_compare.py.
"""

from __future__ import annotations

import numpy as np

from station.compute.bounded_cache import BoundedCache
from station.rim.npfast import sector_medians
from station.wheel.arcs import rim_angles, sector_labels


def bias_covariance(sol, views, n0, e1, e2, n_modes: int, n_sectors: int = 18, own: list | None = None,
                    tilt_per_px: list | None = None) -> np.ndarray:
    """(P,P) covariance of the circle parameters (P = 6, or more for a model whose first six
    parameters are the circle's) from slowly varying edge biases in each view.

    The edge a camera sees may sit off the flange edge by a bias that changes slowly around
    the rim (a shaded lip, the tyre bulge, the blur model): it does not average out over the
    points. Model it per view as Fourier modes 0..``n_modes`` (at most 2) of the rim angle and
    propagate each mode through the least-squares solution (dp = (J^T J)^-1 J^T dr).

    An ellipse absorbs modes 0-2 of its own edge, so they hardly show in the residuals;
    modes 3-4 it cannot absorb, and a smooth bias has similar power there. So every mode
    0-2 has the amplitude the residuals show at modes 3 and 4 (``high_mode_amplitude``, at
    most the sector RMS below), on views that see at least MIN_SPECTRUM_SECTORS sectors.
    Mode 2 is the ellipse's elongation: the monocular shape cue camber leans on, since the
    horizontal baseline leaves the top and bottom of the rim without disparity. Without it,
    camber was stated twice too certain on the typical wheel; sized by the sector RMS, twice
    too uncertain, and modes 0-1 sized by the sector RMS stated the wheels that state the most
    about twice what they are off (bench/accuracy.py's table of stated against observed,
    docs/accuracy.md; the comparison is in docs/history/measurement.md). On a view seeing
    less of its rim, where the modes cannot be told apart, modes 0-1 have the standard
    deviation of its sector medians: the RMS of the median residual of each of ``n_sectors``
    sectors, less its noise (``sector_bias_rms``), and mode 2 none.

    The uniform offset (mode 0) is taken as the same in both views: it comes from where the
    edge model puts a blurred, shaded flange edge, which is the same rim and the same model in
    both cameras. Taken as independent per view it acted as a disparity between the views and
    doubled the stated toe uncertainty: over 160 benchmark vehicles the median of |toe error| /
    stated toe, over 0.674 (its value for honest Gaussian errors), was 0.3-0.8 per benchmark
    set, and is 0.8-1.3 with the common offset (docs/measurement.md).
    The slowly varying modes come from the viewing geometry (a hidden strip, a grazing lip)
    and stay each view's own.

    With residuals weighted by edge contrast (``refine_circle(contrast=...)``) the modes are
    those of the weighted residuals: a faint arc's edge is off by more, and counts for less,
    in about the same proportion. Sized in raw pixels instead, its bias was counted in full
    against a fit that gives it little weight: toe stated/RMS 1.45 on 40 vehicles outside the
    issue set (with a 0.010 deg floor), 1.26 with the weighted modes.

    ``own``: a list that receives each view's own part (P,P) (modes 1-2, the common offset
    left out), in the order of ``views``: which camera's edge wavers.

    ``tilt_per_px``: a list that receives, per view, how far (deg, per direction across the
    axis) the fit's axis turns per pixel of a slowly varying edge bias in that view alone
    (modes 1 and 2 at random phases, as ``view_agreement.view_axis`` turns a view's own axis
    for the same bias): their ratio is the share of a view's own tilt the pair's axis follows."""
    c = sol.x[2:5]
    n = normal_from(sol.x[:2], n0, e1, e2)
    J = sol.jac
    pinv = np.linalg.pinv(J.T @ J) @ J.T                                  # (P, N)
    Jn = (np.eye(3) - np.outer(n, n)) @ np.stack([e1, e2], axis=1)       # (3,2) d n / d (a, b)
    bounds = np.cumsum([0] + [len(v[1]) for v in views])
    cov = np.zeros((J.shape[1], J.shape[1]))
    common = np.zeros((J.shape[1], 1))
    for (cam, xy, *rest), a, b in zip(views, bounds[:-1], bounds[1:]):
        r = sol.fun[a:b]
        phi = rim_angles(cam, xy, c, n)
        if tilt_per_px is not None:  # a bias of 1 px, weighted as the view's residuals are
            w = np.asarray(rest[1], float)[:, None] if len(rest) > 1 else 1.0
            unit = np.stack([np.cos(phi), np.sin(phi), np.cos(2 * phi), np.sin(2 * phi)], axis=1)  # (N_k,4)
            tilts = Jn @ (pinv[:2, a:b] @ (unit * w))                                           # (3,4)
            tilt_per_px.append(float(np.degrees(np.sqrt(np.sum(tilts ** 2) / 2 / 2))))
        med, count = sector_medians(r, sector_labels(phi, n_sectors), n_sectors)
        full = np.nonzero(count >= 3)[0]
        noise = 1.4826 * np.median(np.abs(r - np.median(r)))  # the part of each median that is noise:
        se2 = (1.2533 * noise) ** 2 / count[full]                 # its squared standard error
        sigma_b = sector_bias_rms(med[full], se2)
        modes = min(n_modes, 2)
        high = min(high_mode_amplitude(med[full], full, se2, n_sectors), sigma_b)
        low = high if len(full) >= MIN_SPECTRUM_SECTORS else sigma_b
        amps = [low] * (1 + 2 * min(modes, 1))                    # modes 0, 1
        if modes == 2:
            amps += [high] * 2
        funcs = [np.ones_like(phi)] + [f(k * phi) for k in range(1, modes + 1) for f in (np.cos, np.sin)]
        dp = pinv[:, a:b] @ (np.stack(funcs, axis=1) * np.array(amps))   # (P, modes)
        common += dp[:, :1]                # the uniform offset: the same in both views
        cov += dp[:, 1:] @ dp[:, 1:].T     # the rest: each view's own
        if own is not None:
            own.append(dp[:, 1:] @ dp[:, 1:].T)
    return cov + common @ common.T


def sector_bias_rms(meds: np.ndarray, se2: np.ndarray) -> float:
    """RMS bias of sector medians (S,) whose squared standard errors from noise are se2 (S,)."""
    return float(np.sqrt(max(np.mean(meds ** 2 - se2), 0.0))) if len(meds) else 0.0


MIN_SPECTRUM_SECTORS = 12  # sectors (of 18) a view must cover to measure its modes 3-4


_FOURIER_PINV = BoundedCache(64)  # per set of seen sectors: most views see all, cycle after cycle


def _fourier_pinv(sectors: np.ndarray, n_sectors: int) -> np.ndarray:
    """(9, S) least-squares operator from the medians of ``sectors`` (S,) to Fourier modes 0-4."""
    angle = (sectors + 0.5) * (2 * np.pi / n_sectors) - np.pi
    A = np.stack([np.ones_like(angle)] + [f(k * angle) for k in range(1, 5) for f in (np.cos, np.sin)], axis=1)
    return np.linalg.pinv(A)


def high_mode_amplitude(meds: np.ndarray, sectors: np.ndarray, se2: np.ndarray, n_sectors: int) -> float:
    """Amplitude (px) of one Fourier function at modes 3-4 of the sector medians meds (S,) of
    the sectors ``sectors`` (S,) ints: least squares of modes 0-4, each coefficient's noise
    (from se2 (S,)) subtracted from its square, the mean power kept where positive, however
    weak. A significance test before it would set the weak ones to 0, and a clean rim's
    modes 3-4 are weak in about half of its views, where the low modes that tilt the axis
    are not (on clean rims they are the larger ones). 0 when fewer than MIN_SPECTRUM_SECTORS
    sectors are seen: on a short arc the modes cannot be told apart, and modes 0-1 already
    stand for the arc's smooth bias (with the sector RMS as mode 2's size there, a wheel seen
    on 10 of 18 sectors stated 0.34 deg of camber for an error of 0.04)."""
    if len(meds) < MIN_SPECTRUM_SECTORS:
        return 0.0
    P = _FOURIER_PINV.get((n_sectors, sectors.tobytes()), lambda: _fourier_pinv(sectors, n_sectors))  # (9, S)
    coef = P @ meds
    noise2 = (P[5:] ** 2) @ se2                                          # each coefficient's noise
    return float(np.sqrt(max(np.mean(coef[5:] ** 2 - noise2), 0.0)))


def along_rim(residuals: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Residuals (N,) reordered by the polar angle of their points (N,2) around the centroid."""
    d = xy - xy.mean(axis=0)
    return residuals[np.argsort(np.arctan2(d[:, 1], d[:, 0]))]


def correlation_factor(r: np.ndarray, max_lag_fraction: float = 0.25) -> float:
    """Variance inflation 1 + 2 sum(rho_k) of a mean of correlated samples (N,) ordered in space.

    rho_k is the lag-k autocorrelation, summed over the initial positive sequence (Geyer);
    1 for independent residuals, about the correlation length (in points) for smooth errors.
    """
    n = len(r)
    if n < 8:
        return 1.0
    r = r - r.mean()
    c0 = float(r @ r) / n
    if c0 <= 0:
        return 1.0
    f = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[: int(n * max_lag_fraction)] / (n * c0)
    s = 0.0
    for rho in acf[1:]:
        if rho <= 0:
            break
        s += rho
    return 1.0 + 2.0 * s


def axis_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n0, e1, e2): the unit ``axis`` (3,) and two unit vectors across it, in which the circle
    fits move the normal (n = n0 + a e1 + b e2, normalised)."""
    n0 = axis / np.linalg.norm(axis)
    e1 = np.cross(n0, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    return n0, e1, np.cross(n0, e1)


def noise_covariance(sol, views) -> tuple[np.ndarray | None, np.ndarray]:
    """(P,P) covariance of a fit's parameters from its residuals' robust sigma and the Jacobian
    (None if singular), inflated by the residuals' correlation along the rim, and the (N,)
    inlier mask it was estimated on. sol: fun (N,), jac (N,P); views: [(camera, points, f, ...)]
    in the order of the residuals."""
    r, J = sol.fun, sol.jac
    mad = 1.4826 * np.median(np.abs(r - np.median(r)))
    inlier = np.abs(r) < max(3 * mad, 1e-6)
    sigma2 = float(np.sum(r[inlier] ** 2) / max(inlier.sum() - J.shape[1], 1))
    try:
        cov_p = np.linalg.inv(J.T @ J) * sigma2
    except np.linalg.LinAlgError:
        return None, inlier
    # Edge errors are not independent from point to point (shading, blur and occlusion move
    # whole stretches of the rim): inflate by the residuals' correlation along the rim.
    per_view = np.split(r, np.cumsum([len(v[1]) for v in views])[:-1])
    factors = [correlation_factor(along_rim(res, v[1])) for res, v in zip(per_view, views)]
    return cov_p * float(np.average(factors, weights=[len(v[1]) for v in views])), inlier


def axis_covariance(n: np.ndarray, e1: np.ndarray, e2: np.ndarray, cov_ab: np.ndarray) -> np.ndarray:
    """(3,3) covariance of the unit normal n from that (2,2) of its parameters (a, b):
    d n / d (a, b) = (I - n n^T) [e1 e2] / |n0 + a e1 + b e2|, ~ the tangent basis at the solution."""
    Jn = (np.eye(3) - np.outer(n, n)) @ np.stack([e1, e2], axis=1)
    return Jn @ cov_ab @ Jn.T


def normal_from(params, n0, e1, e2):
    n = n0 + params[0] * e1 + params[1] * e2
    return n / np.linalg.norm(n)
