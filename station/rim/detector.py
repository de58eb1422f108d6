"""The rim detector: the whole pipeline, candidate scoring and the choice of "the rim".

Stages (paper section 3.1, made industrial; docs/rim-detection.md):

1. grey by eq. 36 (``preprocess.to_grey``), sanity checks (black / saturated / flat image);
2. a coarse image (larger side <= 440 px), CLAHE equalisation, Canny with thresholds from the
   image's own gradient distribution (``edges``);
3. lens-distortion correction of the edge points when a camera model is given (``PixelMap``);
4. the three-stage ellipse Hough vote (``hough``): centres from polarity-consistent chord
   midpoints, the shape from one linear solve, the sizes from a 1-D histogram;
5. the choice of the rim among the candidates (``choice``): closure (coverage of the
   perimeter by bright-inside edges), a dark tyre band just outside, a concentric tyre
   outline further out;
6. sub-pixel edge points along the normals of the chosen ellipse in the full-resolution
   original image (``subpixel``), twice, each followed by the robust geometric fit
   (``ellipse_fit``) that gives the ellipse, its covariance and the inliers.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from station.compute.bounded_cache import BoundedCache
from station.errors import RimNotFound
from station.rim import edges as edges_mod
from station.rim import hough
from station.rim.choice import DARK_RIM_NOTE, choose
from station.rim.ellipse import Ellipse
from station.rim.ellipse_fit import fit_direct, fit_geometric, ransac_ellipse
from station.rim.exposure import check_exposure
from station.rim.metal_side import dark_side_share
from station.rim.npfast import finite_rows, median, rows, sector_medians
from station.rim.preprocess import PixelMap, detection_scale, downscale, equalize, noise_grey, to_grey
from station.rim.subpixel import WIDE_BLUR_PX, edge_points, repositioned, step_modulation, window_scale
from station.rim.white_edge import white_share


MIN_REFINED_COVERAGE = 0.35  # the chosen rim's sub-pixel edge may be partly hidden (wheel arch,
                             # tyre bulge in oblique views): the 3-D fit works on arcs
MIN_POINTS = 32


@dataclass
class RimDetection:
    """The rim flange edge found in one image.

    ellipse: the rim ellipse, in image pixels; when a camera model with distortion was given,
        in *ideal pinhole pixels* of that camera (same K, distortion removed), where the rim
        is an exact ellipse (``ellipse_frame`` says which).
    points_px: (N,2) sub-pixel inlier edge points on the flange edge, ORIGINAL (distorted) pixels.
    points_norm: (N,2) the same points in undistorted normalised coordinates (camera given), else None.
    score: 0..1; ellipse_cov: (5,5) covariance of (cx, cy, a, b, angle) in px^2 / rad^2;
    point_sigma_px: robust rms distance of the inliers to the fit; timing_s: seconds per stage.
    points_contrast: (N,) each point's edge step (grey levels), for weighting the points.
    """

    ellipse: Ellipse
    points_px: np.ndarray
    score: float
    ellipse_cov: np.ndarray
    point_sigma_px: float
    timing_s: dict
    camera_id: str = ""
    points_norm: np.ndarray | None = None
    ellipse_frame: str = "pixels"
    coverage: float = 0.0
    contrast: float = 0.0
    details: dict = field(default_factory=dict)
    points_contrast: np.ndarray | None = None

    def to_dict(self) -> dict:
        return {
            "camera_id": self.camera_id,
            "ellipse": {**self.ellipse.to_dict(), "frame": self.ellipse_frame},
            "score": round(float(self.score), 4),
            "coverage": round(float(self.coverage), 4),
            "contrast_grey": round(float(self.contrast), 2),
            "n_points": int(len(self.points_px)),
            "point_sigma_px": float(self.point_sigma_px),
            "white_share": round(float(self.details.get("white_share", 0.0)), 4),
            "metal_side_dark_share": round(float(self.details.get("metal_side_dark_share", 0.0)), 4),
            "ellipse_std": dict(zip(("cx_px", "cy_px", "a_px", "b_px", "angle_deg"),
                                    [float(x) for x in np.sqrt(np.maximum(np.diag(self.ellipse_cov), 0))
                                     * np.array([1, 1, 1, 1, 180 / np.pi])])),
            "timing_ms": {k: round(v * 1e3, 2) for k, v in self.timing_s.items()},
        }


class _Clock:
    def __init__(self):
        self.t = time.perf_counter()
        self.stages: dict[str, float] = {}

    def lap(self, name: str):
        now = time.perf_counter()
        self.stages[name] = self.stages.get(name, 0.0) + now - self.t
        self.t = now


_TABLES = BoundedCache(16)  # per camera and image size


def _ideal_table(pmap: PixelMap, shape: tuple[int, int], s: int) -> np.ndarray:
    """(h,w,2) ideal coarse-pixel coordinates of every coarse pixel centre of a camera, cached
    (the cameras of a station do not change between cycles; the Newton undistortion of ~10^4
    edge points per image would otherwise cost more than the Hough vote)."""
    cam = pmap.camera
    key = (cam.K.tobytes(), cam.dist.tobytes(), shape, s)

    def make():
        h, w = shape
        vv, uu = np.mgrid[0:h, 0:w].astype(float)
        coarse = np.stack([uu.ravel(), vv.ravel()], axis=1)
        full = (coarse + 0.5) * s - 0.5
        # OpenCV's iterative undistortion: 3x faster than the exact Newton of CameraModel on
        # 3e5 points, within 1e-9 px of it here, and the Hough works on coarse pixels anyway
        ideal = cv2.undistortPoints(full.reshape(-1, 1, 2), cam.K, cam.dist, None, cam.K,
                                    criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-10))
        return ((ideal.reshape(-1, 2) + 0.5) / s - 0.5).reshape(h, w, 2)

    return _TABLES.get(key, make)


class _Scene:
    """The coarse image, its edges and the mapping between coarse, full and ideal pixels."""

    def __init__(self, grey: np.ndarray, pmap: PixelMap, equalization: str):
        self.grey = grey
        self.pmap = pmap
        self.s = detection_scale(grey.shape)
        self.coarse = downscale(grey, self.s)
        u8 = np.clip(self.coarse + 0.5, 0, 255).astype(np.uint8)
        self.edges = edges_mod.detect_edges(equalize(u8, equalization))
        if not pmap.identity:  # move the edge points to ideal pixels (coarse scale)
            table = _ideal_table(pmap, self.coarse.shape, self.s)
            iv = self.edges.points[:, 1].astype(np.int64)
            iu = self.edges.points[:, 0].astype(np.int64)
            # Canny pixels sit on the coarse grid: a lookup (table[iv, iu], by rows: 7x faster)
            ideal = rows(table.reshape(-1, 2), iv * table.shape[1] + iu)
            good = finite_rows(ideal)
            self.edges = self.edges.subset(good)
            self.edges.points = rows(ideal, good)

    def to_full(self, p):
        return (p + 0.5) * self.s - 0.5

    def to_coarse(self, p):
        return (p + 0.5) / self.s - 0.5

    def sample_coarse(self, pts_ideal_coarse: np.ndarray) -> np.ndarray:
        """Bilinear coarse-image grey at ideal coarse points (N,2) (NaN outside)."""
        p = self.pmap.distort(self.to_full(pts_ideal_coarse))
        p = self.to_coarse(p)
        h, w = self.coarse.shape
        ok = finite_rows(p) & (p[:, 0] >= 0) & (p[:, 0] <= w - 1.001) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1.001)
        out = np.full(len(p), np.nan)
        u, v = p[:, 0][ok], p[:, 1][ok]
        u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
        fu, fv = u - u0, v - v0
        c = self.coarse.ravel()  # the four neighbours by flat index (2-D fancy indexing is slow)
        i = v0 * w + u0
        out[ok] = ((1 - fu) * (1 - fv) * c[i] + fu * (1 - fv) * c[i + 1]
                   + (1 - fu) * fv * c[i + w] + fu * fv * c[i + w + 1])
        return out


PASSES = (((-6.0, 6.0), "kink"), ((-3.0, 4.5), "kink"))
PRIOR_PASSES = (((-10.0, 10.0), "peak"), ((-5.0, 5.0), "erf"), ((-3.0, 4.5), "kink"))
TRACK_PASSES = (((-3.0, 4.5), "kink"),)  # a prior from the previous frame, the blur known
GATE_PX, GATE_SIGMAS = 1.5, 5.0         # a later pass's points off the earlier pass's ellipse
                                         # by more are on another contour (faint tyre shading
                                         # where the flange edge has no contrast)
TRACK_SHIFT = 0.03                       # of the semi-major axis: tracking lost beyond this
RESCUE_MISFIT_GREY = 2.0  # a search whose edge holds on too little of the rim is refined once more with
                          # the profiles' misfit test at least as tolerant as in one frame's noise (grey
                          # levels): in an 8-frame mean (median misfit 0.7) the profiles a harsh lamp's
                          # glare bends 2-3 levels off the model fail 3x the median, and 1 of 30
                          # harsh-light cycles was refused for coverage (32 %); rescued, none is, and no
                          # other set changes. Tolerating them everywhere put ordinary rims' camber
                          # 0.0094 -> 0.0103 deg RMS: their misfitting profiles are biased
                          # (docs/history/accuracy.md)
SAME_CONTOUR_PX = 0.2  # a point this near the fitted ellipse is an inlier whatever the noise: its
                       # offset is the edge's own bias (lighting, lip), not another contour. Without
                       # it, in an 8-frame mean (points 0.04 px apart from the fit) 3.5 sigma left
                       # out the arcs a harsh lamp biases by 0.2 px, and 4 of 30 harsh-light cycles
                       # failed for coverage (1 with it; single frames: the same results)


def _consensus_threshold(d: np.ndarray) -> float:
    """RANSAC threshold (px) from the points' own noise: 3 sigma, sigma from the second
    differences of the offsets d (N,) of neighbouring points along the curve (any smooth
    model error cancels), so that a compromise between two concentric edges, which passes
    within a pixel or so of both, does not win the consensus."""
    dd = np.diff(d, 2)
    sigma = 1.4826 * median(np.abs(dd - median(dd))) / np.sqrt(6.0)
    return float(np.clip(3.0 * sigma, 0.25, 1.5))


def _scaled(window: tuple[float, float], f: float) -> tuple[float, float]:
    return (window[0] * f, window[1] * f)


def _refine(grey: np.ndarray, e_full: Ellipse, pmap: PixelMap, passes=PASSES, blur_px: float | None = None,
            tracking: bool = False, misfit_floor: float = 0.0):
    """Sub-pixel points and geometric fit, once per (half-width, method) pass; ``blur_px``
    fixes the edge blur instead of estimating it. ``tracking`` (the prior is last frame's
    sub-pixel ellipse): profiles 2.5 px apart, and the robust fit starts from the prior
    without a consensus search. Returns (fit, samples, inlier mask, blur px)."""
    fit = samples = None
    e = e_full
    sigma = None  # the edge blur, estimated in each pass (unless blur_px)
    for k, (window, method) in enumerate(passes):
        final = k == len(passes) - 1
        spacing = (2.5 if tracking else 1.5) if final else 3.0
        known = window_scale(blur_px if blur_px is not None else sigma)  # the blur found so far
        samples, blur = edge_points(grey, e, pmap, window_px=_scaled(window, known), method=method,
                                    spacing_px=spacing, sigma=blur_px, blur_hint=sigma, misfit_floor=misfit_floor)
        if method == "kink" and window_scale(blur) > known:  # a soft edge: sampled again, as wide as it needs
            samples, _ = edge_points(grey, e, pmap, window_px=_scaled(window, window_scale(blur)), method=method,
                                     spacing_px=spacing, sigma=blur, misfit_floor=misfit_floor)
        sigma = blur if blur is not None else sigma
        ok = samples.ok
        if ok.sum() < MIN_POINTS:
            return None, samples, ok, sigma
        ideal = pmap.undistort(rows(samples.points_px, ok))
        d_prev = None if tracking and fit is None else e.distance(ideal)[0]  # (tracking needs neither use)
        if fit is not None:  # a later pass: its edge is the curve the earlier pass fitted
            near = np.abs(d_prev) <= max(GATE_PX, GATE_SIGMAS * fit.sigma_px)
            ok[np.nonzero(ok)[0][~near]] = False
            if ok.sum() < MIN_POINTS:
                return None, samples, ok, sigma
            ideal, d_prev = rows(ideal, near), d_prev[near]
        # one curve, not a compromise between concentric edges: consensus first, then the
        # robust fit of ALL points from the consensus ellipse (a tight consensus band alone
        # would bias the fit toward the minimal sample that defined it)
        keep = None if tracking else ransac_ellipse(ideal, threshold_px=_consensus_threshold(d_prev),
                                                     seed=len(ideal))
        if not tracking and (keep is None or keep.sum() < MIN_POINTS):
            return None, samples, ok, sigma
        try:
            e_cons = e if tracking else fit_direct(rows(ideal, keep))
            fit = fit_geometric(ideal, init=e_cons, iterations=12 if final else 5, reject_floor_px=SAME_CONTOUR_PX)
        except (ValueError, np.linalg.LinAlgError):
            return None, samples, ok, sigma
        e = fit.ellipse
        ok_idx = np.nonzero(ok)[0]
        ok[ok_idx[~fit.inliers]] = False
        samples.ok = ok
    return fit, samples, samples.ok.copy(), sigma


def detect_rim(image: np.ndarray, *, camera=None, prior: Ellipse | None = None, camera_id: str = "",
               equalization: str = "clahe", previous: RimDetection | None = None) -> RimDetection:
    """Find the rim-flange ellipse in one image. See :class:`RimDetection`; raises
    :class:`station.errors.RimNotFound` (or ImageError for an unusable array) with a reason.

    image: (H,W) uint8/uint16 grey or (H,W,3) BGR. camera: optional CameraModel; with lens
    distortion the returned ellipse is in its ideal pinhole pixels (``ellipse_frame``) and
    ``points_norm`` are the points' undistorted normalised coordinates. prior: an Ellipse in
    the same frame as the result (e.g. last cycle's) to refine from; never required.
    equalization: "clahe" (default), "global" (the paper's), "none" - for the Canny stage only.
    previous: this camera's detection in the previous frame (station live): tracking, one
    sub-pixel pass from its ellipse with its edge blur; when the rim moved more than
    ``TRACK_SHIFT`` of its size or lost coverage, the prior path (from its ellipse) and then
    the search take over."""
    tag = camera_id or "image"
    clock = _Clock()
    grey = to_grey(image, camera_id)
    check_exposure(grey, tag)
    pmap = PixelMap(camera)
    clock.lap("grey")
    fit = None
    info: dict = {}
    if previous is not None and previous.details.get("blur_px"):  # tracking: one pass, the blur known
        prior = previous.ellipse
        fit, samples, mask, blur = _refine(grey, prior, pmap, passes=TRACK_PASSES, blur_px=previous.details["blur_px"],
                                           tracking=True)
        if fit is not None and not _holds(fit, samples, mask, prior, TRACK_SHIFT, min(0.8, 0.9 * previous.coverage)):
            fit = None
        if fit is not None:
            info["path"] = "track"
            clock.lap("refine")
    if prior is not None and fit is None:  # fast path: refine straight from the prior, fall back to the search
        fit, samples, mask, blur = _refine(grey, prior, pmap, passes=PRIOR_PASSES)
        if fit is not None and not _holds(fit, samples, mask, prior, 0.15):
            fit = None
        if fit is not None:
            info["path"] = "prior"
            clock.lap("refine")
    if fit is None:
        sc = _Scene(grey, pmap, equalization)
        clock.lap("edges")
        hd, wd = sc.coarse.shape
        r_min = max(12.0, 0.05 * min(hd, wd))
        r_max = 0.7 * max(hd, wd)
        cands = hough.find_candidates(sc.edges, r_min, r_max)
        clock.lap("hough")
        best, info = choose(sc, cands, tag)
        info["path"] = "search"
        clock.lap("choose")
        fit, samples, mask, blur = _refine(grey, best.ellipse.scaled(sc.s), pmap)
        if RESCUE_MISFIT_GREY and fit is not None and _coverage(samples, mask) < MIN_REFINED_COVERAGE:
            again = _refine(grey, best.ellipse.scaled(sc.s), pmap, misfit_floor=RESCUE_MISFIT_GREY)
            if again[0] is not None and _coverage(again[1], again[2]) >= MIN_REFINED_COVERAGE:
                fit, samples, mask, blur = again
                info["misfit_rescue"] = True
        untangled = _untangled(grey, pmap, info["candidates"], fit, samples, mask, blur)
        if untangled is not None:
            fit, samples, mask, blur, info["untangled"] = untangled
        clock.lap("refine")
        if camera is None and sc.s // WORKING_SCALE_STEP >= 2 and untangled is None:
            info["blur_px"] = blur
            return _finer_of(grey, best.ellipse, sc.s, (fit, samples, mask), info, clock, camera_id)
    fit, samples, mask = _repositioned(grey, fit, samples, mask, pmap, blur, info)
    clock.lap("refine")
    info["blur_px"] = blur
    return _with_edge_checks(_result(fit, samples, mask, info, clock, camera, pmap, camera_id), grey, pmap)


REFIT_ITERATIONS = 4
# The final profiles' window (px, - metal / + tyre side). On the tyre side the bead wall is a
# band of its own shade 1-5 px out: a window reaching into it bends the kink model's tyre line
# and moves the edge (the larger part of the camber error at 1.3 Mpx), a shorter one has fewer
# samples to hold that line against the noise. Where the image is quiet (an average of a few
# frames: station/capture/frame_average.py) the shorter reach wins; where the noise is large against a
# faint step (dark rims) the longer one; between, the two edges' weighted mean has the error of
# neither alone (docs/rim-detection.md, "The final window follows the noise").
REPOSITION_WINDOW_PX = (-3.0, 4.5)
QUIET_WINDOW_PX = (-3.0, 3.0)
QUIET_NOISE_SHARE = 0.02   # read noise (preprocess.noise_grey) over the inliers' median edge step under
                           # which it applies alone: 8 frames of 2 grey levels on the simulator's rims 0.010
                           # (a single frame 0.025, 8 frames of dark rims 0.021, up to 0.076)
LONG_NOISE_SHARE = 0.04    # and over which the long one does; between the two, both, weighted (window_blend):
                           # not one switch, at which a camera would jump between two edge definitions
                           # with its noise (the rules compared: docs/history/accuracy.md, "Which window
                           # where")


def window_blend(noise_share: float) -> float:
    """The long window's weight in the final edge positions (0: the quiet window's alone, 1:
    the long one's) at read noise over edge step ``noise_share``: 0 up to
    ``QUIET_NOISE_SHARE``, 1 from ``LONG_NOISE_SHARE``, linear between."""
    lo, hi = QUIET_NOISE_SHARE, max(LONG_NOISE_SHARE, QUIET_NOISE_SHARE)
    if not noise_share >= lo:
        return 0.0 if noise_share == noise_share else 1.0  # NaN: no estimate, the long window
    if noise_share >= hi:
        return 1.0
    return float((noise_share - lo) / (hi - lo))


def _repositioned(grey: np.ndarray, fit, samples, mask, pmap: PixelMap, blur: float | None, info: dict | None = None):
    """The final fit, its samples and inlier mask with the inliers located again by
    :func:`subpixel.repositioned` along the fit's normals (where an inlier's edge is not
    found again it stays), and the ellipse fitted to them (from the fit). Soft edges (blur >
    WIDE_BLUR_PX) keep their points: there the bilinear interpolation's own blur is a small
    share of the edge's, and the soft-focus decisions stay as they were measured. (A large
    photograph without a camera model, refined at two scales by ``_finer_of``, keeps its
    points too.)"""
    if fit is None or blur is None or blur > WIDE_BLUR_PX:
        return fit, samples, mask
    idx = np.nonzero(mask)[0]
    # the points' feet on the fit: those of their profiles' bases (on the ellipse the pass
    # searched along, a fraction of a pixel from the fit; no undistortion of every point)
    bases = samples.along.point_at(samples.t[idx]) if samples.along is not None else pmap.undistort(
        rows(samples.points_px, idx))
    _, t = fit.ellipse.distance(bases)
    feet, n_ideal = fit.ellipse.point_at(t), fit.ellipse.normal_at(t)       # (M,2) ideal pixels
    anchors, nrm, scale = pmap.along_normals(feet, n_ideal)
    noise, step = noise_grey(grey, anchors), float(np.median(samples.contrast[idx]))
    long_share = window_blend(noise / step if step > 0 else np.inf)
    if info is not None:
        info["noise_grey"], info["quiet_window"] = round(noise, 3), bool(long_share < 1.0)
        info["long_window_share"] = round(long_share, 3)
    if long_share <= 0.0 or long_share >= 1.0:
        d, found, _ = repositioned(grey, anchors, nrm, QUIET_WINDOW_PX if long_share <= 0.0 else REPOSITION_WINDOW_PX)
    else:  # between the two: both windows' edges, weighted
        d_q, found_q, _ = repositioned(grey, anchors, nrm, QUIET_WINDOW_PX)
        d_l, found_l, _ = repositioned(grey, anchors, nrm, REPOSITION_WINDOW_PX)
        d, found = (1.0 - long_share) * d_q + long_share * d_l, found_q & found_l
    points_px = samples.points_px.copy()
    points_px[idx[found]] = anchors[found] + d[found, None] * nrm[found]
    ideal = np.empty((len(idx), 2))
    ideal[found] = feet[found] + (d[found] / scale[found])[:, None] * n_ideal[found]   # (|d| <= 1 px)
    if not found.all():
        ideal[~found] = pmap.undistort(rows(samples.points_px, idx[~found]))
    try:
        refit = fit_geometric(ideal, init=fit.ellipse, iterations=REFIT_ITERATIONS, reject_floor_px=SAME_CONTOUR_PX)
    except (ValueError, np.linalg.LinAlgError):
        return fit, samples, mask
    kept = mask.copy()
    kept[idx[~refit.inliers]] = False
    return refit, replace(samples, points_px=points_px, ok=kept), kept


def _with_edge_checks(det: RimDetection, grey: np.ndarray, pmap: PixelMap) -> RimDetection:
    """``det`` with the shares of its rim whose edge is at the sensor's white
    (``details["white_share"]``, station/rim/white_edge.py) and whose bright side is not the
    rim's metal (``details["metal_side_dark_share"]``, station/rim/metal_side.py)."""
    det.details["white_share"] = white_share(grey, det.points_px)
    det.details["metal_side_dark_share"] = round(dark_side_share(grey, det.ellipse, det.points_px, pmap), 4)
    return det


