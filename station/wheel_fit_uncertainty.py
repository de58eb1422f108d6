"""The uncertainty of a 3-D circle fit (``station.wheel3d.refine_circle``) and how two fits of
one wheel compare.

* the normal's parametrisation, n = n0 + a e1 + b e2 normalised (:func:`axis_basis`,
  :func:`normal_from`), and the axis covariance from that of (a, b) (:func:`axis_covariance`);
* :func:`noise_covariance` - from the residuals' noise, inflated by their correlation along the
  rim (:func:`correlation_factor`);
* :func:`bias_covariance` - from slowly varying edge biases (Fourier modes 0-2 of the rim
  angle, :func:`sector_bias_rms`, :func:`high_mode_amplitude`);
* two fits of the same wheel on different points: :func:`extra_points_bias2` (the bias the
  extra points add), :func:`inconsistent` (beyond what both state), :func:`with_disagreement`
  (the kept one states their difference), :func:`toward_subset_weight` and :func:`toward` (the
  least-error step from a fit toward the fit of a subset of its points).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from station.bounded_cache import BoundedCache
from station.wheel_arcs import rim_angles, sector_labels, sector_medians

if TYPE_CHECKING:
    from station.wheel3d import WheelFit


LOW_MODES_FROM_HIGH = True  # modes 0-1 sized like mode 2, from modes 3-4 (views seeing 12+ sectors)


def bias_covariance(sol, views, n0, e1, e2, n_modes: int, n_sectors: int = 18) -> np.ndarray:
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
    too uncertain (stop 16). Modes 0-1 sized by the sector RMS (until stop 16) stated the
    wheels that state the most about twice what they are off (bench/accuracy.py's table of
    stated against observed, docs/accuracy.md). On a view seeing less of its rim, where the
    modes cannot be told apart, modes 0-1 have the standard deviation of its sector
    medians: the RMS of the median residual of each of ``n_sectors`` sectors, less its noise
    (``sector_bias_rms``), and mode 2 none.

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
    against a fit that gives it little weight: toe stated/RMS 1.45 on the held-out vehicles
    1050-1089 (with the 0.010 deg floor), 1.26 with the weighted modes."""
    c = sol.x[2:5]
    n = normal_from(sol.x[:2], n0, e1, e2)
    J = sol.jac
    pinv = np.linalg.pinv(J.T @ J) @ J.T                                  # (P, N)
    bounds = np.cumsum([0] + [len(v[1]) for v in views])
    cov = np.zeros((J.shape[1], J.shape[1]))
    common = np.zeros((J.shape[1], 1))
    for (cam, xy, *_), a, b in zip(views, bounds[:-1], bounds[1:]):
        r = sol.fun[a:b]
        phi = rim_angles(cam, xy, c, n)
        med, count = sector_medians(r, sector_labels(phi, n_sectors), n_sectors)
        full = np.nonzero(count >= 3)[0]
        noise = 1.4826 * np.median(np.abs(r - np.median(r)))  # the part of each median that is noise:
        se2 = (1.2533 * noise) ** 2 / count[full]                 # its squared standard error
        sigma_b = sector_bias_rms(med[full], se2)
        modes = min(n_modes, 2)
        high = min(high_mode_amplitude(med[full], full, se2, n_sectors), sigma_b)
        low = high if LOW_MODES_FROM_HIGH and len(full) >= MIN_SPECTRUM_SECTORS else sigma_b
        amps = [low] * (1 + 2 * min(modes, 1))                    # modes 0, 1
        if modes == 2:
            amps += [high] * 2
        funcs = [np.ones_like(phi)] + [f(k * phi) for k in range(1, modes + 1) for f in (np.cos, np.sin)]
        dp = pinv[:, a:b] @ (np.stack(funcs, axis=1) * np.array(amps))   # (P, modes)
        common += dp[:, :1]                # the uniform offset: the same in both views
        cov += dp[:, 1:] @ dp[:, 1:].T     # the rest: each view's own
    return cov + common @ common.T


def sector_bias_rms(meds: np.ndarray, se2: np.ndarray) -> float:
    """RMS bias of sector medians (S,) whose squared standard errors from noise are se2 (S,)."""
    return float(np.sqrt(max(np.mean(meds ** 2 - se2), 0.0))) if len(meds) else 0.0


MIN_SPECTRUM_SECTORS = 12  # sectors (of 18) a view must cover to measure its modes 3-4
HIGH_MODE_CHI2 = 9.49      # chi-square, 4 dof, 95 %: modes 3-4 hold power beyond their noise


