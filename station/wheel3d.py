"""The 3-D wheel from one stereo pair: the paper's method (section 3.2) and a 3-D circle fit.

Inputs are the rim-flange edge points each camera detected (distorted pixels) and the pair's
calibrated CameraModels. Outputs are in the station frame (docs/conventions.md).

* :func:`reconstruct_paper` - exactly section 3.2: the epipolar line of each left (precision)
  rim point meets the right rim curve at two points, the one in the same order along the line
  is chosen; the top and bottom 10 % of the diameter (where the lines graze the rim) are
  pruned (Fig. 9d); points are triangulated by eq. 24; PCA of the 3-D rim gives the centre
  and the spin axis w (oriented outward from the car).
* :func:`refine_circle` - one 3-D circle (centre, normal, radius) fitted to both views' edge
  points at once by minimising their distance to the circle's projection (exact conics in
  normalised coordinates, Sampson distance scaled to pixels), robust loss; no point matching.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from calibration.camera_model import CameraModel
from calibration.triangulation import homogeneous, triangulate_paper, triangulate_paper_full
from station.blas_threads import single_thread_blas
from station.epipolar import (epipolar_tangency_px, fit_conic, pair_relation, pair_tangency, pencil_basis,
                              tangent_point_gaps_deg)
from station.errors import MeasurementError
from station.robust_lsq import soft_l1_least_squares
from station.wheel_arcs import (MIN_KEPT_FRACTION, edge_visibility, hidden_arcs, not_grazing_xy, rim_angles,
                                sector_labels, stray_arcs, stray_floor_px)
from station.wheel_fit_uncertainty import (axis_basis, axis_covariance, bias_covariance, extra_points_bias2,
                                          inconsistent, moved_beyond_subset, noise_covariance, normal_from, toward,
                                          toward_subset_weight, with_disagreement)

single_thread_blas()  # small least-squares problems: OpenBLAS threads cost 40x here (station/blas_threads.py)

PRUNE_FRACTION = 0.10  # the paper's Fig. 9d: 10 % of the diameter at the top and the bottom
INWARD_WEIGHT = 0.3    # weight of residuals inside the rim's projection in the circle fit
OCCLUSION_TEST = True    # test the arcs the tyre's sidewall could hide before trusting them (hidden_arcs)
MIN_SAFE_FRACTION = 0.2  # of a view's points that no sidewall can hide, to make the test at all
                         # (0.3 until stop 16: a reference view with 25 % safe went untested, 1.2 deg off)
SOFT_GRAZING = True       # the grazing choice as a weighted step toward the fit without them
GRAZING_TEST = True       # also fit without the points seen across the lip at a grazing angle
MIN_VIEW_POINTS = 20      # rim points a view must keep on the fitted circle
FAINT_TEST = True         # also fit without the points whose edge step is faint (_without_faint)
FAINT_STEP_SHARE = 0.2    # faint: under this share of the view's median step (the detector passes' own floor)
INWARD_ARC_PASSES = 3     # rounds of leaving out arcs whose edge strays from the fitted circle (stray_arcs)
GROSS_PX = 1.5           # a point this far (px) off the fitted circle, and GROSS_SIGMAS robust
GROSS_SIGMAS = 5.0       # sigmas, is on another contour: left out and the circle fitted again
BIAS_MODES = 2         # edge-bias Fourier modes (0: uniform, 1: + cos/sin, 2: + elongation) in the covariance


@dataclass
class WheelFit:
    """One wheel in the station frame. Shapes: center (3,), axis (3,) unit outward."""

    method: str
    center_station: np.ndarray
    axis_station: np.ndarray
    radius_m: float
    points_station: np.ndarray | None = None  # (N,3) triangulated rim (paper method)
    cov_center: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    cov_axis: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    reprojection_rms_px: float = float("nan")
    epipolar_rms_px: float = float("nan")
    n_points: tuple[int, int] = (0, 0)
    view_median_px: tuple[float, float] = (float("nan"), float("nan"))  # median |residual| per view
    calibration_share: tuple[float, float] | None = None  # traces of the calibration's (centre m^2, axis) covariance
    grazing_left_out: bool = False  # fitted without the points seen across the lip at a grazing angle
    arcs_left_out: bool = False  # arcs that do not follow the circle of the other half of the rim left out
    faint_left_out: bool = False  # fitted without the points of faint edge step (_without_faint)
    tangent_gap_deg: tuple[float, float] = (float("nan"), float("nan"))  # per view, the larger of its
    # tangent_point_gaps_deg on all its rim points: whether it saw the rim where the epipolar planes touch
    other_contour_mm: float | None = None  # some on another concentric contour, this much outside (station/other_contour.py)
    cov_axis_noise: np.ndarray | None = None  # (3,3) the part of cov_axis from the points' noise alone


# --- pair geometry ----------------------------------------------------------------------------
def line_conic_intersections(lines: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Where lines meet a conic, ordered along each line's direction (b, -a).

    lines: (N,3) homogeneous lines (a, b, c); C: (3,3). Returns (N,2,2): two points per line
    (NaN where the line misses the conic).
    """
    a, b, c = lines.T
    nrm2 = a * a + b * b
    x0 = np.stack([-a * c / nrm2, -b * c / nrm2, np.ones_like(a)], axis=1)
    u = np.stack([b, -a, np.zeros_like(a)], axis=1) / np.sqrt(nrm2)[:, None]
    A = np.einsum("ni,ij,nj->n", u, C, u)
    B = 2 * np.einsum("ni,ij,nj->n", u, C, x0)
    K = np.einsum("ni,ij,nj->n", x0, C, x0)
    disc = B * B - 4 * A * K
    with np.errstate(invalid="ignore"):
        root = np.sqrt(disc)
    s = np.stack([(-B - root) / (2 * A), (-B + root) / (2 * A)], axis=1)
    s.sort(axis=1)
    return x0[:, None, :2] + s[:, :, None] * u[:, None, :2]