WORKING_SCALE_STEP = 3  # a search scale this many times larger gives a sub-pixel try at 1/(s // 3)


def _finer_of(grey: np.ndarray, coarse_ellipse: Ellipse, s: int, full, info: dict, clock: _Clock,
              camera_id: str) -> RimDetection:
    """The sub-pixel rim of a large image without a camera model (a photograph): refined at
    full resolution (``full``: the _refine result) and on the image downscaled by
    r = s // WORKING_SCALE_STEP, whichever fits its edge points better in full-resolution
    pixels (and covers as much of the rim). The edge model's windows and blur range are in
    pixels, made for edges blurred over about a pixel; a 12-Mpx photograph's edge may spread
    over several, where the full-resolution fit follows the model's mismatch (a simulated rim
    upscaled 3x: 1.4 px off at full resolution before the windows grew with the blur, 0.14
    px since, 0.07 px at 1/3). A sharp large image keeps
    its full-resolution fit."""
    r = s // WORKING_SCALE_STEP
    pmap = PixelMap(None)
    candidates = []
    try:
        candidates.append(_result(*full, dict(info), clock, None, pmap, camera_id))
    except RimNotFound as e:
        error = e
    small = downscale(grey, r)
    fit, samples, mask, blur = _refine(small, coarse_ellipse.scaled(s / r), pmap)
    try:
        candidates.append(_rescaled(_result(fit, samples, mask, {**info, "blur_px": blur}, clock, None, pmap,
                                            camera_id), r))
    except RimNotFound as e:
        error = e
    clock.lap("refine")
    if not candidates:
        raise error
    best = candidates[0]
    for c in candidates[1:]:
        if c.point_sigma_px < best.point_sigma_px and c.coverage >= best.coverage - 0.05:
            best = c
    best.timing_s = dict(clock.stages)
    return _with_edge_checks(best, grey, pmap)


