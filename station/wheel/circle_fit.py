"""The 3-D circle fit: one circle (centre, normal, radius) fitted to both views' rim points.

The fit minimises the points' image distance to the circle's projection in each view (exact
conics in normalised coordinates, Sampson distance scaled to pixels, station/wheel/conics.py)
with a robust loss, without matching points between the views. Around the solve, tests leave
out what is not the flange edge: arcs the tyre's sidewall hides, points on another contour,
arcs that stray from the circle, points seen across the lip at a grazing angle, faint points
that tilt the circle (:class:`CircleFitSettings` says which tests run). Inputs are the
rim-flange edge points each camera detected (distorted pixels) and the pair's calibrated
CameraModels; outputs are in the station frame (docs/conventions.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibration.camera_model import CameraModel
from calibration.triangulation import homogeneous, triangulate_paper_full
from station.compute.blas_threads import single_thread_blas
from station.errors import MeasurementError
from station.rim.choice import DARK_RIM_NOTE
from station.wheel.arcs import (MIN_KEPT_FRACTION, edge_visibility, hidden_arcs, not_grazing_xy, rim_angles,
                                stray_arcs, stray_floor_px)
from station.wheel.conics import circle_conic, circle_conics, sampson_jacobian, sampson_px
from station.wheel.epipolar import epipolar_tangency_px, pair_relation, tangent_point_gaps_deg
from station.wheel.fit import WheelFit, outward_sign
from station.wheel.fit_compare import (inconsistent, moved_beyond_subset, toward, toward_subset_weight,
                                       with_disagreement)
from station.wheel.robust_lsq import soft_l1_least_squares
from station.wheel.uncertainty import axis_basis, axis_covariance, bias_covariance, noise_covariance, normal_from

single_thread_blas()  # small least-squares problems: OpenBLAS threads cost 40x here (station/compute/blas_threads.py)

MIN_SAFE_FRACTION = 0.2  # of a view's points that no sidewall can hide, to make the sidewall test at all
MIN_VIEW_POINTS = 20      # rim points a view must keep on the fitted circle
FAINT_STEP_SHARE = 0.2    # faint: under this share of the view's median step (the detector passes' own floor)
GROSS_PX = 1.5            # a point this far (px) off the fitted circle, and GROSS_SIGMAS robust
GROSS_SIGMAS = 5.0        # sigmas, is on another contour: left out and the circle fitted again
MIN_CONTRAST_WEIGHT = 0.05  # a weight never reaches 0: the residual divided by it gives px again


@dataclass(frozen=True)
class CircleFitSettings:
    """What the circle fit does besides the solve. The defaults are a cycle's full fit;
    ``station live`` fits without the covariance's bias term and without the grazing test
    (station/live.py)."""

    loss_scale_px: float = 0.3  # soft-L1 scale (px): the edge points' noise
    inward_weight: float = 0.3  # residuals inside the rim's projection beyond the noise count this much
    bias_modes: int = 2         # edge-bias Fourier modes in the covariance (0: uniform, 1: + cos/sin,
                                # 2: + elongation; 0 leaves the bias term out)
    occlusion_test: bool = True  # test the arcs the tyre's sidewall could hide before trusting them
    grazing_test: bool = True    # also fit without the points seen across the lip at a grazing angle
    faint_test: bool = True      # with contrast: also fit without the points of faint edge step
    stray_arc_passes: int = 3    # rounds of leaving out arcs whose edge strays from the fitted circle


def circle_from_ellipses(cam_l: CameraModel, cam_r: CameraModel, ellipse_l, ellipse_r) -> tuple[np.ndarray, float]:
    """(centre (3,), radius m) of the rim from its two image ellipses (ideal, undistorted
    pixels): the station point nearest the rays through the ellipses' centres, and the radius
    that the major semi-axes subtend at its depth (a circle's major axis is never
    foreshortened), averaged over the two cameras. An ellipse's centre is not the image of the
    circle's, and the two rays meet at a narrow angle: 3-4 cm off along them and 3 % in radius
    on the simulated station, a start for the circle fit, not a measurement. But it holds
    whatever part of the rim the cameras see, where the paper's centroid of the triangulated
    points lies toward the seen part (0.1-0.16 m off for half a rim)."""
    R, t = pair_relation(cam_l, cam_r)
    rays = [np.linalg.solve(cam.K, [e.center_px[0], e.center_px[1], 1.0]) for cam, e in
            ((cam_l, ellipse_l), (cam_r, ellipse_r))]              # homogeneous normalised centres
    mid_l = triangulate_paper_full(rays[0][None], rays[1][None], R, t).midpoint_l[0]  # left camera frame
    centre = (mid_l - cam_l.t_cam_station) @ cam_l.R_cam_station
    depth = [(cam.R_cam_station @ centre + cam.t_cam_station)[2] for cam in (cam_l, cam_r)]
    radius = np.mean([e.axes_px[0] * z / (0.5 * (cam.K[0, 0] + cam.K[1, 1]))
                      for cam, e, z in ((cam_l, ellipse_l, depth[0]), (cam_r, ellipse_r, depth[1]))])
    return centre, float(radius)


def tangent_gaps(xy_l: np.ndarray, xy_r: np.ndarray, cam_l: CameraModel, cam_r: CameraModel) -> tuple[float, float]:
    """Per view, the larger of its ``tangent_point_gaps_deg`` (NaN where they cannot be found)."""
    try:
        g = tangent_point_gaps_deg(xy_l, xy_r, cam_l, cam_r)
        return float(np.max(g[:2])), float(np.max(g[2:]))
    except (np.linalg.LinAlgError, ValueError):
        return float("nan"), float("nan")


def refine_circle(points_l_px: np.ndarray, points_r_px: np.ndarray, cam_l: CameraModel, cam_r: CameraModel,
                  init: WheelFit, *, contrast: tuple | None = None, settings: CircleFitSettings = CircleFitSettings(),
                  init_is_fitted: bool = False) -> WheelFit:
    """Fit one 3-D circle to both views' rim points (N,2), (M,2) (distorted pixels) by
    minimising their image distance (px) to its projections, starting from ``init``.

    ``contrast``: per view, each point's edge step (grey levels, (N,) and (M,), as
    :class:`station.rim.RimDetection` gives them) or None. A point's residual is then weighted
    by :func:`contrast_weights`: an edge's position is as uncertain as its noise over its step,
    and a faint stretch of the flange edge is also where a nearby stronger edge (a shaded tyre
    bead) pulls the sub-pixel point off it. The weights enter the final solve, on the points
    the tests below kept; the tests and the solves before it are unweighted.

    Residuals of points inside the circle's projection count ``settings.inward_weight`` times
    (1: a symmetric fit): the tyre bulge and a lip shaded as dark as the tyre hide the flange
    edge on whole arcs of an oblique view, and then the edge the detector finds lies inside it.

    The covariance is (a) the Jacobian's, inflated by the residuals' correlation along the rim,
    plus (b) slowly varying edge biases (:func:`bias_covariance`, Fourier modes up to
    ``settings.bias_modes`` of the rim angle; 0 leaves it out).

    ``settings.occlusion_test``: arcs that the sidewall *could* hide are tested instead of
    trusted (:func:`hidden_arcs`): the circle is first fitted to the points that no sidewall
    can hide, and an arc of doubtful points whose edge lies inside that circle's projection
    beyond the noise is left out of the final fit; arcs that agree are kept.
    ``init_is_fitted``: ``init`` is already a circle fitted this way (``station live``'s previous
    frame): the test is made against it, without the first fit.

    ``settings.grazing_test``: the circle is also fitted without the points seen across the
    lip at a grazing angle, and the two are combined (:func:`_with_subset_fit`).

    ``settings.faint_test``: with ``contrast``, the circle is also fitted without each view's
    faint points, and that fit is taken where they move the axis beyond what it states
    (:func:`_without_faint`).
    """
    xys, ws, steps = [], [], []
    for cam, pts, con in zip((cam_l, cam_r), (points_l_px, points_r_px), contrast or (None, None)):
        xy = cam.pixels_to_normalized(pts)
        keep = np.all(np.isfinite(xy), axis=1)
        xys.append(xy[keep])
        ws.append(None if con is None else contrast_weights(con)[keep])
        steps.append(None if con is None else np.asarray(con, float)[keep])

    def fitted(keep=(None, None)):
        return _fit_circle([xy if k is None else xy[k] for xy, k in zip(xys, keep)],
                           [w if k is None else _subset(w, k) for w, k in zip(ws, keep)], (cam_l, cam_r), init,
                           settings, init_is_fitted)

    fit = fitted()
    if settings.faint_test and all(c is not None for c in steps):
        fit = _without_faint(fit, steps, fitted)
    # on every point the cameras found: did they see the rim where the epipolar planes touch it?
    return replace(fit, tangent_gap_deg=tangent_gaps(xys[0], xys[1], cam_l, cam_r))


def contrast_weights(contrast: np.ndarray) -> np.ndarray:
    """(N,) residual weights of a view's points from their edge steps ``contrast`` (N,): the step
    over the view's median step, at most 1 (inverse-sigma weighting for the faint points; the
    strong ones stay equal, so that a lit highlight next to the flange cannot outweigh the rest)."""
    c = np.asarray(contrast, float)
    med = float(np.median(c)) if len(c) else 0.0
    if not med > 0:
        return np.ones(len(c))
    return np.clip(c / med, MIN_CONTRAST_WEIGHT, 1.0)


def _subset(w: np.ndarray | None, keep: np.ndarray) -> np.ndarray | None:
    return None if w is None else w[keep]


# A view as the fit holds it: (camera, normalised points (N,2), focal length px, residual
# weights (N,)); a test that leaves points out subsets the points and their weights together.
View = tuple


class _CircleModel:
    """The residuals of a circle against views, and their solve. A circle is p (6,): the normal
    n0 + p[0] e1 + p[1] e2 (normalised; the basis from the start's axis), the centre p[2:5] and
    the radius p[5], station frame."""

    def __init__(self, basis: tuple[np.ndarray, np.ndarray, np.ndarray], settings: CircleFitSettings):
        self.n0, self.e1, self.e2 = basis
        self.scale = settings.loss_scale_px
        self.inward_weight = settings.inward_weight
        self.stray_arc_passes = settings.stray_arc_passes

    @staticmethod
    def homogeneous(views: list[View], keep: list[np.ndarray] | None = None, weighted: bool = True) -> list[View]:
        """The views with homogeneous points (N,3), only the ``keep`` (N,) bool of each if given,
        their weights or (not ``weighted``) ones."""
        return [(cam, homogeneous(xy), f, w if weighted else np.ones(len(xy))) if keep is None else
                (cam, homogeneous(xy[keep[k]]), f, w[keep[k]] if weighted else np.ones(int(np.sum(keep[k]))))
                for k, (cam, xy, f, w) in enumerate(views)]

    def normal(self, p: np.ndarray) -> np.ndarray:
        return normal_from(p[:2], self.n0, self.e1, self.e2)

    def raw_residuals(self, p: np.ndarray, views: list[View]) -> np.ndarray:
        """(N,) distances (px) of the views' points to the circle's projections, unweighted."""
        c = p[2:5]
        n = self.normal(p)
        out = []
        for cam, X, f, _ in self.homogeneous(views):
            C = circle_conic(cam.R_cam_station @ c + cam.t_cam_station, cam.R_cam_station @ n, p[5])
            out.append(sampson_px(C, X, f))
        return np.concatenate(out)

    def residuals_and_jacobian(self, p: np.ndarray, hviews: list[View]) -> tuple[np.ndarray, np.ndarray]:
        """The weighted residuals (N,) and their derivatives (N,6) d residuals / d p: the six
        conic derivatives by central differences (the conic is a low-order polynomial of p:
        exact to ~1e-10), the points' part analytic. An edge seen inside the rim's projection
        is more likely a hidden or shaded flange (tyre bulge, dark lip) than a real one:
        occlusion only ever moves the edge inward. Beyond the noise (the loss scale) only, such
        a residual counts ``inward_weight`` times; within it the fit stays unbiased."""
        h = 1e-6 * np.maximum(1.0, np.abs(p))
        P = np.vstack([p, p + np.diag(h), p - np.diag(h)])                  # (13,6)
        n = self.n0 + P[:, :1] * self.e1 + P[:, 1:2] * self.e2
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        raw, J = [], []
        for cam, X, f, _ in hviews:
            C = circle_conics(P[:, 2:5] @ cam.R_cam_station.T + cam.t_cam_station, n @ cam.R_cam_station.T, P[:, 5])
            r_k, J_k = sampson_jacobian(C[0], (C[1:7] - C[7:]) / (2 * h)[:, None, None], X, f)
            raw.append(r_k)
            J.append(J_k)
        r = np.concatenate(raw)
        w = np.concatenate([v[3] for v in hviews])
        s = self.scale
        inward = r < -s
        return (w * np.where(inward, self.inward_weight * (r + s) - s, r),
                np.vstack(J) * (w * np.where(inward, self.inward_weight, 1.0))[:, None])

    def solve(self, x0: np.ndarray, views: list[View], keep: list[np.ndarray] | None = None, weighted: bool = False):
        """The robust solve from x0 (6,) on the views' points (``keep`` of them), weighted or not."""
        hviews = self.homogeneous(views, keep, weighted)
        return soft_l1_least_squares(lambda p: self.residuals_and_jacobian(p, hviews), x0, f_scale=self.scale)


def _per_view(values: np.ndarray, views: list[View]) -> list[np.ndarray]:
    """A stacked (N,) array over the views -> one array per view."""
    return np.split(values, np.cumsum([len(v[1]) for v in views])[:-1])


def _fit_circle(xys: list[np.ndarray], ws: list[np.ndarray | None], cams: tuple[CameraModel, CameraModel],
                init: WheelFit, settings: CircleFitSettings, init_is_fitted: bool) -> WheelFit:
    """:func:`refine_circle` on both views' undistorted normalised points (N,2), (M,2) and their
    residual weights (N,), (M,) (None: all 1): the tests that leave points out, in turn, then
    the fit and its covariance; the fit without the grazing points where the settings ask."""
    views = [(cam, xy, 0.5 * (cam.K[0, 0] + cam.K[1, 1]), np.ones(len(xy)) if w is None else w)
             for cam, xy, w in zip(cams, xys, ws)]
    n_input = sum(len(v[1]) for v in views)
    model = _CircleModel(axis_basis(init.axis_station), settings)
    x0 = np.concatenate([[0.0, 0.0], init.center_station, [init.radius_m]])
    doubtful = False
    if settings.occlusion_test:
        views, x0, doubtful = _hidden_arcs_left_out(model, views, x0, init, init_is_fitted)
    sol = model.solve(x0, views)
    views, sol = _gross_outliers_left_out(model, views, sol)
    views, sol = _stray_arcs_left_out(model, views, sol)
    # the points' weights (their edge steps) enter the last solve only, on the points every
    # test above kept: weighted, the earlier solves moved those decisions (which arcs stay,
    # which runner-up pairs), and on harsh-light vehicles wheels came out 1.5 deg off
    if not all(np.all(v[3] == 1.0) for v in views):
        sol = model.solve(sol.x, views, weighted=True)
    fit = _wheel_fit(model, sol, views, init, settings, n_input)
    if doubtful:
        plain = _fit_circle(xys, ws, cams, init, replace(settings, occlusion_test=False, grazing_test=False),
                            init_is_fitted)
        if np.trace(plain.cov_axis) < np.trace(fit.cov_axis):
            fit = plain
    if settings.grazing_test:
        keeps = not_grazing_xy(fit, xys[0], xys[1], *cams)
        if not all(k.all() for k in keeps):
            # the fit without the grazing points, made from ``init`` as this one was (from
            # ``fit``, the sidewall test would be judged against a circle they had shaped)
            alt = _fit_circle([xy[k] for xy, k in zip(xys, keeps)], [_subset(w, k) for w, k in zip(ws, keeps)], cams,
                              init, replace(settings, grazing_test=False), init_is_fitted)
            fit = _with_subset_fit(fit, replace(alt, grazing_left_out=True))
    return fit


def _hidden_arcs_left_out(model: _CircleModel, views: list[View], x0: np.ndarray, init: WheelFit,
                          init_is_fitted: bool) -> tuple[list[View], np.ndarray, bool]:
    """The views without the arcs the tyre's sidewall hides (:func:`hidden_arcs`), judged
    against the circle of the points no sidewall can hide (or ``init``, when it is such a
    circle already), that circle (6,), and whether the test left out so much of a view that
    the fit should also be made without it. Views with too few safe points are not tested."""
    vis = [edge_visibility(cam, xy, init) for cam, xy, *_ in views]
    safe = [v >= 0.0 for v in vis]
    if not all(k.sum() >= MIN_SAFE_FRACTION * len(k) for k in safe):
        return views, x0, False
    # every other safe point: the test needs the circle to a tenth of a pixel, not better
    # (or ``init`` itself when it is such a circle: the last live frame's)
    x_safe = x0 if init_is_fitted else model.solve(x0, views, [k & (np.arange(len(k)) % 2 == 0) for k in safe]).x
    r_all = _per_view(model.raw_residuals(x_safe, views), views)
    c_safe, n_safe = x_safe[2:5], model.normal(x_safe)
    keeps = [hidden_arcs(r, k, rim_angles(cam, xy, c_safe, n_safe), model.scale)
             for r, k, (cam, xy, *_) in zip(r_all, safe, views)]
    # leaving out more than half of a view is either a camera that sees little of the
    # flange past the sidewall or a test judged against a circle extrapolated from
    # narrow safe arcs: fit it both ways and keep the better-determined axis
    doubtful = not all(k.sum() >= MIN_KEPT_FRACTION * len(k) for k in keeps)
    return [(cam, xy[k], f, w[k]) for (cam, xy, f, w), k in zip(views, keeps)], x_safe, doubtful


def _gross_outliers_left_out(model: _CircleModel, views: list[View], sol):
    """Points far off the circle in either view are another contour (a lip's inner edge taken
    for the flange where the flange is shaded as dark as the tyre: in one view the union of
    the two is itself an ellipse, only the other view shows it): the views without them and
    the circle fitted again. MeasurementError when a view keeps too few points for a rim."""
    r = model.raw_residuals(sol.x, views)
    sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    far = np.abs(r) > max(GROSS_PX, GROSS_SIGMAS * sigma)
    if not far.any():
        return views, sol
    views = [(cam, xy[~out], f, w[~out]) for (cam, xy, f, w), out in zip(views, _per_view(far, views))]
    for cam, xy, *_ in views:  # a view with (almost) nothing on the circle: no 3-D rim
        if len(xy) < MIN_VIEW_POINTS:
            raise MeasurementError(f"{cam.name}: only {len(xy)} of its rim points lie on the 3-D circle "
                                   "the pair's points agree on",
                                   hint=f"the two cameras may have found different rims; {DARK_RIM_NOTE}")
    return views, model.solve(sol.x, views)


def _stray_arcs_left_out(model: _CircleModel, views: list[View], sol):
    """Arcs biased inward that the tests before caught not (an edge moved over a whole arc by
    shading or a hidden flange on the side no sidewall model expects), or outward (a lit bead
    wall taken for metal): left out and the circle fitted again, a few rounds, never leaving a
    view under MIN_KEPT_FRACTION of its points."""
    n_start = [len(v[1]) for v in views]
    for _ in range(model.stray_arc_passes):
        c_now, n_now = sol.x[2:5], model.normal(sol.x)
        keeps = []
        for r_v, (cam, xy, *_), n_v in zip(_per_view(model.raw_residuals(sol.x, views), views), views, n_start):
            phi_v = rim_angles(cam, xy, c_now, n_now)
            keep = ~stray_arcs(r_v, phi_v, stray_floor_px(r_v, phi_v, model.scale))
            keeps.append(keep if keep.sum() >= MIN_KEPT_FRACTION * n_v else np.ones(len(xy), bool))
        if all(k.all() for k in keeps):
            break
        views = [(cam, xy[k], f, w[k]) for (cam, xy, f, w), k in zip(views, keeps)]
        sol = model.solve(sol.x, views)
    return views, sol


def _wheel_fit(model: _CircleModel, sol, views: list[View], init: WheelFit, settings: CircleFitSettings,
               n_input: int) -> WheelFit:
    """The WheelFit of a solve on the views it was made on: its covariance (the points' noise,
    and the edge biases' where ``settings.bias_modes``), the residuals per view, and the pair's
    epipolar check on these points."""
    r = sol.fun / np.concatenate([v[3] for v in views])  # px again (weights are > 0)
    cov_p, inlier = noise_covariance(sol, views)
    if cov_p is None:
        cov_p = np.full((6, 6), np.nan)
    cov_noise, own, tilts = cov_p, [], []
    if settings.bias_modes:
        cov_p = cov_p + bias_covariance(sol, views, model.n0, model.e1, model.e2, settings.bias_modes, own=own,
                                        tilt_per_px=tilts)
    # the pair's epipolar check on the points the circle was fitted to: an arc left out
    # (hidden, another contour) would otherwise move a tangent plane of its view's ellipse
    epipolar = init.epipolar_rms_px
    if sum(len(v[1]) for v in views) < n_input:
        try:
            epipolar = epipolar_tangency_px(views[0][1], views[1][1], views[0][0], views[1][0])
        except (MeasurementError, np.linalg.LinAlgError, ValueError):
            pass
    n = model.normal(sol.x)
    if n[0] * outward_sign(sol.x[2:5]) < 0:
        n = -n
    cov_axis = axis_covariance(n, model.e1, model.e2, cov_p[:2, :2])
    medians = tuple(float(np.median(np.abs(res))) if len(res) else float("inf") for res in _per_view(r, views))
    return WheelFit("circle", sol.x[2:5].copy(), n, float(sol.x[5]), view_median_px=medians,
                    cov_center=cov_p[2:5, 2:5], cov_axis=cov_axis,
                    reprojection_rms_px=float(np.sqrt(np.mean(r[inlier] ** 2))) if inlier.any() else float("nan"),
                    epipolar_rms_px=epipolar, n_points=(len(views[0][1]), len(views[1][1])),
                    cov_axis_noise=axis_covariance(n, model.e1, model.e2, cov_noise[:2, :2]),
                    cov_axis_bias_views=tuple(axis_covariance(n, model.e1, model.e2, c[:2, :2]) for c in own) or None,
                    tilt_per_px_views=tuple(tilts) or None)


def _with_subset_fit(fit: WheelFit, subset: WheelFit) -> WheelFit:
    """``fit`` combined with ``subset``, the fit without some of its points: the least expected
    squared error between the two (``toward_subset_weight``: the left-out points' bias estimated
    from how far they move the axis beyond what their noise explains, and the result moves that
    share of the way toward the fit without them; a hard choice of the smaller expected error
    would jump by the whole difference where it flips), unless they disagree beyond all they
    state (one of them is broken, say the weaker geometry without the points found another
    minimum): then the smaller stated, stating their difference."""
    if not inconsistent(fit, subset):
        return toward(fit, subset, toward_subset_weight(fit, subset))
    if np.trace(subset.cov_axis) < np.trace(fit.cov_axis):
        return with_disagreement(subset, fit)
    return with_disagreement(fit, subset)


def not_faint(steps: np.ndarray) -> np.ndarray:
    """(N,) bool: the points of a view whose edge step ``steps`` (N,) is at least
    ``FAINT_STEP_SHARE`` of the view's median step."""
    c = np.asarray(steps, float)
    return c >= FAINT_STEP_SHARE * np.median(c) if len(c) else np.ones(0, bool)


def _without_faint(fit: WheelFit, steps: list, fitted) -> WheelFit:
    """``fit``, or the fit without each view's faint points where they tilt it: points of edge
    step ``steps`` (N,), (M,) under ``FAINT_STEP_SHARE`` of the view's median (``not_faint``);
    ``fitted`` fits the circle to a (mask, mask) subset of the views' points.

    Contrast weights (``contrast_weights``) keep a faint point's say small in the final solve,
    but the tests before it are unweighted (weighted, they moved their own decisions): a faint
    arc alone in a stretch of the rim that the other view does not see can tilt the circle the
    tests judge the other arcs by, and they then leave out good arcs (one camera's shaded
    bottom arc at an eighth of the median step put a simulated wheel's camber 0.13 deg off;
    without it 0.02). Left out everywhere, the faint points take dark rims' only good arcs with
    them (a wheel 1.4 deg off). So the fit without them is a check for that gross failure only:
    it replaces the weighted fit where the faint points move the axis beyond what the fit
    without them states (``moved_beyond_subset``), stating their difference as well
    (``with_disagreement``: the fit without them may be the broken one, as on a bright tyre
    whose faint points were the flange), and elsewhere the weighted fit stands as it is.
    Weighing the two by their stated covariances (``_with_subset_fit``) instead moved sound
    wheels by 0.01-0.025 deg toward the fit without, and taking the fit without only where the
    two are ``inconsistent`` missed the gross cases, since a fit tilted by a faint arc states a
    large uncertainty too (the rules compared: docs/history/accuracy.md)."""
    bright = [not_faint(c) for c in steps]
    if all(b.all() for b in bright) or any(b.sum() < MIN_VIEW_POINTS for b in bright):
        return fit
    try:
        subset = fitted(bright)
    except (MeasurementError, np.linalg.LinAlgError, ValueError):
        return fit
    if not moved_beyond_subset(fit, subset):
        return fit
    return with_disagreement(replace(subset, faint_left_out=True), fit)