_FOURIER_PINV = BoundedCache(64)  # per set of seen sectors: most views see all, cycle after cycle


def _fourier_pinv(sectors: np.ndarray, n_sectors: int) -> np.ndarray:
    """(9, S) least-squares operator from the medians of ``sectors`` (S,) to Fourier modes 0-4."""
    angle = (sectors + 0.5) * (2 * np.pi / n_sectors) - np.pi
    A = np.stack([np.ones_like(angle)] + [f(k * angle) for k in range(1, 5) for f in (np.cos, np.sin)], axis=1)
    return np.linalg.pinv(A)


def high_mode_amplitude(meds: np.ndarray, sectors: np.ndarray, se2: np.ndarray, n_sectors: int) -> float:
    """Amplitude (px) of one Fourier function at modes 3-4 of the sector medians meds (S,) of
    the sectors ``sectors`` (S,) ints (least squares of modes 0-4, their noise se2 (S,)
    subtracted). 0 when fewer than MIN_SPECTRUM_SECTORS sectors are seen: on a short arc the
    modes cannot be told apart, and modes 0-1 already stand for the arc's smooth bias (with
    the sector RMS as mode 2's size there, a wheel seen on 10 of 18 sectors stated 0.34 deg
    of camber for an error of 0.04)."""
    if len(meds) < MIN_SPECTRUM_SECTORS:
        return 0.0
    P = _FOURIER_PINV.get((n_sectors, sectors.tobytes()), lambda: _fourier_pinv(sectors, n_sectors))  # (9, S)
    coef = P @ meds
    noise2 = (P[5:] ** 2) @ se2                                          # each coefficient's noise
    if np.sum(coef[5:] ** 2 / np.maximum(noise2, 1e-30)) < HIGH_MODE_CHI2:
        return 0.0  # no power above the noise: a noise estimate would still come out positive
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


def _axis_difference(fit: WheelFit, other: WheelFit) -> np.ndarray:
    """(3,) other's axis minus fit's, other's sign flipped if they point opposite ways (so that
    fit + d points the way fit does)."""
    return other.axis_station * np.sign(other.axis_station @ fit.axis_station) - fit.axis_station


def extra_points_bias2(fit: WheelFit, subset: WheelFit) -> float:
    """The squared axis error (rad^2) that the points ``fit`` has and ``subset`` (the fit of a
    subset of them) has not are estimated to add: the squared angle between the two axes
    minus what the points' noise explains (for nested fits the difference has about the
    covariance ``subset.cov_axis_noise - fit.cov_axis_noise``), at least 0 (a Hausman-style
    estimate of their bias)."""
    d = _axis_difference(fit, subset)
    excess = float(np.trace(subset.cov_axis_noise) - np.trace(fit.cov_axis_noise))
    return max(float(d @ d) - max(excess, 0.0), 0.0)


INCONSISTENT_CHI2 = 9.21  # chi-square, 2 degrees of freedom, 99 %


def inconsistent(fit: WheelFit, other: WheelFit) -> bool:
    """Whether two fits' axes differ by more than even their stated uncertainties (noise and
    biases, ``cov_axis``) allow at 99 %: then at least one of them is wrong in a way its
    covariance does not describe, and neither difference-based estimate can be trusted."""
    return _beyond(_axis_difference(fit, other), float(np.trace(fit.cov_axis) + np.trace(other.cov_axis)))


def moved_beyond_subset(fit: WheelFit, subset: WheelFit) -> bool:
    """Whether the points ``fit`` has and ``subset`` (the fit of a subset of them) has not move
    the axis by more than the subset's own stated uncertainty allows at 99 %. Were those points
    unbiased, the two axes would differ by about the noise the subset lacks,
    cov(subset) - cov(fit), less than cov(subset): a difference beyond that says they are
    biased, whatever ``fit`` states (a fit whose covariance grew with its bad points stays
    ``inconsistent``-free with anything)."""
    return _beyond(_axis_difference(fit, subset), float(np.trace(subset.cov_axis)))


def _beyond(d: np.ndarray, spread: float) -> bool:
    """Whether an axis difference d (3,) exceeds the 99 % chi-square (2 dof) of a covariance
    of trace ``spread`` (rad^2; its two components across the axis share it)."""
    return bool(np.isfinite(spread)) and float(d @ d) > 0.5 * INCONSISTENT_CHI2 * spread