def _rescaled(det: RimDetection, r: int) -> RimDetection:
    """A detection made on an image downscaled by ``r``, in the full image's pixels."""
    J = np.diag([r, r, r, r, 1.0])  # (cx, cy, a, b, angle)
    return replace(det, ellipse=det.ellipse.scaled(r), points_px=(det.points_px + 0.5) * r - 0.5,
                   ellipse_cov=J @ det.ellipse_cov @ J, point_sigma_px=det.point_sigma_px * r,
                   details={**det.details, "blur_px": det.details.get("blur_px", 0.0) * r, "working_scale": r})


NEAR_TIE = 0.8         # a runner-up scoring this share of the best's score is checked (_untangled)
SAME_WHEEL = 0.15      # centre within this share of the semi-major, size within it: the same wheel
UNTANGLE_ARCS = 36     # arcs of 10 degrees
AGREE_PX = 1.0         # two fits this close on an arc (median): the same edge there
APART_PX = 2.0         # the best's other arcs this far off the shared arcs' ellipse: another contour
MIN_SHARED = 0.3       # of the arcs: a shared part this large defines the rim alone
MIN_APART_ARCS = 3     # arcs this far off it (30 degrees): the best is a compromise


def _untangled(grey: np.ndarray, pmap: PixelMap, candidates: list[dict], fit, samples, mask, blur):
    """The rim when the chosen candidate's fit is a compromise between two contours, else None.

    Where the flange edge has no contrast over part of the rim (a lip in deep shadow under one
    harsh lamp, a dark rim, a narrow flange at low resolution), the edge found there is the
    next contour of the same polarity: the lip's highlight 5-15 px inside, or the bead's edge
    outside. One ellipse then follows the flange on one arc and that contour on the other
    (residuals of a few tenths of a pixel: it passes every test of one curve). The wheel's
    other concentric candidates show it: a runner-up of nearly the same score, refined, is the
    same kind of compromise the other way, and the two agree only where both follow the
    flange. So: a runner-up (``candidates``: the detector's ranked list, ideal full-resolution
    pixels) of the same wheel scoring ``NEAR_TIE`` of the best is refined; where its fit passes
    within ``AGREE_PX`` of the best's points arc by arc (``UNTANGLE_ARCS``) on at least
    ``MIN_SHARED`` of the rim, an ellipse is fitted to the best's points there. If the best's
    points lie ``APART_PX`` or more off it on ``MIN_APART_ARCS`` arcs or more (medians), those
    are another contour: the rim is the best's points on the other arcs, those within
    ``APART_PX`` of that ellipse, shared or not, and their fit. (A final pass from that
    ellipse found, where the flange has no contrast, whatever faint edge lay 1-2 px off it: an
    offset the 3-D tests cannot tell from edge bias, where a contour 5-15 px off is refused
    there.) A best fit that is one curve passes unchanged.

    fit, samples, mask, blur: the best candidate's _refine result. Returns (fit, samples, mask,
    blur, info) of the new fit, or None."""
    if fit is None or len(candidates) < 2:
        return None
    best = candidates[0]["ellipse"]
    a0, c0 = best["axes_px"][0], np.asarray(best["center_px"])
    ties = [(k, c["ellipse"]) for k, c in enumerate(candidates[1:], 1)
            if c["score"] >= NEAR_TIE * candidates[0]["score"] and abs(c["ellipse"]["axes_px"][0] / a0 - 1) <= SAME_WHEEL
            and np.linalg.norm(np.asarray(c["ellipse"]["center_px"]) - c0) <= SAME_WHEEL * a0]
    if not ties:
        return None
    pts = pmap.undistort(rows(samples.points_px, mask))  # (N,2) the best's inliers, ideal pixels
    _, t = fit.ellipse.distance(pts)
    arc = (np.mod(t, 2 * np.pi) * (UNTANGLE_ARCS / (2 * np.pi))).astype(int) % UNTANGLE_ARCS
    seen = np.bincount(arc, minlength=UNTANGLE_ARCS) >= 5
    for k, e in ties:
        other_fit, *_ = _refine(grey, Ellipse(e["center_px"], e["axes_px"], np.radians(e["angle_deg"])), pmap)
        if other_fit is None:
            continue
        shared = _arc_medians(np.abs(other_fit.ellipse.distance(pts)[0]), arc, seen) < AGREE_PX
        if shared.sum() < MIN_SHARED * UNTANGLE_ARCS:
            continue
        try:
            shared_fit = fit_geometric(rows(pts, shared[arc]), init=fit.ellipse, iterations=12)
        except (ValueError, np.linalg.LinAlgError):
            continue
        off = _arc_medians(np.abs(shared_fit.ellipse.distance(pts)[0]), arc, seen)
        apart = seen & (off > APART_PX)
        if apart.sum() < MIN_APART_ARCS:
            return None  # the best follows one curve all round: it stays
        on_rim = (off < APART_PX)[arc]  # the arcs on the shared arcs' ellipse, shared or not
        try:
            rim_fit = fit_geometric(rows(pts, on_rim), init=shared_fit.ellipse, iterations=12)
        except (ValueError, np.linalg.LinAlgError):
            continue
        kept = np.zeros_like(mask)
        kept[np.nonzero(mask)[0][on_rim][rim_fit.inliers]] = True
        if _coverage(samples, kept) < MIN_REFINED_COVERAGE:
            continue
        samples.ok = kept.copy()
        return rim_fit, samples, kept, blur, {"runner_up": k, "shared_arcs": int(shared.sum()),
                                              "other_contour_arcs": int(apart.sum()), "arcs": UNTANGLE_ARCS}
    return None


