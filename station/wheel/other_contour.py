"""Arcs of a rim that follow another concentric contour of the wheel.

Where the flange edge has no contrast on part of the rim (a dark rim whose rounded lip is in
shadow at the bottom, a lit tyre bead just outside it), the detector follows the nearest
concentric contour there instead: the lip's inner edge, a step on the tyre bead. The points
of both contours together still fit one ellipse in each view, and one 3-D circle to both
views, but a TILTED one: the mixture of two radii on different arcs reads as a wrong camber
or toe, with a large stated uncertainty (docs/measurement.md).

Every concentric contour of a wheel lies in a plane perpendicular to the spin axis, around the
same centre: in the plane of the right circle, the points of both contours sit at two radii.
This module tests that explanation. Each hypothesis is a circle fitted to the points on one
half of the rim (a half that holds one contour only, in the failing cases); every point's ray
is then met with that circle's plane, and its distance from the centre (``radial_offsets_m``)
is compared with the circle's radius. The hypothesis that explains the most points by its
own radius and one other is kept when it explains clearly more of them than the original
circle did. Then both contours are fitted together (``fit_two_contours``: one axis and
centre, a radius each, the second's plane offset along the axis); points on neither are left
out.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibration.camera_model import CameraModel
from calibration.triangulation import homogeneous
from station.errors import MeasurementError
from station.wheel.robust_lsq import soft_l1_least_squares
from station.wheel.epipolar import epipolar_tangency_px
from station.wheel.circle_fit import MIN_VIEW_POINTS, CircleFitSettings, contrast_weights, tangent_gaps
from station.wheel.conics import circle_conics, sampson_jacobian
from station.wheel.fit import WheelFit
from station.wheel.uncertainty import axis_basis, axis_covariance, bias_covariance, noise_covariance, normal_from
from station.wheel.arcs import rim_angles

WINDOWS = 4               # half-rim windows, centred 90 degrees apart
MIN_WINDOW_POINTS = 40    # per view, for a hypothesis circle
TOL_PX = (0.5, 1.5)       # radial tolerance: 3 robust sigmas of the hypothesis' own offsets, clipped
MIN_SECOND = 0.10         # the second contour holds at least this fraction of the points
MIN_GAIN = 0.15           # and the hypothesis explains this much more of them than the circle did
MAX_OFFSET = 0.12         # the second contour lies within this fraction of the radius
REFITS = 2                # rounds of refitting a hypothesis to every point it explains
MAX_RADIUS_CHANGE = 0.5   # a hypothesis this much larger or smaller than the circle is no concentric contour
SEPARATION = 3.0          # and at least this many tolerances from the first (not its noise tail)
TEST_ABOVE_DEG = 0.15      # a circle whose own axis uncertainty is above this is tested at all (deg)


def radial_offsets_m(cam: CameraModel, xy: np.ndarray, c: np.ndarray, n: np.ndarray, radius_m: float) -> np.ndarray:
    """(N,) distance (m) from the centre c (3,) of the points where the rays of normalised
    points xy (N,2) meet the plane through c with normal n (3,), minus ``radius_m``: the
    radial offset of each point in the circle's plane."""
    C0 = cam.center_station
    d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ cam.R_cam_station
    P = C0 + (((c - C0) @ n) / (d @ n))[:, None] * d
    return np.linalg.norm(P - c, axis=1) - radius_m


def metres_per_px(cam: CameraModel, c: np.ndarray) -> float:
    """The size of a pixel at the depth of the point c (3,) (station frame)."""
    return float((cam.R_cam_station @ c + cam.t_cam_station)[2] / (0.5 * (cam.K[0, 0] + cam.K[1, 1])))


