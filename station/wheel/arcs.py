"""Which of a view's rim points to trust: arcs of the rim, the viewing geometry at each point,
and the tests that leave out arcs whose edge is not the flange's (station.wheel.circle_fit's circle fit).

* :func:`edge_visibility` - how the viewing ray meets the rim at each point (outward: no sidewall
  can hide it; low over the wheel plane: it grazes the lip);
* :func:`hidden_arcs` - arcs the sidewall could hide, kept only where they agree with the others;
* :func:`inward_arcs` - arcs whose edge lies inside the fitted circle beyond the view's scatter;
  :func:`stray_arcs` - those, and the arcs outside it by as much;
* :func:`not_grazing` - the points whose ray does not graze the lip;
* :func:`arc_median_noise` - how well a view's own scatter knows one arc's median, and
  :func:`stray_floor_px` - the least offset at which an arc strays, from it.
"""

from __future__ import annotations

import numpy as np

from calibration.camera_model import CameraModel
from station.rim.npfast import sector_medians
from station.wheel.fit import WheelFit

GRAZING_VISIBILITY = 0.5  # edge_visibility above which a ray grazes the lip (30 deg from the wheel plane)
MIN_KEPT_FRACTION = 0.5   # a test leaving out more of a view is not trusted alone
HIDDEN_SECTORS = 24       # arcs of 15 degrees
INWARD_ARC_SIGMAS = 3.0   # beyond this many robust sigmas of the arcs' medians (inward_arcs)
STRAY_NOISE_SIGMAS = 5.0  # and beyond this many standard errors of one arc's median (arc_median_noise)
STRAY_MIN_PX = 0.01       # the stray-arc floor never below this: no sub-pixel edge is known better