def _arc_medians(x: np.ndarray, arc: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(len(seen),) median of x (N,) over the points of each arc (arc (N,) ints), inf where
    the arc is not ``seen``."""
    med, _ = sector_medians(x, arc, len(seen))
    return np.where(seen, med, np.inf)


def refine_candidate(image: np.ndarray, ellipse: Ellipse, *, camera=None, camera_id: str = "") -> RimDetection:
    """The sub-pixel rim along one candidate ellipse (e.g. a runner-up of ``details["candidates"]``,
    in the frame of the detection it came from), refined exactly as the search refines its
    choice; raises RimNotFound when no rim edge holds there. No search, no fallback."""
    clock = _Clock()
    grey = to_grey(image, camera_id)
    pmap = PixelMap(camera)
    fit, samples, mask, blur = _refine(grey, ellipse, pmap)
    clock.lap("refine")
    return _with_edge_checks(_result(fit, samples, mask, {"path": "candidate", "blur_px": blur}, clock, camera, pmap,
                                     camera_id), grey, pmap)


def _result(fit, samples, mask, info: dict, clock: _Clock, camera, pmap: PixelMap, camera_id: str) -> RimDetection:
    tag = camera_id or "image"
    if fit is None:
        raise RimNotFound(f"{tag}: no closed rim contour (the sub-pixel edge was found at only "
                          f"{int(mask.sum())} points of the candidate ellipse)",
                          hint=f"check focus and lighting of the rim flange; {DARK_RIM_NOTE}")
    coverage = _coverage(samples, mask)
    if coverage < MIN_REFINED_COVERAGE:
        raise RimNotFound(f"{tag}: no closed rim contour (sub-pixel edge on {coverage:.0%} of the perimeter)",
                          hint=f"check that the whole rim is in view and evenly lit; {DARK_RIM_NOTE}")
    pts = rows(samples.points_px, mask)
    ring = info.get("ring", 1.0)
    outer = info.get("outer", 1.0)
    sharp = float(np.exp(-max(fit.sigma_px - 0.1, 0.0) / 0.5))
    score = float(np.clip(coverage * (0.6 + 0.4 * ring) * (0.8 + 0.2 * outer) * (0.7 + 0.3 * sharp), 0, 1))
    clock.lap("score")
    return RimDetection(
        ellipse=fit.ellipse, points_px=pts, score=score, ellipse_cov=fit.cov, point_sigma_px=fit.sigma_px,
        timing_s=dict(clock.stages), camera_id=camera_id,
        points_norm=pmap.normalized(pts) if camera is not None else None,
        ellipse_frame="pixels" if pmap.identity else "ideal_pixels",
        coverage=coverage, contrast=float(median(samples.contrast[mask])),
        details={**info, "step_modulation": step_modulation(samples.t[mask], samples.contrast[mask])},
        points_contrast=samples.contrast[mask].copy())


def _holds(fit, samples, mask, prior: Ellipse, shift: float, min_coverage: float = 0.8) -> bool:
    """A fit from a prior is the prior's rim: centre and size within ``shift`` of its size,
    and the edge found on ``min_coverage`` of the perimeter."""
    return bool(np.linalg.norm(fit.ellipse.center_px - prior.center_px) <= shift * prior.axes_px[0]
                and abs(fit.ellipse.axes_px[0] / prior.axes_px[0] - 1) <= shift
                and _coverage(samples, mask) >= min_coverage)


def _coverage(samples, mask) -> float:
    """Fraction of the in-image samples that gave an inlier edge point."""
    visible = samples.rms < np.inf  # the profile lay inside the image
    return float(mask.sum() / max(visible.sum(), 1))