def outward_sign(center_station: np.ndarray) -> float:
    """+1 for a right-hand wheel (x > 0), -1 for a left-hand one."""
    return 1.0 if center_station[0] >= 0 else -1.0


# --- the paper's method ---------------------------------------------------------------------------
def match_rim_points(xy_l: np.ndarray, xy_r: np.ndarray, R: np.ndarray, t: np.ndarray,
                     prune_fraction: float = PRUNE_FRACTION) -> tuple[np.ndarray, np.ndarray, float]:
    """Section 3.2's matching: left points -> their epipolar lines' crossings of the right rim.

    xy_l (N,2), xy_r (M,2): undistorted normalised rim points of the left and right cameras.
    R, t: the paper's pair (eqs 34-35). Returns (p_l (K,3), p_r (K,3)) matched homogeneous
    points after pruning, and the epipolar tangency residual (radians): the two epipolar planes
    tangent to the rim must be the same from both cameras; their angle differences (RMS) grow
    when a camera of the pair has moved since calibration.
    """
    C_l, C_r = fit_conic(xy_l), fit_conic(xy_r)
    p_l = homogeneous(xy_l)
    n_l = np.cross(t, p_l)                   # epipolar plane normals in the left frame (N,3)
    n_l /= np.linalg.norm(n_l, axis=1, keepdims=True)
    n_r = n_l @ R.T                          # the same planes in the right frame
    # Order of the left point among its line's two crossings of the left rim, kept on the right.
    cross_l = line_conic_intersections(n_l, C_l)
    first = np.linalg.norm(cross_l[:, 0] - xy_l, axis=1) < np.linalg.norm(cross_l[:, 1] - xy_l, axis=1)
    cross_r = line_conic_intersections(n_r, C_r)
    chosen = np.where(first[:, None], cross_r[:, 0], cross_r[:, 1])
    # Prune where the lines graze the rim: the top/bottom 10 % of the pencil of planes that cut it.
    e1, e2 = pencil_basis(t, p_l.mean(axis=0))
    theta = np.arctan(np.einsum("ni,i->n", n_l, e2) / np.einsum("ni,i->n", n_l, e1))
    (lo_l, hi_l), tangency = pair_tangency(C_l, C_r, R, e1, e2)
    span = hi_l - lo_l
    keep = (theta > lo_l + prune_fraction * span) & (theta < hi_l - prune_fraction * span)
    keep &= np.all(np.isfinite(chosen), axis=1)
    return p_l[keep], homogeneous(chosen[keep]), tangency


