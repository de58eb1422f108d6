"""Two fits of one wheel on different points: how far apart they may be, and which to keep.

* :func:`extra_points_bias2` - the bias the points one fit has and the other has not add;
* :func:`inconsistent` - the two differ beyond what both state; :func:`moved_beyond_subset` -
  beyond what the fit of the subset states;
* :func:`with_disagreement` - the kept one states their difference as well;
* :func:`toward_subset_weight` and :func:`toward` - the least-error step from a fit toward the
  fit of a subset of its points.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from station.wheel.fit import WheelFit


def _axis_difference(fit: WheelFit, other: WheelFit) -> np.ndarray:
    """(3,) other's axis minus fit's, other's sign flipped if they point opposite ways (so that
    fit + d points the way fit does)."""
    return other.axis_station * np.sign(other.axis_station @ fit.axis_station) - fit.axis_station


def _noise_added(fit: WheelFit, subset: WheelFit) -> float:
    """tr(N_subset) - tr(N_fit) (rad^2): the noise the points ``subset`` lacks take away, from
    the two nested fits' noise covariances (``cov_axis_noise``)."""
    return float(np.trace(subset.cov_axis_noise) - np.trace(fit.cov_axis_noise))


def extra_points_bias2(fit: WheelFit, subset: WheelFit) -> float:
    """The squared axis error (rad^2) that the points ``fit`` has and ``subset`` (the fit of a
    subset of them) has not are estimated to add: the squared angle between the two axes
    minus what the points' noise explains (for nested fits the difference has about the
    covariance ``subset.cov_axis_noise - fit.cov_axis_noise``), at least 0 (a Hausman-style
    estimate of their bias)."""
    d = _axis_difference(fit, subset)
    return max(float(d @ d) - max(_noise_added(fit, subset), 0.0), 0.0)


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
    take away u, of variance V = tr(C_subset) - tr(C_fit) (the stated covariances: the
    subset's weaker geometry states its shared biases larger too), and at least the noise
    they take away (``_noise_added``): a weak edge-bias power
    estimated on the full fit's views and none on the subset's short arcs must not make the
    subset look surer than fewer points can be. fit + l (subset - fit) has the expected
    squared error (1 - l)^2 |b|^2 + tr(C_fit) + l^2 V, least at l = |b|^2 / (|b|^2 + V), with |b|^2 from
    ``extra_points_bias2``. l = 1 when the subset is the better determined anyway (V <= 0),
    0 when the extra points show no bias, 1/2 where a choice of the smaller expected error
    would flip: near there, a hard choice moves the result by the whole difference between
    the fits on an immaterial change of the points."""
    bias2 = extra_points_bias2(fit, subset)
    var = max(float(np.trace(subset.cov_axis) - np.trace(fit.cov_axis)), _noise_added(fit, subset))
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