def _explained(offsets: np.ndarray, tol: np.ndarray, max_offset: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Points within their ``tol`` (N,) of offset 0 (N,), and of the most populated other
    offset within ``max_offset``: (on the first (N,) bool, on the second (N,) bool, its offset)."""
    first = np.abs(offsets) <= tol
    near = ~first & (np.abs(offsets) <= max_offset)
    rest = offsets[near]
    if len(rest) == 0:
        return first, np.zeros_like(first), 0.0
    w = float(np.median(tol[near]))
    edges = np.arange(-max_offset, max_offset + w, w)
    hist = np.bincount(np.clip(((rest + max_offset) / w).astype(int), 0, len(edges) - 1), minlength=len(edges))
    hist = hist[:-1] + hist[1:]  # windows of two bins: a peak that straddles a bin edge counts whole
    k = int(np.argmax(hist))
    centre = np.median(rest[(rest >= edges[k]) & (rest < edges[k] + 2 * w)])
    second = ~first & (np.abs(offsets - centre) <= tol)
    return first, second, float(centre)


def other_contour_points(views, circle, fit_plain):
    """Which points to keep when some arcs follow another concentric contour, or None.

    views: [(camera, normalised points (N,2)), (camera, (M,2))]; circle: the WheelFit of all
    of them; fit_plain(mask_l, mask_r, start) -> WheelFit: one circle through the masked
    points, fitted from the WheelFit ``start``.
    Returns ([(N,) ints, (M,) ints] labels: 1 on the contour with the most points, 2 on the
    other, 0 on neither; info dict) or None when no hypothesis explains clearly more points
    than ``circle`` does."""
    c0, n0 = circle.center_station, circle.axis_station
    base = np.concatenate([radial_offsets_m(cam, xy, c0, n0, circle.radius_m) / metres_per_px(cam, c0)
                           for cam, xy in views])                                   # px at the wheel
    phis = [rim_angles(cam, xy, c0, n0) for cam, xy in views]
    best = None
    for k in range(WINDOWS):
        phi0 = -np.pi + 2 * np.pi * k / WINDOWS
        sel = [np.abs(np.angle(np.exp(1j * (phi - phi0)))) < np.pi / 2 for phi in phis]
        if min(int(s.sum()) for s in sel) < MIN_WINDOW_POINTS:
            continue
        split = np.cumsum([len(xy) for _, xy in views])[:-1]
        hyp = circle
        for _ in range(1 + REFITS):  # the window's circle, then refitted to all points on it
            try:
                hyp = fit_plain(sel[0], sel[1], hyp)
            except (MeasurementError, np.linalg.LinAlgError, ValueError):
                hyp = None
            if hyp is None:  # a hypothesis that cannot be fitted is no explanation
                break
            c, n = hyp.center_station, hyp.axis_station
            scale = [metres_per_px(cam, c) for cam, _ in views]
            if min(scale) <= 0 or not abs(hyp.radius_m / circle.radius_m - 1) <= MAX_RADIUS_CHANGE:
                hyp = None  # a wild fit (behind a camera, or another circle altogether) explains nothing
                break
            offs = [radial_offsets_m(cam, xy, c, n, hyp.radius_m) for cam, xy in views]
            inside = np.concatenate([o[s] / m for o, s, m in zip(offs, sel, scale)])         # px
            sigma = 1.4826 * np.median(np.abs(inside - np.median(inside)))
            tol_px = float(np.clip(3 * sigma, *TOL_PX))
            tol = np.concatenate([np.full(len(o), tol_px * m) for o, m in zip(offs, scale)])  # m
            on = np.split(np.abs(np.concatenate(offs)) <= tol, split)
            if min(int(s.sum()) for s in on) < MIN_WINDOW_POINTS:
                break
            sel = on
        if hyp is None:
            continue
        first, second, offset = _explained(np.concatenate(offs), tol, MAX_OFFSET * hyp.radius_m)
        if second.mean() < MIN_SECOND or abs(offset) < SEPARATION * float(np.median(tol)):
            second = np.zeros_like(first)  # no second contour: its noise tail, or scattered points
        score = float((first | second).mean())
        if best is None or score > best["score"]:
            best = {"score": score, "tol_px": tol_px, "first": first, "second": second, "offset_mm": offset * 1e3,
                    "base": float((np.abs(base) <= tol_px).mean()), "window": k}
    if best is None:
        return None
    if best["score"] - best["base"] < MIN_GAIN:
        return None
    first, second = best["first"], best["second"]
    info = {k: best[k] for k in ("score", "tol_px", "offset_mm", "base", "window")}
    if second.sum() > first.sum():  # label 1: the contour with the most points
        first, second = second, first
        info["offset_mm"] = -info["offset_mm"]
    labels = np.where(first, 1, np.where(second, 2, 0))
    split = np.cumsum([len(xy) for _, xy in views])[:-1]
    info["fraction_second"] = float(second.mean())
    if not second.any():
        info["offset_mm"] = None
    return np.split(labels, split), info

MIN_SECOND_PER_VIEW = 20  # points on the second contour in each view, to fit it as well


def fit_two_contours(views, labels, init, loss_scale_px: float = CircleFitSettings.loss_scale_px,
                     bias_modes: int = CircleFitSettings.bias_modes, weights=None):
    """One spin axis, centre and radius for the points of label 1, and a second concentric
    circle (its own radius, its plane offset along the axis) for those of label 2.

    views: [(camera, normalised points (N,2)), (camera, (M,2))]; labels: per view (N,) ints,
    1 or 2 (0: neither, left out); init: a WheelFit to start from. Parameters (a, b, c (3),
    R1, R2, h2): the normal n0 + a e1 + b e2 (normalised), contour 1 the circle (c, n, R1),
    contour 2 (c + h2 n, n, R2). Residuals: Sampson distances (px), soft-L1 at
    ``loss_scale_px``, each weighted by ``weights`` (per view (N,), or None: 1; as in
    :func:`station.wheel.circle_fit.refine_circle`). Returns a WheelFit of contour 1, its covariances as the circle fit
    states them (Jacobian, residual correlation along the rim, slow edge biases); None when a
    view keeps fewer than MIN_VIEW_POINTS points of contour 1 (no 3-D circle rests on it)."""
    if any(int((lab == 1).sum()) < MIN_VIEW_POINTS for lab in labels):
        return None
    n0, e1, e2 = axis_basis(init.axis_station)
    weights = weights or [np.ones(len(xy)) for _, xy in views]
    used = [(cam, xy[lab > 0], lab[lab > 0], 0.5 * (cam.K[0, 0] + cam.K[1, 1]), w[lab > 0])
            for (cam, xy), lab, w in zip(views, labels, weights)]
    second = all(int((lab == 2).sum()) >= MIN_SECOND_PER_VIEW for _, _, lab, _, _ in used)
    if not second:  # too little of the other contour to place it: contour 1 alone
        used = [(cam, xy[lab == 1], lab[lab == 1], f, w[lab == 1]) for cam, xy, lab, f, w in used]
    hviews = [(cam, homogeneous(xy), lab, f) for cam, xy, lab, f, _ in used]
    w_all = np.concatenate([w for *_, w in used])

    def conics(P, cam):
        """(K,3,3) image conics of contour 1 and contour 2 for K parameter vectors P (K,8)."""
        n = n0 + P[:, :1] * e1 + P[:, 1:2] * e2
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        c1 = P[:, 2:5]
        c2 = c1 + P[:, 7:8] * n
        R, t = cam.R_cam_station, cam.t_cam_station
        return (circle_conics(c1 @ R.T + t, n @ R.T, P[:, 5]), circle_conics(c2 @ R.T + t, n @ R.T, P[:, 6]))

    n_par = 8 if second else 6

    def residuals_and_jacobian(p):
        h = 1e-6 * np.maximum(1.0, np.abs(p))
        P = np.vstack([p, p + np.diag(h), p - np.diag(h)])                 # (2 n_par + 1, n_par)
        if n_par == 6:
            P = np.concatenate([P, np.zeros((len(P), 2))], axis=1)
        r_all, J_all = [], []
        for cam, X, lab, f in hviews:
            r = np.empty(len(X))
            J = np.empty((len(X), n_par))
            for g, C in zip((1, 2), conics(P, cam)):
                m = lab == g
                if m.any():
                    dC = (C[1:n_par + 1] - C[n_par + 1:]) / (2 * h)[:, None, None]
                    r[m], J[m] = sampson_jacobian(C[0], dC, X[m], f)
            r_all.append(r)
            J_all.append(J)
        return w_all * np.concatenate(r_all), w_all[:, None] * np.vstack(J_all)

    x0 = np.concatenate([[0.0, 0.0], init.center_station, [init.radius_m]])
    if second:
        r2 = [np.median(radial_offsets_m(cam, xy[lab == 2], init.center_station, n0, init.radius_m))
              for cam, xy, lab, _, _ in used]
        x0 = np.concatenate([x0, [init.radius_m + float(np.mean(r2)), 0.0]])
    sol = soft_l1_least_squares(residuals_and_jacobian, x0, f_scale=loss_scale_px)
    fviews = [(cam, xy, f, w) for cam, xy, _, f, w in used]
    cov_p, inlier = noise_covariance(sol, fviews)
    if cov_p is None:
        return None
    tilts = []
    if bias_modes:
        cov_p = cov_p + bias_covariance(sol, fviews, n0, e1, e2, bias_modes, tilt_per_px=tilts)
    n = normal_from(sol.x[:2], n0, e1, e2)
    if n @ init.axis_station < 0:
        n = -n
    r = sol.fun / w_all  # px again
    return WheelFit("circle", sol.x[2:5].copy(), n, float(sol.x[5]),
                    view_median_px=tuple(float(np.median(np.abs(v)))
                                         for v in np.split(r, np.cumsum([len(v[1]) for v in fviews])[:-1])),
                    cov_center=cov_p[2:5, 2:5], cov_axis=axis_covariance(n, e1, e2, cov_p[:2, :2]),
                    reprojection_rms_px=float(np.sqrt(np.mean(r[inlier] ** 2))),
                    epipolar_rms_px=init.epipolar_rms_px, n_points=(len(used[0][1]), len(used[1][1])),
                    other_contour_mm=float(1e3 * (sol.x[6] - sol.x[5])) if second else None,
                    tilt_per_px_views=tuple(tilts) or None)


def refit_other_contour(points_l_px: np.ndarray, points_r_px: np.ndarray, cam_l: CameraModel, cam_r: CameraModel,
                        circle: WheelFit, above_deg: float = TEST_ABOVE_DEG,
                        contrast: tuple | None = None) -> WheelFit | None:
    """The wheel fitted with its arcs on another concentric contour told apart, or None.

    Tried only when ``circle`` (the fit of all points, (N,2) and (M,2) pixels) states an axis
    uncertainty above ``above_deg`` (its own covariance's, before the unseen terms), and kept
    only when it states a smaller one. ``contrast``: as for
    :func:`station.wheel.circle_fit.refine_circle`."""
    if not np.degrees(np.sqrt(max(np.trace(circle.cov_axis), 0.0))) > above_deg:  # (NaN: not above)
        return None
    views, weights = [], []
    for cam, pts, con in zip((cam_l, cam_r), (points_l_px, points_r_px), contrast or (None, None)):
        xy = cam.pixels_to_normalized(pts)
        finite = np.all(np.isfinite(xy), axis=1)
        views.append((cam, xy[finite]))
        weights.append(np.ones(int(finite.sum())) if con is None else contrast_weights(con)[finite])

    def fit_plain(sel_l, sel_r, start):  # one robust solve: the refits trim what does not fit
        return fit_two_contours(views, [sel_l.astype(int), sel_r.astype(int)], start, bias_modes=0, weights=weights)

    found = other_contour_points(views, circle, fit_plain)
    if found is None:
        return None
    labels, info = found
    alt = fit_two_contours(views, labels, circle, weights=weights)
    if alt is None or not np.trace(alt.cov_axis) < np.trace(circle.cov_axis):
        return None
    if alt.other_contour_mm is None and info["offset_mm"] is not None:
        alt = replace(alt, other_contour_mm=info["offset_mm"])  # found, too short to fit: left out
    try:  # the pair's epipolar check on the contour reported, as the circle fit does
        ones = [xy[lab == 1] for (_, xy), lab in zip(views, labels)]
        alt = replace(alt, epipolar_rms_px=epipolar_tangency_px(ones[0], ones[1], cam_l, cam_r))
    except (MeasurementError, np.linalg.LinAlgError, ValueError):
        pass
    # and, on every point found, whether the cameras saw the rim where the epipolar planes touch it
    return replace(alt, arcs_left_out=True, tangent_gap_deg=tangent_gaps(views[0][1], views[1][1], cam_l, cam_r))


LIVE_TOL_PX = 1.5  # station live: a point this near the last circle, in its plane, is on its contour


def on_circle(views, circle: WheelFit, tol_px: float = LIVE_TOL_PX) -> list[np.ndarray]:
    """Per view (camera, normalised points (N,2)), the (N,) bool mask of the points whose
    radial offset from ``circle`` in its plane is within ``tol_px`` pixels at the wheel:
    ``station live`` keeps a wheel's arcs on another contour out, update after update, as
    its baseline cycle did, without searching again."""
    return [np.abs(radial_offsets_m(cam, xy, circle.center_station, circle.axis_station, circle.radius_m))
            <= tol_px * metres_per_px(cam, circle.center_station) for cam, xy in views]