def rim_angles(cam: CameraModel, xy: np.ndarray, c: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N,) angle (rad) around the circle (centre c (3,), unit normal n (3,), station frame) of
    the points where the rays of ``cam``'s normalised points xy (N,2) meet the circle's plane."""
    u = np.cross(n, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    C0 = cam.center_station
    d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ cam.R_cam_station
    P = C0 + (((c - C0) @ n) / (d @ n))[:, None] * d
    return np.arctan2((P - c) @ v, (P - c) @ u)


def sector_labels(phi: np.ndarray, n_sectors: int) -> np.ndarray:
    return ((phi + np.pi) / (2 * np.pi) * n_sectors).astype(int) % n_sectors



def edge_visibility(cam: CameraModel, xy: np.ndarray, circle: WheelFit) -> np.ndarray:
    """(N,) how safely each rim point is seen past the tyre: the cosine between the viewing ray
    at the point and the rim's outward radial direction there.

    The tyre's sidewall stands outside the flange edge and bulges toward the cameras. A ray that
    reaches the edge travelling radially outward has passed over the rim, never the tyre; one
    travelling inward has passed over the sidewall, which may hide the edge (oblique views, the
    side of the rim nearer the camera). xy: (N,2) normalised points of ``cam``.
    """
    C = cam.center_station
    d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ cam.R_cam_station  # rays, station frame
    n, c = circle.axis_station, circle.center_station
    s = ((c - C) @ n) / (d @ n)
    P = C + s[:, None] * d                     # where each ray meets the rim plane
    rho = (P - c) - np.outer((P - c) @ n, n)
    rho /= np.linalg.norm(rho, axis=1, keepdims=True)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.einsum("ij,ij->i", d, rho)


def hidden_arcs(r: np.ndarray, safe: np.ndarray, phi: np.ndarray, noise_px: float,
                n_sectors: int = HIDDEN_SECTORS) -> np.ndarray:
    """(N,) bool: the points of one view to keep. r (N,) signed image residuals (px, negative
    inside) of the view's points against the circle fitted to the *safe* points only; safe (N,)
    bool, points no sidewall can hide (``edge_visibility`` >= 0); phi (N,) their rim angles.

    Every doubtful point is kept unless its arc (``n_sectors`` sectors of the rim) lies inside
    the circle's projection beyond what the safe arcs' own scatter allows: the median of the
    arc's residuals below -max(noise_px, 3 x the spread of the safe arcs' medians). A hidden
    flange edge is seen on the tyre's occluding contour, up to a few pixels inside; a visible one
    agrees with the safe arcs within their bias. The spread is robust (1.4826 x the median
    absolute safe-arc median): a few safe arcs on another contour, pixels inside,
    would otherwise widen it until every doubtful arc passed."""
    lab = sector_labels(phi, n_sectors)
    med_safe, n_safe = sector_medians(r[safe], lab[safe], n_sectors)
    meds_safe = med_safe[n_safe >= 5]
    spread = 1.4826 * float(np.median(np.abs(meds_safe))) if len(meds_safe) else noise_px
    limit = -max(noise_px, 3.0 * spread)
    med_doubt, n_doubt = sector_medians(r[~safe], lab[~safe], n_sectors)
    agree = (n_doubt > 0) & (med_doubt >= limit)                   # (n_sectors,) doubtful arcs kept
    keep = safe | agree[lab]
    return keep


def inward_arcs(r: np.ndarray, phi: np.ndarray, noise_px: float, n_sectors: int = HIDDEN_SECTORS) -> np.ndarray:
    """(N,) bool: the points of one view that lie on arcs whose edge is inside the fitted
    circle's projection beyond what the view's other arcs allow. r (N,) signed image residuals
    (px, negative inside) against the fitted circle; phi (N,) rim angles (rad).

    Occlusion (a tyre bulge), a lip shaded as dark as the tyre, or a lip's inner edge taken for
    the flange move the edge found *inward*, over whole arcs. An arc (one of ``n_sectors`` of
    the rim, >= 5 points) is flagged when its median residual lies below the median of all arc
    medians by more than max(``noise_px``, INWARD_ARC_SIGMAS robust sigmas (1.4826 MAD) of the
    arc medians). With fewer than 6 such arcs nothing is flagged."""
    return _arc_offsets(r, phi, noise_px, n_sectors) < 0


def stray_arcs(r: np.ndarray, phi: np.ndarray, noise_px: float, n_sectors: int = HIDDEN_SECTORS) -> np.ndarray:
    """(N,) bool: :func:`inward_arcs`, and the arcs whose edge lies *outside* the fitted circle
    by as much. A lit tyre bead wall next to the flange looks like metal: on a small rim under
    a tall sidewall the oblique camera saw the edge 0.4-1.5 px outside the flange on a third
    of the rim, just under the gross-outlier limit, and those arcs tilted the circle by
    0.25 deg."""
    return _arc_offsets(r, phi, noise_px, n_sectors) != 0


def arc_median_noise(r: np.ndarray, phi: np.ndarray, n_sectors: int = HIDDEN_SECTORS) -> float:
    """The standard error (px) of one arc's median residual from the view's own scatter: the
    robust sigma (1.4826 MAD) of the residuals r (N,) about their arc's median, x 1.2533 (a
    median's efficiency), over the root of the median count per arc (arcs of >= 5 points;
    phi (N,) rim angles, rad). inf with fewer than 6 such arcs: no floor can be told.

    It measures what separates an arc's bias from its noise in *this* capture: 0.016 px on
    one sigma-2 frame, 0.009 on the mean of eight (bench/accuracy.py, 20 vehicles)."""
    lab = sector_labels(phi, n_sectors)
    med, count = sector_medians(r, lab, n_sectors)
    arcs = count >= 5
    if arcs.sum() < 6:
        return float("inf")
    on = arcs[lab]
    spread = 1.4826 * float(np.median(np.abs(r[on] - med[lab[on]])))
    return 1.2533 * spread / float(np.sqrt(np.median(count[arcs])))


def stray_floor_px(r: np.ndarray, phi: np.ndarray, loss_scale_px: float) -> float:
    """The least offset (px) at which an arc of one view strays (:func:`stray_arcs`):
    STRAY_NOISE_SIGMAS standard errors of an arc's median in this view's residuals r (N,) at rim
    angles phi (N,), at most ``loss_scale_px``. A fixed 0.3 px let arcs 0.1 px off stay where their medians are
    known to 0.01 px (a mean of eight frames): one such arc over 60 degrees of one view moved
    camber 0.03 deg. Noisier edges keep the higher floor; noise-free points (a
    synthetic test, a perfect render) STRAY_MIN_PX, so that arithmetic is never judged."""
    return min(loss_scale_px, max(STRAY_MIN_PX, STRAY_NOISE_SIGMAS * arc_median_noise(r, phi)))


def _arc_offsets(r: np.ndarray, phi: np.ndarray, noise_px: float, n_sectors: int) -> np.ndarray:
    """Per point (N,): -1 / +1 where its arc's (>= 5 points) median residual lies below / above
    the median of all arc medians by more than max(noise_px, INWARD_ARC_SIGMAS robust sigmas of
    them), else 0. All 0 with fewer than 6 arcs."""
    lab = sector_labels(phi, n_sectors)
    med, count = sector_medians(r, lab, n_sectors)
    arcs = count >= 5
    off = np.zeros(n_sectors, int)
    if arcs.sum() < 6:
        return off[lab]
    m = med[arcs]
    centre = float(np.median(m))
    limit = max(noise_px, INWARD_ARC_SIGMAS * 1.4826 * float(np.median(np.abs(m - centre))))
    with np.errstate(invalid="ignore"):
        off[arcs & (med < centre - limit)] = -1
        off[arcs & (med > centre + limit)] = 1
    return off[lab]


def not_grazing(circle: WheelFit, points_l_px: np.ndarray, points_r_px: np.ndarray, cam_l: CameraModel,
                cam_r: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Per view, (N,) bool: the points (pixels) whose ray does not graze the lip (see
    :func:`not_grazing_xy`)."""
    return not_grazing_xy(circle, cam_l.pixels_to_normalized(points_l_px), cam_r.pixels_to_normalized(points_r_px),
                           cam_l, cam_r)


def not_grazing_xy(circle: WheelFit, xy_l: np.ndarray, xy_r: np.ndarray, cam_l: CameraModel,
                    cam_r: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Per view, (N,) bool: the normalised points whose ray does not graze the lip
    (:func:`edge_visibility` against ``circle`` at most ``GRAZING_VISIBILITY``); all points of
    a view where that would leave fewer than ``MIN_KEPT_FRACTION`` of them.

    Where the viewing ray crosses the rounded flange lip travelling outward and low over the
    wheel plane (the ray within 30 degrees of the plane), the lip's rim-side surface turns away
    from the camera before the flange edge: the edge seen is the lip's terminator, up to a
    millimetre inside (measured on the simulator: 0.65-0.8 px on such arcs of the oblique
    camera, against 0.05 px elsewhere). Leaving such points out removes that bias but weakens
    the geometry of the view, so :func:`station.wheel.circle_fit.refine_circle` fits both ways and keeps the fit that
    is better determined by its own covariance."""
    keeps = []
    for cam, xy in ((cam_l, xy_l), (cam_r, xy_r)):
        keep = ~(edge_visibility(cam, xy, circle) > GRAZING_VISIBILITY)
        keeps.append(keep if keep.sum() >= MIN_KEPT_FRACTION * len(xy) else np.ones(len(xy), bool))
    return keeps[0], keeps[1]
