"""One wheel's stereo pair: detect its rim in both cameras, rebuild the 3-D wheel, check that
both cameras found the same rim, and pair runner-up candidates when they did not.

The whole cycle over the four pairs is :func:`station.measure.measure_frames`; the checks
across the pairs of an axle are in station/wheel/axle_rims.py.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from calibration.camera_model import CameraModel
from station.wheel.calibration_share import calibration_covariance, pair_perturbation_covariance
from station.config import StationConfig
from station.errors import MeasurementError, StationError
from station.rim.choice import DARK_RIM_NOTE
from station.compute.frame_handoff import resolve as resolve_frame
from station.wheel.other_contour import refit_other_contour
from station.wheel.rim_size import AXLE_RIM_TOLERANCE
from station.wheel.circle_fit import circle_from_ellipses, refine_circle
from station.wheel.face_surface import face_near_plane
from station.wheel.fit import WheelFit
from station.wheel.paper import reconstruct_paper
from station.wheel.rim_pattern import FacePose
from station.wheel.view_agreement import ViewAgreement, view_agreement


@dataclass
class WheelObservation:
    wheel: str
    cams: tuple[str, str]            # (precision, reference)
    detections: tuple                # RimDetection per camera
    paper: WheelFit
    circle: WheelFit
    views: ViewAgreement | None = None  # each view's own rim axis against the pair's (view_agreement.py)


def detect_one(image: np.ndarray, camera: CameraModel, cam_id: str):
    """The RimDetection of one camera, or the StationError it raised."""
    from station.rim import detect_rim

    try:
        return detect_rim(image, camera=camera, camera_id=cam_id)
    except StationError as e:
        return e


@dataclass
class WheelOutcome:
    """One wheel of a cycle: both cameras' detections (RimDetection or StationError), the
    observation or the error that refused it, a warning, and seconds per stage."""

    wheel: str
    cams: tuple[str, str]
    detections: dict
    observation: WheelObservation | None = None
    error: StationError | None = None
    note: str | None = None
    timing_s: dict | None = None
    first_choices: dict | None = None  # the detections before a runner-up pairing replaced them


def measure_wheel(wheel: str, cams: tuple[str, str], images: dict, cameras: dict,
                  config: StationConfig, calibration_cov: np.ndarray | None = None) -> WheelOutcome:
    """Detect the rim in both cameras of a pair and rebuild the wheel (one worker's task).
    images: {camera id: array, or a FrameRef of station.compute.frame_handoff}."""
    t0 = time.perf_counter()
    images = {c: resolve_frame(im) for c, im in images.items()}
    detections = {c: detect_one(images[c], cameras[c], c) for c in cams}
    t1 = time.perf_counter()
    out = WheelOutcome(wheel, cams, detections, first_choices=dict(detections))
    if not any(isinstance(d, StationError) for d in detections.values()):
        try:
            out.observation = reconstruct_wheel(wheel, cams, detections, cameras, calibration_cov,
                                                other_contour_test=True)
            check_same_rim(out.observation, config, images=images, cameras=cameras)
        except StationError as e:
            # a runner-up pairing is a second guess: it must pass the full check, including
            # the epipolar one that a first choice seen on part of its rim may be excused
            resolved = resolve_pair(wheel, cams, detections, images, cameras, config, calibration_cov)
            if resolved is None:
                out.observation, out.error = None, e
            else:
                out.observation, out.note = resolved
                detections.update(dict(zip(cams, out.observation.detections)))
    out.timing_s = {"detect": t1 - t0, "reconstruct": time.perf_counter() - t1}
    return out


DIVERGED_PX = 1.0  # a circle fit whose median residual in a view exceeds this is not on its points


def reconstruct_wheel(wheel: str, cams: tuple[str, str], detections: dict, cameras: dict,
                      calibration_cov: np.ndarray | None = None,
                      other_contour_test: bool = False) -> WheelObservation:
    """Both 3-D methods for one pair. calibration_cov: the pair's (30,30) joint camera-parameter
    covariance from the calibration (StationCalibration.pair_covariance); when given, its share
    of the circle's uncertainty is added to the circle's centre and axis covariance.
    other_contour_test: a circle less certain than other_contour.TEST_ABOVE_DEG is tested for arcs on another
    concentric contour of the wheel (station/wheel/other_contour.py).

    The circle fit starts from the paper's circle, whose centre is the centroid of the
    triangulated points. A view that sees part of the rim moves it toward that part (0.16 m
    for a rim seen on two thirds of its perimeter under harsh light, and the fit from there ran
    off to a circle 4 m wide). When the fit is not on its points (``DIVERGED_PX``), it starts
    again from the circle of the two image ellipses
    (:func:`station.wheel.circle_fit.circle_from_ellipses`), kept if that one is."""
    cam_l, cam_r = (cameras[c] for c in cams)
    det_l, det_r = detections[cams[0]], detections[cams[1]]
    paper = reconstruct_paper(det_l.points_px, det_r.points_px, cam_l, cam_r)
    contrast = (det_l.points_contrast, det_r.points_contrast)  # each point weighted by its edge step
    circle = refine_circle(det_l.points_px, det_r.points_px, cam_l, cam_r, paper, contrast=contrast)
    if not max(circle.view_median_px) <= DIVERGED_PX:  # the paper's circle was too far off to start from
        centre, radius = circle_from_ellipses(cam_l, cam_r, det_l.ellipse, det_r.ellipse)
        start = replace(paper, center_station=centre, radius_m=radius)
        retry = refine_circle(det_l.points_px, det_r.points_px, cam_l, cam_r, start, contrast=contrast)
        if max(retry.view_median_px) <= DIVERGED_PX:
            circle = retry
    if other_contour_test:
        circle = refit_other_contour(det_l.points_px, det_r.points_px, cam_l, cam_r, circle,
                                     contrast=contrast) or circle
    if calibration_cov is not None:
        cov_pair = pair_perturbation_covariance(cam_l, cam_r, calibration_cov)
        cc, ca = calibration_covariance(det_l.points_px, det_r.points_px, cam_l, cam_r, circle, cov_pair=cov_pair)
        circle.cov_center = circle.cov_center + cc
        circle.cov_axis = circle.cov_axis + ca
        circle.calibration_share = (float(np.trace(cc)), float(np.trace(ca)))
    views = view_agreement((det_l.points_px, det_r.points_px), (cam_l, cam_r), circle.center_station,
                           circle.axis_station, circle.radius_m, circle.tilt_per_px_views)
    return WheelObservation(wheel, cams, (det_l, det_r), paper, circle, views)


UNCHECKED_MIN_KEPT = 1 / 3  # of each view's edge points the circle must rest on to be taken unchecked
FULL_VIEW_COVERAGE = 0.8    # an unchecked pair's warning names a camera's coverage below this, else the
                            # tangent point it missed
TANGENT_GAP_DEG = 15.0      # the drift check needs rim points this near where the epipolar planes touch


def unverifiable_epipolar(o: WheelObservation, config: StationConfig) -> bool:
    """The epipolar tangents disagree beyond the mismatch limit, but one 3-D circle fits both
    views (median residual <= a fifth of that limit) on at least ``UNCHECKED_MIN_KEPT`` of each
    view's edge points, and a camera saw no rim point within ``TANGENT_GAP_DEG`` of where an
    epipolar plane touches the rim: its tangent there is extrapolated. The pair is the same
    rim, but this cycle cannot check its calibration. (A wrong candidate that a circle fits on
    a few of its points only - 6 % on a camera whose image was flipped, tests/test_measure_pairs.py -
    is not: a true rim that one camera saw on 68 % of its perimeter kept 48 %.) Where both
    cameras saw the tangent points, a residual this large is a moved camera, whatever else they
    missed: a camera knocked 6-15 px after calibration, its pair centred on the wheel, showed
    5-11 px with 73-76 % of the rim seen and every tangent point within 4 deg
    (bench/perturbed_images.py)."""
    limit = config.measurement.mismatch_limit_px
    return (o.circle.epipolar_rms_px > limit and max(o.circle.view_median_px) <= 0.2 * limit
            and min(kept_fractions(o)) >= UNCHECKED_MIN_KEPT
            and not np.max(o.circle.tangent_gap_deg) <= TANGENT_GAP_DEG)


def kept_fractions(o: WheelObservation) -> list[float]:
    """Per camera of the pair, the fraction of its detected edge points the 3-D circle rests on."""
    return [n / max(len(d.points_px), 1) for n, d in zip(o.circle.n_points, o.detections)]


def check_same_rim(o: WheelObservation, config: StationConfig, allow_unchecked: bool = True,
                   images: dict | None = None, cameras: dict | None = None) -> None:
    """Refuse a wheel whose two cameras did not find the same 3-D rim.

    A wrong ellipse in one camera (the tyre outline, a hub, the other wheel) cannot share the
    rim's two epipolar tangent planes with the other camera, nor fit one 3-D circle with it:
    the residuals are then tens of pixels where a true rim gives tenths. With the pair's
    ``images`` (linear) and ``cameras``, the circle must also have the wheel's face behind it
    (:func:`check_face_behind`).
    """
    limit = config.measurement.mismatch_limit_px
    nominal = np.array(config.cameras[o.cams[0]].nominal.look_at_m)
    offset = float(np.linalg.norm(o.circle.center_station - nominal))
    if offset > config.measurement.max_wheel_offset_m:
        raise MeasurementError(
            f"{o.cams[0]} and {o.cams[1]} found a rim {offset:.2f} m from where the {o.wheel} wheel "
            f"should be (limit {config.measurement.max_wheel_offset_m} m): not this wheel's rim",
            hint=f"check the vehicle's position on the lift and both cameras' images; {DARK_RIM_NOTE}")
    lo, hi = config.measurement.min_rim_radius_m, config.measurement.max_rim_radius_m
    if not lo <= o.circle.radius_m <= hi:
        raise MeasurementError(
            f"{o.cams[0]} and {o.cams[1]} found a circle of radius {o.circle.radius_m * 1000:.0f} mm, "
            f"not a rim flange ({lo * 1000:.0f}-{hi * 1000:.0f} mm): the hub, the disc or the tyre, "
            "or each camera another contour",
            hint="look at both cameras' images of this wheel (station review); rims outside this "
                 f"range need measurement.min_rim_radius_m / max_rim_radius_m; {DARK_RIM_NOTE}")
    worst_view = max(o.circle.view_median_px)
    unchecked = allow_unchecked and unverifiable_epipolar(o, config)
    # (unchecked: one circle fits both views, the same rim, its tangents extrapolated; a warning says so)
    if not unchecked and (o.circle.epipolar_rms_px > limit or not worst_view <= limit):
        raise MeasurementError(
            f"{o.cams[0]} and {o.cams[1]} did not find the same rim (epipolar residual "
            f"{o.circle.epipolar_rms_px:.1f} px, circle fit median {worst_view:.1f} px, "
            f"limit {limit} px)", hint="look at both cameras' images of this wheel (station review); if both "
                                       "show this wheel's rim, a camera may have moved since calibration: recalibrate; "
                                       f"{DARK_RIM_NOTE}")
    if images is not None and cameras is not None:
        check_face_behind(o, images, cameras)


MIN_FACE_RECESS_M = 0.008  # a flange stands at least this far in front of its wheel's face
MAX_NEAR_SHARE = 0.2       # of the face's points placed, at most this share nearer the circle's plane
MIN_RECESS_CELLS = 100     # points of the face both cameras place, for the test to be made


def check_face_behind(o: WheelObservation, images: dict, cameras: dict) -> None:
    """Refuse a circle that the wheel's own face does not lie behind.

    The flange is the wheel's outermost edge: its spokes and face lie tens of mm behind its
    plane. On a dark rim whose flange hardly stands out from the tyre, both cameras may agree
    on another concentric contour, the ring where the spokes meet the barrel: a circle a fifth
    smaller and 40-90 mm inboard, with the spokes in its plane. Such a circle passes every other
    test, and its centre, inboard along a cambered axis, tilts the car frame (a whole cycle's
    cambers 0.16 deg off, stated 0.01). Of the outer face's points both cameras place
    (station/wheel/face_surface.py, ``face_near_plane``), a circle on the face has 30-100 %
    within ``MIN_FACE_RECESS_M`` of its plane or in front of it, a flange at most 11 % (points
    matched at a wrong depth under harsh light); a face the views cannot place (plain, or too
    dark) is not judged."""
    share, cells = face_near_plane({c: images[c] for c in o.cams}, {c: cameras[c] for c in o.cams},
                                   FacePose(np.asarray(o.circle.center_station, float),
                                            np.asarray(o.circle.axis_station, float), float(o.circle.radius_m)),
                                   MIN_FACE_RECESS_M)
    if cells >= MIN_RECESS_CELLS and share > MAX_NEAR_SHARE:
        raise MeasurementError(
            f"{o.cams[0]} and {o.cams[1]} found a circle of radius {o.circle.radius_m * 1000:.0f} mm with "
            f"{share:.0%} of the wheel's face within {MIN_FACE_RECESS_M * 1000:.0f} mm of its plane or in front of "
            "it (a flange stands in front of its face): a contour of the face (the ring where the spokes meet the "
            "barrel), not the flange",
            hint="light the rim's lip or clean it so that it stands out from the tyre, and measure again; "
                 "look at both cameras' images of this wheel (station review)")


ALTERNATIVES = 2  # runner-up candidates per camera tried when a pair's first choices disagree


def _alternatives(cid: str, det, image: np.ndarray, camera: CameraModel) -> list[tuple[float, object]]:
    """[(search score, RimDetection)] of the detector's first choice and its runner-up
    candidates in one image, each refined to sub-pixel edges (those that hold)."""
    from station.rim import Ellipse
    from station.rim.detector import refine_candidate

    cands = det.details.get("candidates", [])
    out = [(cands[0]["score"] if cands else det.score, det)]
    for c in cands[1:1 + ALTERNATIVES]:
        e = c["ellipse"]
        prior = Ellipse(e["center_px"], e["axes_px"], np.radians(e["angle_deg"]))
        try:
            out.append((c["score"], refine_candidate(image, prior, camera=camera, camera_id=cid)))
        except StationError:
            continue
    return out


def resolve_pair(wheel: str, cams: tuple[str, str], detections: dict, images: dict, cameras: dict,
                 config: StationConfig, calibration_cov: np.ndarray | None = None,
                 radius_m: float | None = None) -> tuple[WheelObservation, str] | None:
    """A pair whose cameras' first choices are not the same rim (the hub won in one view, say):
    the best combination of each camera's candidates that is one 3-D rim, scored by the weaker
    of its two detection scores; with a warning naming what was changed. None if there is none.
    ``radius_m``: the size the rim must have (its axle partner's, within AXLE_RIM_TOLERANCE)."""
    options = {c: _alternatives(c, detections[c], images[c], cameras[c]) for c in cams}
    best = None
    for i, (sl, dl) in enumerate(options[cams[0]]):
        for j, (sr, dr) in enumerate(options[cams[1]]):
            if i == j == 0 or (best is not None and min(sl, sr) <= best[0]):
                continue
            try:
                o = reconstruct_wheel(wheel, cams, {cams[0]: dl, cams[1]: dr}, cameras, calibration_cov,
                                      other_contour_test=True)
                check_same_rim(o, config, allow_unchecked=False, images=images, cameras=cameras)
            except StationError:
                continue
            if radius_m is not None and abs(o.circle.radius_m - radius_m) > AXLE_RIM_TOLERANCE * radius_m:
                continue
            best = (min(sl, sr), o, (i, j))
    if best is None:
        return None
    changed = [f"{c} took its candidate {k + 1} ({options[c][k][0]:.2f}) over its first choice ({options[c][0][0]:.2f})"
               for c, k in zip(cams, best[2]) if k]
    return best[1], f"{wheel} ({cams[0]}, {cams[1]}): the first choices were not the same rim; " + "; ".join(changed)