def reconstruct_paper(points_l_px: np.ndarray, points_r_px: np.ndarray, cam_l: CameraModel,
                      cam_r: CameraModel) -> WheelFit:
    """The paper's 3-D wheel: match, prune, triangulate (eq. 24), PCA. Station frame."""
    xy_l = cam_l.pixels_to_normalized(points_l_px)
    xy_r = cam_r.pixels_to_normalized(points_r_px)
    R, t = pair_relation(cam_l, cam_r)
    p_l, p_r, tangency = match_rim_points(xy_l, xy_r, R, t)
    if len(p_l) < 20:
        raise MeasurementError(f"{cam_l.name}/{cam_r.name}: only {len(p_l)} rim points could be matched")
    X_l = triangulate_paper(p_l, p_r, R, t)
    X = (X_l - cam_l.t_cam_station) @ cam_l.R_cam_station  # left frame -> station, (N,3)
    center = X.mean(axis=0)
    _, sv, Vt = np.linalg.svd(X - center, full_matrices=False)
    w = Vt[2]
    if w[0] * outward_sign(center) < 0:
        w = -w
    radius = float(np.mean(np.linalg.norm((X - center) - np.outer((X - center) @ w, w), axis=1)))
    f = 0.5 * (cam_l.K[0, 0] + cam_r.K[0, 0])
    # A plane-angle error d moves a rim point across its epipolar line by about f * d pixels
    # (the rays to the wheel are roughly perpendicular to the baseline).
    return WheelFit("paper", center, w, radius, points_station=X, epipolar_rms_px=tangency * f,
                    n_points=(len(points_l_px), len(points_r_px)))


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


# --- the 3-D circle fit -------------------------------------------------------------------------
def circle_conic(center_cam: np.ndarray, normal_cam: np.ndarray, radius: float) -> np.ndarray:
    """(3,3) conic of a 3-D circle's image in normalised coordinates (camera frame inputs).

    Points X = lambda x on the cone through the circle satisfy
    (n.c)^2 x.x - 2 (n.c)(n.x)(c.x) + (c.c - r^2)(n.x)^2 = 0.
    """
    return circle_conics(center_cam[None], normal_cam[None], np.array([radius], float))[0]