def axis_covariance(n: np.ndarray, e1: np.ndarray, e2: np.ndarray, cov_ab: np.ndarray) -> np.ndarray:
    """(3,3) covariance of the unit normal n from that (2,2) of its parameters (a, b):
    d n / d (a, b) = (I - n n^T) [e1 e2] / |n0 + a e1 + b e2|, ~ the tangent basis at the solution."""
    Jn = (np.eye(3) - np.outer(n, n)) @ np.stack([e1, e2], axis=1)
    return Jn @ cov_ab @ Jn.T


def normal_from(params, n0, e1, e2):
    n = n0 + params[0] * e1 + params[1] * e2
    return n / np.linalg.norm(n)


def with_disagreement(fit: WheelFit, other: WheelFit) -> WheelFit:
    """``fit`` whose axis covariance also holds its difference d from ``other``, a fit of the
    same wheel on other points that disagrees beyond what both state (``inconsistent``): one
    of the two is wrong. The kept one is wrong by d with the chance that the other is right,
    taken as the other's share of their certainty, tr(C_fit) / (tr(C_fit) + tr(C_other)):
    cov_axis + p d d^T. Two fits equally sure and 0.95 deg apart (a reference view seeing half
    its rim) no longer state +/-0.1 each; a broken fit stated +/-3 deg hardly counts."""
    d = _axis_difference(fit, other)
    d = d - (d @ fit.axis_station) * fit.axis_station  # across the axis
    a, b = float(np.trace(fit.cov_axis)), float(np.trace(other.cov_axis))
    p_other = a / (a + b) if np.isfinite(a + b) and a >= 0 and b >= 0 and a + b > 0 else 0.0  # (a broken fit's
    # covariance may be no covariance at all)
    return replace(fit, cov_axis=fit.cov_axis + p_other * np.outer(d, d))


def toward_subset_weight(fit: WheelFit, subset: WheelFit) -> float:
    """How far (0..1) to move from ``fit`` toward ``subset``, the fit of a subset of its
    points, to minimise the expected squared axis error.

    Write fit = truth + b + e and subset = truth + e + u: the extra points add a bias b and
    take away the noise u, of variance V = tr(C_subset) - tr(C_fit) (the stated covariances,
    noise and biases). fit + l (subset - fit) has the expected squared error
    (1 - l)^2 |b|^2 + tr(C_fit) + l^2 V, least at l = |b|^2 / (|b|^2 + V), with |b|^2 from
    ``extra_points_bias2``. l = 1 when the subset is the better determined anyway (V <= 0),
    0 when the extra points show no bias, 1/2 where a choice of the smaller expected error
    would flip: near there, a hard choice moves the result by the whole difference between
    the fits on an immaterial change of the points."""
    bias2 = extra_points_bias2(fit, subset)
    var = float(np.trace(subset.cov_axis) - np.trace(fit.cov_axis))
    if not (np.isfinite(bias2) and np.isfinite(var)):
        return 0.0
    if var <= 0:
        return 1.0
    return bias2 / (bias2 + var)


def toward(fit: WheelFit, other: WheelFit, weight: float) -> WheelFit:
    """The fit ``weight`` (0..1) of the way from ``fit`` to ``other`` (centre, axis, radius),
    with the covariances (1 - weight^2) C_fit + weight^2 C_other (the nested-fit model of
    ``toward_subset_weight``) plus the squared bias left, (1 - weight)^2 times the estimated
    extra-points bias along the axes' difference. The rest (point counts, residuals, flags)
    is from the nearer of the two."""
    if weight <= 0.0:
        return fit
    if weight >= 1.0:
        return other
    d = _axis_difference(fit, other)
    n = fit.axis_station + weight * d
    n /= np.linalg.norm(n)
    bias2 = extra_points_bias2(fit, other)
    across = d - (d @ n) * n
    norm = float(np.linalg.norm(across))
    bias_axis = (1 - weight) ** 2 * bias2 * np.outer(across, across) / norm**2 if norm > 0 else 0.0
    a, b = 1 - weight**2, weight**2
    noise = None
    if fit.cov_axis_noise is not None and other.cov_axis_noise is not None:
        noise = a * fit.cov_axis_noise + b * other.cov_axis_noise
    base = fit if weight < 0.5 else other
    return replace(base, center_station=fit.center_station + weight * (other.center_station - fit.center_station),
                   axis_station=n, radius_m=fit.radius_m + weight * (other.radius_m - fit.radius_m),
                   cov_axis=a * fit.cov_axis + b * other.cov_axis + bias_axis,
                   cov_center=a * fit.cov_center + b * other.cov_center, cov_axis_noise=noise)

