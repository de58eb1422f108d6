"""One measurement from eight images: detect the rims, rebuild the wheels, compute the angles.

:func:`measure_frames` is pure (images + calibrated cameras -> a :class:`~station.result.Measurement`,
its JSON in docs/result-schema.md); the cycle around it (capture, saving, recording, history) is
in station/cycle.py. A wheel that cannot be measured makes the whole result invalid, with the
wheel, the camera and the reason; no angle of an invalid result is reported as valid.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from calibration.camera_model import CameraModel
from calibration.station_frame import AXLE_PARTNER, AXLES, WHEELS
from station import alignment
from station.compute.frame_handoff import FrameHandoff
from station.config import StationConfig
from station.errors import MeasurementError, StationError
from station.result import (ANGLE_NAMES, AxleResult, CameraDetection, Failure, Measurement, WarningFlag, WheelQuality,
                            WheelResult)
from station.rim.camera_response import linear_images
from station.rim.choice import DARK_RIM_NOTE
from station.stated_uncertainty import refuse_uncertain_wheels, unseen_axis_covariance, views_covariance
from station.wheel.axle_rims import pair_from_partner, settle_axles
from station.wheel.fit import WheelFit
from station.wheel.pair import (FULL_VIEW_COVERAGE, TANGENT_GAP_DEG, measure_wheel,
                                unverifiable_epipolar)
from station.wheel.rim_size import size_mismatches

METHODS = ("circle", "paper")


def measure_frames(images: dict[str, np.ndarray], cameras: dict[str, CameraModel],
                   config: StationConfig, method: str = "circle", workers=None,
                   calibration_cov: dict | None = None, refuse_uncertain: bool = True) -> Measurement:
    """The measurement of one set of eight images.

    images, cameras: keyed by camera id. method: "circle" (default, the refined fit) or
    "paper" (section 3.2 exactly). Never raises for a wheel that fails: the result is
    invalid and ``failure`` names the wheel, the camera and why. workers: a
    :class:`station.compute.workers.WorkerPool` to run the four wheels in processes (both
    cores), else two threads. ``timing_s``: "wheels" the wall time of the four wheels,
    "detect" and "reconstruct" their stages summed over the wheels (work, not wall time).
    calibration_cov: wheel -> the pair's (30,30) camera-parameter covariance from the
    calibration file (``StationCalibration.pair_covariance``), added to the stated uncertainty.
    refuse_uncertain: refuse a wheel less certain than ``measurement.uncertainty_limit_deg``
    (:func:`refuse_uncertain_wheels`); False for a capture of a procedure whose reported values
    rest on several captures (runout compensation, a steering sweep's steered positions): the
    procedure judges what it reports.
    """
    if method not in METHODS:
        raise MeasurementError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    t0 = time.perf_counter()
    images = linear_images(images, config)  # grey proportional to light, as the edge model takes it
    outcomes = _measure_wheels(images, cameras, config, workers, calibration_cov)
    pair_from_partner(outcomes, images, cameras, config, calibration_cov)
    timing = {"wheels": time.perf_counter() - t0,
              "detect": sum(o.timing_s["detect"] for o in outcomes),
              "reconstruct": sum(o.timing_s["reconstruct"] for o in outcomes)}
    by_cam = {c: d for o in outcomes for c, d in o.detections.items()}
    detections = {c: by_cam[c] for c in images if c in by_cam}
    result = Measurement(station=config.name)
    for kind, warn in (("focus", _soft_focus_warnings), ("small_rim", _small_rim_warnings),
                       ("exposure", _white_edge_warnings)):
        for cid, text in warn(detections, config):
            result.warn(text, WarningFlag(kind, config.cameras[cid].wheel, camera=cid))
    for o in outcomes:
        if o.note:
            result.warnings.append(o.note)
    result.warning_flags += [WarningFlag("runner_up", o.wheel) for o in outcomes if o.note]

    def finish(failure: Failure | None, summary: bool = True) -> Measurement:
        result.failure = failure
        timing["total"] = time.perf_counter() - t0
        result.timing_s = timing
        if summary:
            result.detections = _detection_summary(detections)
        return result

    failures = [(cid, d) for cid, d in detections.items() if isinstance(d, StationError)]
    if failures:
        cid, err = failures[0]
        wheel = config.cameras[cid].wheel
        result.warnings += [f"{config.cameras[c].wheel} {c}: {e}" for c, e in failures[1:]]
        return finish(Failure(err.code, f"{wheel} {cid}: {err}", err.hint, wheel, cid))
    observations = {}
    for o in outcomes:
        if o.error is not None:
            e, cams = o.error, o.cams
            return finish(Failure(e.code, f"{o.wheel} ({cams[0]}, {cams[1]}): {e}", e.hint, o.wheel,
                                  f"{cams[0]}+{cams[1]}"), summary=False)
        observations[o.wheel] = o.observation
    failure = settle_axles(result, observations, outcomes, images, cameras, config, calibration_cov)
    if failure is not None:
        return finish(failure)
    for wheel, text in size_mismatches({w: o.circle.radius_m for w, o in observations.items()}, AXLE_PARTNER):
        result.warn(f"{wheel} ({', '.join(observations[wheel].cams)}): {text}", WarningFlag("rim_size", wheel))
    t2 = time.perf_counter()
    fits = {w: (o.circle if method == "circle" else o.paper) for w, o in observations.items()}
    fill_angles(result, fits, observations, config)
    _pair_warnings(result, observations, config)
    centreline_warnings(result)
    timing["angles"] = time.perf_counter() - t2
    result.method = method
    result.observations = observations  # for recordings and station live; not in the JSON
    failure = refuse_uncertain_wheels(result, observations, config) if refuse_uncertain else None
    result.valid = failure is None
    return finish(failure)


def _measure_wheels(images: dict, cameras: dict, config: StationConfig, workers, calibration_cov: dict | None) -> list:
    """The four wheels' :class:`station.wheel.pair.WheelOutcome`, in WHEELS order: in the
    worker processes (the frames handed over in shared memory), else in two threads."""
    def tasks(frames):
        out = []
        for wheel in WHEELS:
            cams = (config.pairs[wheel].precision, config.pairs[wheel].reference)
            out.append((wheel, cams, {c: frames[c] for c in cams}, {c: cameras[c] for c in cams}, config,
                        (calibration_cov or {}).get(wheel)))
        return out

    if workers is not None:
        with FrameHandoff(images) as frames:
            return workers.map(measure_wheel, tasks(frames))
    with ThreadPoolExecutor(max_workers=2) as pool:  # overlap only where OpenCV and large numpy calls release the GIL
        return list(pool.map(lambda a: measure_wheel(*a), tasks(images)))


DOUBTFUL_RIM_KINDS = ("uncertain", "rim_size")  # warning kinds that put a wheel's rim centre in doubt


def centreline_warnings(result: Measurement) -> None:
    """Warn the other wheels when one wheel's rim is in doubt (``DOUBTFUL_RIM_KINDS`` among the
    result's ``warning_flags``): every toe is measured against the centreline through all four
    rim centres, so a rim found on the wrong contour turns the other wheels' toes as well (a
    knocked camera's wheel off by 9 mm moved the three others' toes 0.2 deg, each stated
    +/-0.015: bench/perturbed_images.py). Adds one text and a "centreline" flag per other wheel;
    nothing when a drift warning already puts the whole cycle in doubt."""
    if result.has_flag("drift"):
        return
    doubtful = [w for w in WHEELS if any(result.has_flag(kind, w) for kind in DOUBTFUL_RIM_KINDS)]
    others = [w for w in WHEELS if w not in doubtful]
    if not doubtful or not others:
        return
    result.warnings.append(
        f"{', '.join(others)}: toe is measured against the car's centreline through all four rim centres, "
        f"{' and '.join(doubtful)}'s among them, whose rim is in doubt (above); their toe may be off as well: "
        "resolve that and measure again before adjusting toe")
    result.warning_flags.extend(WarningFlag("centreline", w, because_of=doubtful) for w in others)


def fill_angles(result: Measurement, fits: dict[str, WheelFit], observations: dict, config: StationConfig,
                floors: bool = True) -> None:
    """The angles of the wheels ``fits`` (one WheelFit per wheel), their standard uncertainty
    and each wheel's 3-D rim, into ``result``. ``floors``: add each wheel's unseen variance
    (:func:`unseen_axis_variance`) and its views' disagreement (:func:`views_covariance`, of
    ``observations``) to its fit's axis covariance (False: the fits' covariances hold both
    already, as a spin axis fitted to several captures does)."""
    centers = {w: f.center_station for w, f in fits.items()}
    axes = {w: f.axis_station for w, f in fits.items()}
    angles = alignment.compute_angles(centers, axes)
    cov_c = {w: _finite_cov(f.cov_center, 1e-8) for w, f in fits.items()}
    # the floor: an error no single cycle's residuals show (a decision between arcs that a
    # new capture may take the other way, an edge bias the circle absorbs completely), in
    # quadrature across each axis, less in toe's direction than camber's (docs/measurement.md)
    cov_a = {w: _finite_cov(f.cov_axis, 1e-8) + (views_covariance(observations[w], config)
                                                  + unseen_axis_covariance(observations[w], f.axis_station, config)
                                                  if floors else 0.0)
             for w, f in fits.items()}
    cov = alignment.angle_covariance(centers, axes, cov_c, cov_a)
    std = dict(zip(ANGLE_NAMES, np.sqrt(np.clip(np.diag(cov), 0, None))))
    for w in WHEELS:
        f, o = fits[w], observations[w]
        a = angles["wheels"][w]
        det_l, det_r = o.detections
        result.wheels[w] = WheelResult(
            toe_deg=float(a["toe_deg"]), camber_deg=float(a["camber_deg"]),
            toe_thrust_deg=float(a["toe_thrust_deg"]) if "toe_thrust_deg" in a else None,
            toe_std_deg=float(std[f"{w}.toe"]), camber_std_deg=float(std[f"{w}.camber"]),
            center_station_m=f.center_station.tolist(), axis_station=f.axis_station.tolist(),
            rim_radius_m=float(f.radius_m),
            quality=WheelQuality(score=float(min(det_l.score, det_r.score)), points_left=int(len(det_l.points_px)),
                                 points_right=int(len(det_r.points_px)),
                                 epipolar_rms_px=float(o.circle.epipolar_rms_px),
                                 reprojection_rms_px=float(o.circle.reprojection_rms_px),
                                 grazing_left_out=bool(o.circle.grazing_left_out),
                                 arcs_left_out=bool(o.circle.arcs_left_out),
                                 faint_left_out=bool(o.circle.faint_left_out),
                                 other_contour_mm=(None if o.circle.other_contour_mm is None
                                                   else round(float(o.circle.other_contour_mm), 2)),
                                 view_disagreement_deg=(None if o.views is None else round(o.views.angle_deg, 4))))
    for axle in AXLES:
        a = {k: float(v) for k, v in angles["axles"][axle].items()}
        result.axles[axle] = AxleResult(**a, total_toe_std_deg=float(std[f"{axle}.total_toe"]))
    result.thrust_deg = float(angles["thrust_deg"])
    result.thrust_std_deg = float(std["thrust"])
    result.wheelbase_m = angles["wheelbase_m"]
    result.centreline_deg = angles["centreline_deg"]
    result.paper_front_angles_deg = alignment.paper_front_angles(centers, axes)
    result.alignment_frame = {"origin_station_m": np.mean([centers[w] for w in WHEELS], axis=0).tolist(),
                              "R_station_align": angles["R_station_align"].tolist()}


def _pair_warnings(result: Measurement, observations: dict, config: StationConfig) -> None:
    """Per wheel: whether this cycle could check the pair's calibration (the epipolar residual:
    a moved camera, or tangents extrapolated where a camera did not see the rim)."""
    limit = config.measurement.epipolar_limit_px
    for w in WHEELS:
        o = observations[w]
        d = min(o.detections, key=lambda det: det.coverage)
        if unverifiable_epipolar(o, config) and d.coverage < FULL_VIEW_COVERAGE:
            result.warn(
                f"pair {w} ({o.cams[0]}, {o.cams[1]}): {d.camera_id or 'a camera'} sees the rim edge on only "
                f"{d.coverage:.0%} of its perimeter, too little to check the pair's calibration this cycle "
                f"(epipolar residual {o.circle.epipolar_rms_px:.1f} px from extrapolated tangents; one 3-D circle "
                f"fits both views within {max(o.circle.view_median_px):.2f} px); if this persists, look at "
                f"{d.camera_id or 'the camera'}'s image (lighting, the tyre or the wheel arch hiding the rim) and recalibrate",
                WarningFlag("unchecked", w))
        elif o.circle.epipolar_rms_px > limit and not np.max(o.circle.tangent_gap_deg) <= TANGENT_GAP_DEG:
            # the epipolar planes touch the rim where a camera did not see it: the tangents
            # there are extrapolated, and their disagreement is no evidence that a camera moved
            gaps = np.nan_to_num(np.asarray(o.circle.tangent_gap_deg, float), nan=360.0)
            k = int(np.argmax(gaps))
            where = f"nearest edge point {gaps[k]:.0f} deg of the rim away" if gaps[k] < 360 else "no tangent point found"
            result.warn(
                f"pair {w} ({o.cams[0]}, {o.cams[1]}): {o.cams[k]} did not see the rim where the epipolar planes "
                f"touch it ({where}), too little "
                f"to check the pair's calibration this cycle (epipolar residual {o.circle.epipolar_rms_px:.1f} px "
                f"from extrapolated tangents); if this persists on well-lit, fully visible rims, recalibrate",
                WarningFlag("unchecked", w))
        elif o.circle.epipolar_rms_px > limit:
            result.warn(
                f"pair {w} ({o.cams[0]}, {o.cams[1]}): epipolar residual {o.circle.epipolar_rms_px:.2f} px "
                f"> {limit} px: a camera of this pair may have moved since calibration; recalibrate. Every "
                f"wheel's toe is taken against the car frame this wheel's centre helps define: treat the whole "
                f"cycle as suspect until then", WarningFlag("drift", w))


def _finite_cov(c: np.ndarray, fallback_var: float) -> np.ndarray:
    c = np.asarray(c, float)
    return c if np.all(np.isfinite(c)) else np.eye(3) * fallback_var


def _detections_where(detections: dict, test) -> list[tuple[str, object]]:
    """[(camera id, RimDetection)] of the cameras whose detection (not an error) passes ``test``."""
    return [(cid, d) for cid, d in detections.items() if not isinstance(d, StationError) and test(d)]


SMALLER_THAN_OTHERS = 0.6  # a rim this share of the other cameras' (median) is another contour, not a far rim


def _small_rim_warnings(detections: dict, config: StationConfig) -> list[tuple[str, str]]:
    """A warning per camera whose rim ellipse is smaller than ``measurement.min_rim_axis_px``
    (semi-major axis, px). The edge model's windows are in pixels, made for a flange a few
    pixels wide: on the simulator, rims of 125-175 px (640x512 cameras) gave toe errors of
    0.78 deg RMS, rims of 190-260 px 0.08, of 250-350 px 0.03-0.04 (docs/rim-detection.md,
    "Known limits"; the figures in docs/history/rim-detection.md). The station's cameras see
    their wheels from about the same distance: a "rim" under ``SMALLER_THAN_OTHERS`` of the
    other cameras' (their median, three or more) is more likely the hub, a hubcap's ring or the
    lip's inner edge than a rim too far away (on black rims, which the detector does not find,
    83-90 px against the other cameras' 170), and the warning says so instead of asking for a
    longer lens."""
    limit = config.measurement.min_rim_axis_px
    sizes = {cid: float(d.ellipse.axes_px[0]) for cid, d in _detections_where(detections, lambda d: True)}
    out = []
    for cid, a in sizes.items():
        if a >= limit:
            continue
        others = [v for c, v in sizes.items() if c != cid]
        typical = float(np.median(others)) if len(others) >= 3 else 0.0
        head = f"{config.cameras[cid].wheel} {cid}: the rim spans only {a:.0f} px (semi-major axis; "
        if a < SMALLER_THAN_OTHERS * typical:
            out.append((cid, head + f"the other cameras' rims {typical:.0f} px): {cid} may have taken the hub, a "
                                    f"hubcap's ring or the lip's inner edge instead of the rim; {DARK_RIM_NOTE}"))
        else:
            out.append((cid, head + f"limit {limit:.0f} px, 250 or more measure best): its toe and camber are less "
                                    f"accurate; use a longer lens or a higher resolution, or bring {cid} closer to the "
                                    "wheel"))
    return out


def _soft_focus_warnings(detections: dict, config: StationConfig) -> list[tuple[str, str]]:
    """A warning per camera whose rim edge is blurred beyond ``measurement.edge_blur_limit_px``
    (the detector's estimate, ``details["blur_px"]``): a lens out of focus or a moving wheel.
    The detector copes (its windows grow with the blur), but such a station measured on the
    simulator is several times less accurate (docs/accuracy.md, "Outside the envelope")."""
    limit = config.measurement.edge_blur_limit_px
    return [(cid, f"{config.cameras[cid].wheel} {cid}: the rim edge is blurred over {d.details['blur_px']:.1f} px "
                  f"(limit {limit} px; a focused camera gives about 1): refocus {cid}'s lens and check that the "
                  f"car stood still; its toe and camber are less accurate until then")
            for cid, d in _detections_where(detections, lambda d: (d.details.get("blur_px") or 0.0) > limit)]


def _white_edge_warnings(detections: dict, config: StationConfig) -> list[tuple[str, str]]:
    """A warning per camera whose rim edge reaches the sensor's white on more than
    ``measurement.white_edge_limit`` of the rim (``details["white_share"]``, station/rim/
    white_edge.py): a cut-off edge profile puts the edge toward the tyre, by half a pixel where
    the metal would be twice the white (simulated station, exposure 1.5x too long: toe 0.038
    deg RMS instead of 0.026; 2x: 0.072)."""
    limit = config.measurement.white_edge_limit
    return [(cid, f"{config.cameras[cid].wheel} {cid}: the rim edge reaches the sensor's white on "
                  f"{d.details['white_share']:.0%} of the rim (limit {limit:.0%}): shorten {cid}'s exposure or "
                  f"lower its gain; its toe and camber are less accurate until then")
            for cid, d in _detections_where(detections, lambda d: d.details.get("white_share", 0.0) > limit)]


def _detection_summary(detections: dict) -> dict[str, CameraDetection]:
    out = {}
    for cid, d in detections.items():
        if isinstance(d, StationError):
            out[cid] = CameraDetection(ok=False, reason=str(d))
        else:
            e = d.ellipse
            out[cid] = CameraDetection(ok=True, center_px=np.asarray(e.center_px).tolist(),
                                       axes_px=np.asarray(e.axes_px).tolist(), angle_deg=float(np.degrees(e.angle_rad)),
                                       score=float(d.score), coverage=float(d.coverage), points=int(len(d.points_px)),
                                       white_share=float(d.details.get("white_share", 0.0)),
                                       metal_side_dark_share=float(d.details.get("metal_side_dark_share", 0.0)))
    return out