def circle_conics(center_cam: np.ndarray, normal_cam: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(K,3,3) :func:`circle_conic` of K circles at once: centres (K,3), normals (K,3), radii (K,)."""
    c, n = center_cam, normal_cam
    nc = np.einsum("ki,ki->k", n, c)[:, None, None]
    nn = n[:, :, None] * n[:, None, :]
    nc_outer = n[:, :, None] * c[:, None, :]
    cc_rr = (np.einsum("ki,ki->k", c, c) - radius * radius)[:, None, None]
    return nc * nc * np.eye(3) - nc * (nc_outer + np.swapaxes(nc_outer, 1, 2)) + cc_rr * nn


def sampson_jacobian(C: np.ndarray, dC: np.ndarray, X: np.ndarray, focal_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Sampson distances (N,) px of homogeneous points X (N,3) to the conic C (3,3), and their
    derivatives (N,K) along K conic directions dC (K,3,3): s = f F / G with F = x'Cx and
    G = 2 |(Cx)_12|, so ds = f (dF G - F dG) / G^2, dF = x' dC x, dG = 2 g.(dC x)_12 / |g|.
    One (N,3) x (3,3(K+1)) product for all of them."""
    K = len(dC)
    Y = (X @ np.concatenate([C, *dC], axis=1)).reshape(len(X), K + 1, 3)   # C and dC symmetric
    CX, dCX = Y[:, 0], Y[:, 1:]
    F = np.einsum("ni,ni->n", CX, X)
    dF = np.einsum("nki,ni->nk", dCX, X)
    g = np.hypot(CX[:, 0], CX[:, 1])
    dG = 2 * (dCX[:, :, 0] * CX[:, :1] + dCX[:, :, 1] * CX[:, 1:2]) / g[:, None]
    G = 2 * g
    return focal_px * F / G, focal_px * (dF * G[:, None] - F[:, None] * dG) / (G * G)[:, None]


def sampson_px(C: np.ndarray, xy: np.ndarray, focal_px: float) -> np.ndarray:
    """(N,) first-order geometric distance (px) of normalised points (N,2), or the same points
    already homogeneous (N,3) (a fit calls this hundreds of times on the same points), to the conic C."""
    X = xy if xy.shape[1] == 3 else homogeneous(xy)
    CX = X @ C
    f = np.einsum("ni,ni->n", CX, X)
    grad = 2 * np.hypot(CX[:, 0], CX[:, 1])
    return focal_px * f / grad


def _sector_jackknife(residuals, x, views, n0, e1, e2, n_sectors: int, loss_scale_px: float) -> np.ndarray:
    """Block-jackknife covariance (6,6) of the circle parameters, leaving out one rim sector at a time."""
    c = x[2:5]
    n = normal_from(x[:2], n0, e1, e2)
    labels = [sector_labels(rim_angles(cam, xy, c, n), n_sectors) for cam, xy, *_ in views]
    estimates = []
    for k in range(n_sectors):
        keep = [lab != k for lab in labels]
        sol = least_squares(lambda p: residuals(p, keep), x, loss="soft_l1", f_scale=loss_scale_px,
                            x_scale="jac", method="trf", max_nfev=6)  # warm start: a few steps suffice
        estimates.append(sol.x)
    est = np.array(estimates)
    dev = est - est.mean(axis=0)
    return (n_sectors - 1) / n_sectors * dev.T @ dev


def tangent_gaps(xy_l: np.ndarray, xy_r: np.ndarray, cam_l: CameraModel, cam_r: CameraModel) -> tuple[float, float]:
    """Per view, the larger of its ``tangent_point_gaps_deg`` (NaN where they cannot be found)."""
    try:
        g = tangent_point_gaps_deg(xy_l, xy_r, cam_l, cam_r)
        return float(np.max(g[:2])), float(np.max(g[2:]))
    except (np.linalg.LinAlgError, ValueError):
        return float("nan"), float("nan")


def refine_circle(points_l_px: np.ndarray, points_r_px: np.ndarray, cam_l: CameraModel,
                  cam_r: CameraModel, init: WheelFit, loss_scale_px: float = 0.3,
                  visibility_margin: float | None = None, jackknife_sectors: int = 0,
                  inward_weight: float = INWARD_WEIGHT, bias_modes: int = BIAS_MODES,
                  occlusion_test: bool = OCCLUSION_TEST, init_is_fitted: bool = False,
                  grazing_test: bool = GRAZING_TEST, contrast: tuple | None = None,
                  faint_test: bool | None = None) -> WheelFit:
    """Fit one 3-D circle to both views' rim points by minimising image distance (px).

    ``contrast``: per view, each point's edge step (grey levels, (N,) and (M,), as
    :class:`station.rim.RimDetection` gives them) or None. A point's residual is then weighted
    by :func:`contrast_weights`: an edge's position is as uncertain as its noise over its step,
    and a faint stretch of the flange edge is also where a nearby stronger edge (a shaded tyre
    bead) pulls the sub-pixel point off it. The weights enter the final solve, on the points
    the tests below kept; the tests and the solves before it are unweighted.

    Residuals of points inside the circle's projection count ``inward_weight`` times (1: a
    symmetric fit): the tyre bulge and a lip shaded as dark as the tyre hide the flange edge
    on whole arcs of an oblique view, and then the edge the detector finds lies inside it.

    The covariance is (a) the Jacobian's, inflated by the residuals' correlation along the rim,
    plus (b) slowly varying edge biases (:func:`bias_covariance`, Fourier modes up to
    ``bias_modes`` of the rim angle; 0 skips it). Optionally (``jackknife_sectors`` > 0) the
    larger of that and a block jackknife over sectors of the rim (the same physical sector left
    out of both views in turn); docs/accuracy.md compares the two against the observed errors.

    Points where the tyre's sidewall may hide the flange edge (:func:`edge_visibility` below
    ``visibility_margin``) are left out; None keeps every point.

    ``occlusion_test`` (default): arcs that the sidewall *could* hide are tested instead of
    trusted (:func:`hidden_arcs`): the circle is first fitted to the points that no sidewall
    can hide, and an arc of doubtful points whose edge lies inside that circle's projection
    beyond the noise is left out of the final fit; arcs that agree are kept.
    ``init_is_fitted``: ``init`` is already a circle fitted this way (``station live``'s previous
    frame): the test is made against it, without the first fit.

    ``faint_test`` (None: ``FAINT_TEST``): with ``contrast``, the circle is also fitted without
    each view's faint points, and that fit is taken where they move the axis beyond what it
    states (:func:`_without_faint`).
    """
    xys, ws, steps = [], [], []
    for cam, pts, con in zip((cam_l, cam_r), (points_l_px, points_r_px), contrast or (None, None)):
        xy = cam.pixels_to_normalized(pts)
        w = None if con is None else contrast_weights(con)
        keep = np.all(np.isfinite(xy), axis=1)
        if visibility_margin is not None:
            keep[keep] = edge_visibility(cam, xy[keep], init) > visibility_margin
        xys.append(xy[keep])
        ws.append(_subset(w, keep))
        steps.append(None if con is None else np.asarray(con, float)[keep])

    def fitted(keep=(None, None)):
        return _fit_circle(*(xy if k is None else xy[k] for xy, k in zip(xys, keep)),
                           *(w if k is None else _subset(w, k) for w, k in zip(ws, keep)), cam_l, cam_r, init,
                           loss_scale_px, jackknife_sectors, inward_weight, bias_modes, occlusion_test,
                           init_is_fitted, grazing_test)

    fit = fitted()
    if (FAINT_TEST if faint_test is None else faint_test) and all(c is not None for c in steps):
        fit = _without_faint(fit, steps, fitted)
    # on every point the cameras found: did they see the rim where the epipolar planes touch it?
    return replace(fit, tangent_gap_deg=tangent_gaps(xys[0], xys[1], cam_l, cam_r))


MIN_CONTRAST_WEIGHT = 0.05  # a weight never reaches 0: the residual divided by it gives px again


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


def _fit_circle(xy_l: np.ndarray, xy_r: np.ndarray, w_l: np.ndarray | None, w_r: np.ndarray | None,
                cam_l: CameraModel, cam_r: CameraModel, init: WheelFit, loss_scale_px: float, jackknife_sectors: int,
                inward_weight: float, bias_modes: int, occlusion_test: bool, init_is_fitted: bool,
                grazing_test: bool) -> WheelFit:
    """:func:`refine_circle` on the views' undistorted normalised points (N,2), (M,2) and their
    residual weights (N,), (M,) (None: all 1)."""
    # views: (camera, points (N,2), focal px, residual weights (N,)), subset together below
    views = [(cam, xy, 0.5 * (cam.K[0, 0] + cam.K[1, 1]), np.ones(len(xy)) if w is None else w)
             for cam, xy, w in ((cam_l, xy_l, w_l), (cam_r, xy_r, w_r))]
    n_input = sum(len(v[1]) for v in views)
    n0, e1, e2 = axis_basis(init.axis_station)

    def homogeneous_views(keep=None, weighted=True):
        return [(cam, homogeneous(xy), f, w if weighted else np.ones(len(xy))) if keep is None else
                (cam, homogeneous(xy[keep[k]]), f, w[keep[k]] if weighted else np.ones(int(np.sum(keep[k]))))
                for k, (cam, xy, f, w) in enumerate(views)]

    def raw_residuals(p, keep=None, hviews=None):
        """(N,) distances (px) of the points to the circle's projections, unweighted."""
        c = p[2:5]
        n = normal_from(p[:2], n0, e1, e2)
        out = []
        for cam, X, f, _ in hviews or homogeneous_views(keep):
            C = circle_conic(cam.R_cam_station @ c + cam.t_cam_station, cam.R_cam_station @ n, p[5])
            out.append(sampson_px(C, X, f))
        return np.concatenate(out)

    def residuals(p, keep=None, hviews=None):
        hviews = hviews or homogeneous_views(keep)
        r = raw_residuals(p, hviews=hviews)
        # an edge seen inside the rim's projection is more likely a hidden or shaded flange
        # (tyre bulge, dark lip) than a real one: occlusion only ever moves the edge inward
        # beyond the noise (loss_scale_px) only; within it the fit stays unbiased
        return np.concatenate([v[3] for v in hviews]) * \
            np.where(r < -loss_scale_px, inward_weight * (r + loss_scale_px) - loss_scale_px, r)

    def per_view(values):
        """A stacked (N,) array over the current views -> one array per view."""
        return np.split(values, np.cumsum([len(v[1]) for v in views])[:-1])

    def residuals_and_jacobian(p, hviews):
        """:func:`residuals` (N,) and their derivatives (N,6) d residuals / d p: the six conic
        derivatives by central differences (the conic is a low-order polynomial of p: exact to
        ~1e-10), the points' part analytic."""
        h = 1e-6 * np.maximum(1.0, np.abs(p))
        P = np.vstack([p, p + np.diag(h), p - np.diag(h)])                  # (13,6)
        n = n0 + P[:, :1] * e1 + P[:, 1:2] * e2
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        raw, J = [], []
        for cam, X, f, _ in hviews:
            C = circle_conics(P[:, 2:5] @ cam.R_cam_station.T + cam.t_cam_station, n @ cam.R_cam_station.T, P[:, 5])
            r_k, J_k = sampson_jacobian(C[0], (C[1:7] - C[7:]) / (2 * h)[:, None, None], X, f)
            raw.append(r_k)
            J.append(J_k)
        r = np.concatenate(raw)
        w = np.concatenate([v[3] for v in hviews])
        inward = r < -loss_scale_px
        return (w * np.where(inward, inward_weight * (r + loss_scale_px) - loss_scale_px, r),
                np.vstack(J) * (w * np.where(inward, inward_weight, 1.0))[:, None])

    def solve(x0, keep=None, weighted=False):  # (weighted: the last solve, below)
        hviews = homogeneous_views(keep, weighted)
        return soft_l1_least_squares(lambda p: residuals_and_jacobian(p, hviews), x0, f_scale=loss_scale_px)

    x0 = np.concatenate([[0.0, 0.0], init.center_station, [init.radius_m]])
    doubtful = False
    if occlusion_test:
        vis = [edge_visibility(cam, xy, init) for cam, xy, *_ in views]
        safe = [v >= 0.0 for v in vis]
        if all(k.sum() >= MIN_SAFE_FRACTION * len(k) for k in safe):
            # every other safe point: the test needs the circle to a tenth of a pixel, not better
            # (or ``init`` itself when it is such a circle: the last live frame's)
            x_safe = x0 if init_is_fitted else solve(x0, [k & (np.arange(len(k)) % 2 == 0) for k in safe]).x
            r_all = per_view(raw_residuals(x_safe))
            c_safe, n_safe = x_safe[2:5], normal_from(x_safe[:2], n0, e1, e2)
            keeps = [hidden_arcs(r, k, rim_angles(cam, xy, c_safe, n_safe), loss_scale_px)
                     for r, k, (cam, xy, *_) in zip(r_all, safe, views)]
            # leaving out more than half of a view is either a camera that sees little of the
            # flange past the sidewall or a test judged against a circle extrapolated from
            # narrow safe arcs: fit it both ways below and keep the better-determined axis
            doubtful = not all(k.sum() >= MIN_KEPT_FRACTION * len(k) for k in keeps)
            views = [(cam, xy[k], f, w[k]) for (cam, xy, f, w), k in zip(views, keeps)]
            x0 = x_safe
    sol = solve(x0)
    # points far off the circle in either view are another contour (a lip's inner edge taken
    # for the flange where the flange is shaded as dark as the tyre: in one view the union of
    # the two is itself an ellipse, only the other view shows it): leave them out, fit again
    r = raw_residuals(sol.x)
    sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    far = np.abs(r) > max(GROSS_PX, GROSS_SIGMAS * sigma)
    if far.any():
        views = [(cam, xy[~out], f, w[~out]) for (cam, xy, f, w), out in zip(views, per_view(far))]
        for cam, xy, *_ in views:  # a view with (almost) nothing on the circle: no 3-D rim
            if len(xy) < MIN_VIEW_POINTS:
                raise MeasurementError(f"{cam.name}: only {len(xy)} of its rim points lie on the 3-D circle "
                                       "the pair's points agree on", hint="the two cameras may have found different rims")
        sol = solve(sol.x)
    # arcs biased inward that neither test above caught (an edge moved over a whole arc by
    # shading or a hidden flange on the side no sidewall model expects), or outward (a lit
    # bead wall taken for metal): leave them out and fit again, a few rounds, never leaving a
    # view under MIN_KEPT_FRACTION of its points
    n_start = [len(v[1]) for v in views]
    for _ in range(INWARD_ARC_PASSES):
        c_now, n_now = sol.x[2:5], normal_from(sol.x[:2], n0, e1, e2)
        keeps = []
        for r_v, (cam, xy, *_), n_v in zip(per_view(raw_residuals(sol.x)), views, n_start):
            phi_v = rim_angles(cam, xy, c_now, n_now)
            keep = ~stray_arcs(r_v, phi_v, stray_floor_px(r_v, phi_v, loss_scale_px))
            keeps.append(keep if keep.sum() >= MIN_KEPT_FRACTION * n_v else np.ones(len(xy), bool))
        if all(k.all() for k in keeps):
            break
        views = [(cam, xy[k], f, w[k]) for (cam, xy, f, w), k in zip(views, keeps)]
        sol = solve(sol.x)
    # the points' weights (their edge steps) enter the last solve only, on the points every
    # test above kept: weighted, the earlier solves moved those decisions (which arcs stay,
    # which runner-up pairs), and on harsh-light vehicles wheels came out 1.5 deg off
    if not all(np.all(v[3] == 1.0) for v in views):
        sol = solve(sol.x, weighted=True)
    r = sol.fun / np.concatenate([v[3] for v in views])  # px again (weights are > 0)
    cov_p, inlier = noise_covariance(sol, views)
    if cov_p is None:
        cov_p = np.full((6, 6), np.nan)
    if jackknife_sectors:
        cov_jk = _sector_jackknife(residuals, sol.x, views, n0, e1, e2, jackknife_sectors, loss_scale_px)
        if np.trace(cov_jk[:2, :2]) > np.trace(cov_p[:2, :2]):
            cov_p = cov_jk
    cov_noise = cov_p  # the points' noise (or the sector jackknife's, where it replaced it)
    if bias_modes:
        cov_p = cov_p + bias_covariance(sol, views, n0, e1, e2, bias_modes)
    # the pair's epipolar check on the points the circle was fitted to: an arc left out above
    # (hidden, another contour) would otherwise move a tangent plane of its view's ellipse
    epipolar = init.epipolar_rms_px
    if sum(len(v[1]) for v in views) < n_input:
        try:
            epipolar = epipolar_tangency_px(views[0][1], views[1][1], cam_l, cam_r)
        except (MeasurementError, np.linalg.LinAlgError, ValueError):
            pass
    n = normal_from(sol.x[:2], n0, e1, e2)
    if n[0] * outward_sign(sol.x[2:5]) < 0:
        n = -n
    cov_axis = axis_covariance(n, e1, e2, cov_p[:2, :2])
    medians = tuple(float(np.median(np.abs(res))) if len(res) else float("inf") for res in per_view(r))
    fit = WheelFit("circle", sol.x[2:5].copy(), n, float(sol.x[5]), view_median_px=medians,
                    cov_center=cov_p[2:5, 2:5], cov_axis=cov_axis,
                    reprojection_rms_px=float(np.sqrt(np.mean(r[inlier] ** 2))) if inlier.any() else float("nan"),
                    epipolar_rms_px=epipolar, n_points=(len(views[0][1]), len(views[1][1])),
                    cov_axis_noise=axis_covariance(n, e1, e2, cov_noise[:2, :2]))
    if doubtful:
        plain = _fit_circle(xy_l, xy_r, w_l, w_r, cam_l, cam_r, init, loss_scale_px, jackknife_sectors,
                            inward_weight, bias_modes, occlusion_test=False, init_is_fitted=init_is_fitted,
                            grazing_test=False)
        if np.trace(plain.cov_axis) < np.trace(fit.cov_axis):
            fit = plain
    if grazing_test:
        keep_l, keep_r = not_grazing_xy(fit, xy_l, xy_r, cam_l, cam_r)
        if not (keep_l.all() and keep_r.all()):
            # the fit without the grazing points, made from ``init`` as this one was (from
            # ``fit``, the sidewall test would be judged against a circle they had shaped)
            alt = _fit_circle(xy_l[keep_l], xy_r[keep_r], _subset(w_l, keep_l), _subset(w_r, keep_r), cam_l, cam_r,
                              init, loss_scale_px, jackknife_sectors, inward_weight, bias_modes, occlusion_test,
                              init_is_fitted, grazing_test=False)
            # the least expected squared error between the two: the grazing points' bias is
            # estimated from how far they move the axis beyond what their noise explains, and
            # the result moves that share of the way toward the fit without them (SOFT_GRAZING;
            # else the smaller expected error is chosen, a jump of the whole difference where
            # the choice flips); unless the two fits disagree beyond all they state (one of
            # them is broken, say the weaker geometry without them found another minimum):
            # the smaller stated then, stating their difference
            fit = _with_subset_fit(fit, replace(alt, grazing_left_out=True))
    return fit


def _with_subset_fit(fit: WheelFit, subset: WheelFit) -> WheelFit:
    """``fit`` combined with ``subset``, the fit without some of its points: the least expected
    squared error between the two (``toward_subset_weight``: the left-out points' bias estimated
    from how far they move the axis beyond what their noise explains; with ``SOFT_GRAZING`` off,
    the smaller expected error, a jump where the choice flips), unless they disagree beyond all
    they state (one of them is broken, say the weaker geometry without the points found another
    minimum): then the smaller stated, stating their difference."""
    if not inconsistent(fit, subset):
        return toward(fit, subset, toward_subset_weight(fit, subset) if SOFT_GRAZING else
                      float(np.trace(subset.cov_axis) < np.trace(fit.cov_axis) + extra_points_bias2(fit, subset)))
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
    tests judge the other arcs by, and they then leave out good arcs (simulated 1121 RL: one
    camera's shaded bottom arc at an eighth of the median step, camber 0.13 deg off; without
    it 0.02). Left out everywhere, the faint points take dark rims' only good arcs with them
    (6001 RL 1.4 deg off). So the fit without them is a check for that gross failure only: it
    replaces the weighted fit where the faint points move the axis beyond what the fit without
    them states (``moved_beyond_subset``), stating their difference as well
    (``with_disagreement``: the fit without them may be the broken one, as on a bright tyre
    whose faint points were the flange), and elsewhere the weighted fit stands as it is.
    (Weighed by their stated covariances instead, ``_with_subset_fit``, the two moved sound
    wheels by 0.01-0.025 deg toward the fit without: 1115 FL 0.017 -> 0.042 deg with one
    calibration. Only where the two were ``inconsistent``, it missed the gross cases: a fit
    tilted by a faint arc also states a large uncertainty.)"""
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
