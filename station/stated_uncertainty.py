"""What a wheel's stated uncertainty holds beyond its circle fit, and the wheels stated beyond
``measurement.uncertainty_limit_deg``.

* :func:`unseen_axis_covariance` - what no single cycle's residuals show, grown with how unevenly
  the lip is lit, how noisy its edge and how blurred it is; :func:`views_covariance` - the
  pair's two views' disagreement about the rim's axis, and :func:`views_bound_covariance` - the
  bound on it a wheel is refused by;
* :func:`statement_parts` - a wheel's stated toe or camber split into its parts;
* :func:`refuse_uncertain_wheels` - the cycle's failure naming each wheel stated beyond the
  limit, why (the largest part) and what to do (docs/measurement.md, "Too uncertain to trust").
"""

from __future__ import annotations

import numpy as np

from calibration.station_frame import WHEELS
from station.config import StationConfig
from station.errors import WheelUncertain
from station.result import Failure, Measurement, WarningFlag
from station.wheel.pair import FULL_VIEW_COVERAGE, WheelObservation, kept_fractions
from station.wheel.view_agreement import disagreement_bound_covariance, disagreement_covariance


def unseen_axis_variance(o: WheelObservation, config: StationConfig) -> float:
    """The variance (rad^2) added across a wheel's axis for what no single cycle's residuals
    show: ``measurement.uncertainty_floor_deg`` squared, plus (``uncertainty_light_gain`` l)
    (l m q / a)^2, m the lip's step modulation round the rim (:func:`mean_step_modulation`), q
    the circle's reprojection RMS (px) and a the rim's mean semi-axis in its two views (px), plus
    (``uncertainty_blur_gain`` g) (g e / a)^2, e the blur beyond ``edge_blur_limit_px`` of the
    blurrier view (px, :func:`blur_excess_px`). A lamp on one side leaves the lip's rounding
    shaded on the other, where the step is faint; there the noise decides whole arcs (which
    stay, which edge model they take) and moves their edge: a bias the residuals do not show,
    as large as the light is uneven and the edges are noisy (docs/measurement.md, "Uncertainty
    of every angle"). A lens out of focus widens the edge model's windows, which then take in
    the lip's neighbouring contours (its inner edge, the tyre's bead): a bias that grows with
    the blur."""
    m = config.measurement
    q = o.circle.reprojection_rms_px
    a = float(np.mean([np.sqrt(np.prod(d.ellipse.axes_px)) for d in o.detections]))
    if not a > 0:
        return float(np.radians(m.uncertainty_floor_deg) ** 2)
    light = m.uncertainty_light_gain * mean_step_modulation(o) * q / a if np.isfinite(q) else 0.0
    blur = m.uncertainty_blur_gain * blur_excess_px(o, m.edge_blur_limit_px) / a
    return float(np.radians(m.uncertainty_floor_deg) ** 2 + light ** 2 + blur ** 2)


def mean_step_modulation(o: WheelObservation) -> float:
    """The mean over a wheel's two views of how unevenly the lip's edge step is lit round the
    rim (the detector's ``details["step_modulation"]``, station/rim/subpixel.py)."""
    return float(np.mean([d.details.get("step_modulation") or 0.0 for d in o.detections]))


def blur_excess_px(o: WheelObservation, limit_px: float) -> float:
    """How far (px) the blurrier of a wheel's two views is blurred beyond ``limit_px``
    (``measurement.edge_blur_limit_px``), 0 for views within it (:func:`blurred_views`)."""
    return float(max((b - limit_px for b in blurred_views(o, limit_px).values()), default=0.0))


def blurred_views(o: WheelObservation, limit_px: float) -> dict[str, float]:
    """{camera: its edge blur (px, the detector's ``details["blur_px"]``)} of a wheel's views
    blurred beyond ``limit_px``: cameras warned to be refocused (station/measure.py)."""
    blur = {c: d.details.get("blur_px") or 0.0 for c, d in zip(o.cams, o.detections)}
    return {c: float(b) for c, b in blur.items() if b > limit_px}


def unseen_axis_covariance(o: WheelObservation, axis_station: np.ndarray, config: StationConfig) -> np.ndarray:
    """(3,3) the unseen variance (:func:`unseen_axis_variance`) across the unit axis (3,), shaped
    by :func:`unseen_axis_shape`."""
    return unseen_axis_variance(o, config) * unseen_axis_shape(axis_station, config.measurement.uncertainty_toe_scale)


def views_covariance(o: WheelObservation, config: StationConfig) -> np.ndarray:
    """(3,3) what the pair's two views' disagreement about the rim's axis adds to it
    (station/wheel/view_agreement.py). A procedure of several captures adds it to the axis it
    finds from the lip, not to each capture: the arc a view sees off the edge stays where the
    light puts it while the wheel rolls or steers, so it weighs every capture alike."""
    return disagreement_covariance(o.views, config.measurement.view_edge_bias_px)


def views_bound_covariance(o: WheelObservation, config: StationConfig) -> np.ndarray:
    """(3,3) the bound on :func:`views_covariance` a wheel is refused by
    (station/wheel/view_agreement.py, ``disagreement_bound_covariance``)."""
    return disagreement_bound_covariance(o.views, config.measurement.view_edge_bias_px)


def unseen_axis_shape(axis_station: np.ndarray, toe_scale: float) -> np.ndarray:
    """(3,3) shape of the unseen variance across a wheel's unit axis (3,): 1 along the
    direction that tilts the axis up or down (camber), ``toe_scale`` squared along the
    horizontal one (toe; ``measurement.uncertainty_toe_scale``). The pair's baseline is
    horizontal: toe shows in the disparity across the rim's vertical edges, which the epipolar
    lines cross (modes 0 and cos 2phi of the rim angle), and in each view's aspect ratio;
    camber only in the sin-2phi mode of the two views' difference, where an edge bias of the
    same size moves the axis further (docs/measurement.md)."""
    a = np.asarray(axis_station, float)
    a = a / np.linalg.norm(a)
    tilts = tilt_directions(a)
    if tilts is None:  # an axis straight up: no toe direction to tell apart
        return np.eye(3) - np.outer(a, a)
    e_toe, e_camber = tilts
    return toe_scale ** 2 * np.outer(e_toe, e_toe) + np.outer(e_camber, e_camber)


def tilt_directions(axis_station: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(e_toe, e_camber), unit (3,) each: the directions across a wheel's axis (3,) that turn it
    in toe (horizontal) and tilt it in camber (up or down); None for an axis straight up."""
    a = np.asarray(axis_station, float)
    a = a / np.linalg.norm(a)
    e_toe = np.cross([0.0, 0.0, 1.0], a)
    if np.linalg.norm(e_toe) < 1e-9:
        return None
    e_toe /= np.linalg.norm(e_toe)
    return e_toe, np.cross(a, e_toe)


# why a wheel is stated beyond the limit, as its ``uncertain`` flag's ``reason`` says it (the PLC's
# uncertain_reasons codes them, station/plc/register_map.py): its views disagree, one lip at the
# sensor's white, or on arcs no brighter than the tyre, or the fainter; its edge wavers round
# the rim beyond its noise; its edge is faint or noisy; the calibration's share
UNCERTAIN_REASONS = ("white_lip", "dark_lip", "faint_view", "uneven_edge", "faint_edge", "calibration")


def refuse_uncertain_wheels(result: Measurement, observations: dict, config: StationConfig) -> Failure | None:
    """The failure of a cycle with a wheel whose toe or camber is less certain than
    ``measurement.uncertainty_limit_deg``: a value that uncertain is no use for aligning, and a
    wrong value reported as valid is the worst outcome for a technician. The message names every
    such wheel and why (the largest part of its statement: its two cameras disagree about the
    rim's axis, its edge wavers round the rim, its edge is faint, or the calibration), the hint
    what to do about it; each such wheel is flagged ``uncertain``."""
    limit = config.measurement.uncertainty_limit_deg
    refused = []
    for w in WHEELS:
        r = result.wheels[w]
        worst = max(((a, _bounded_std_deg(observations[w], a, std, config))
                     for a, std in (("toe", r.toe_std_deg), ("camber", r.camber_std_deg))), key=lambda kv: kv[1])
        if worst[1] > limit:
            refused.append((w, worst))
    if not refused:
        return None
    texts, hints = [], []
    for w, (name, std) in refused:
        text, hint, reason = _why_uncertain(observations[w], name, std, config)
        result.warning_flags.append(WarningFlag("uncertain", w, text=f"{w}: {text}", reason=reason))
        texts.append(f"{w}: {name} +/-{std:.3f} deg, {text}")
        hints.append(hint)
    wheels = [w for w, _ in refused]
    camera = "+".join(observations[wheels[0]].cams)
    return Failure(WheelUncertain.code,
                   f"{', '.join(wheels)} less certain than the {limit} deg uncertainty limit ({'; '.join(texts)}); "
                   "no angle of this cycle is reported", " ".join(dict.fromkeys(hints)) + " Then measure again.",
                   wheels[0] if len(wheels) == 1 else ",".join(wheels), camera)


def _angle_direction(axis_station: np.ndarray, angle: str) -> np.ndarray | None:
    """(3,) the direction across the unit axis (3,) that turns it in ``angle`` ("toe" or
    "camber", :func:`tilt_directions`), or None where they are undefined."""
    tilts = tilt_directions(axis_station)
    return None if tilts is None else tilts[0] if angle == "toe" else tilts[1]


def _bounded_std_deg(o: WheelObservation, angle: str, std_deg: float, config: StationConfig) -> float:
    """A wheel's stated ``angle`` ("toe" or "camber") ``std_deg`` with its views' share
    (:func:`views_covariance`) raised to the bound (:func:`views_bound_covariance`): what the
    wheel is refused by."""
    d = _angle_direction(o.circle.axis_station, angle)
    if d is None:
        return std_deg
    extra = float(d @ (views_bound_covariance(o, config) - views_covariance(o, config)) @ d)  # rad^2
    return float(np.sqrt(std_deg ** 2 + np.degrees(np.sqrt(max(extra, 0.0))) ** 2))


def _why_uncertain(o: WheelObservation, angle: str, std_deg: float, config: StationConfig) -> tuple[str, str, str]:
    """(why the wheel's ``angle`` ("toe" or "camber") is stated ``std_deg``, what to do, which of
    ``UNCERTAIN_REASONS``), from the largest part of that statement (:func:`statement_parts`):
    the views' disagreement, naming the camera whose edge is off (:func:`_edge_off`); an edge
    that wavers round the rim beyond its noise, naming the camera whose edge wavers
    (:func:`_wavering`); the edges' noise, naming the fainter edge and a camera whose edge
    points the 3-D rim rests on only in part; or the calibration."""
    parts = statement_parts(o, angle, config, bound=True)
    main = max(parts, key=parts.get)
    if parts[main] <= 0.0 or (main == "views" and o.views is None):  # no part stated: the fit itself is in doubt
        main = "edge"
    share = f"+/-{np.sqrt(parts[main]):.3f} deg on its own"
    if main == "views":
        why, hint, reason = _edge_off(o, config)
        return (f"its cameras {o.cams[0]} and {o.cams[1]} each see the rim's axis differently, by "
                f"{o.views.angle_deg:.2f} deg: one of them sees the rim's edge off on part of the rim ({why})", hint,
                reason)
    if main == "calibration":
        return (f"the calibration of {o.cams[0]} and {o.cams[1]} is uncertain here ({share})",
                f"Calibrate again (station calibrate), the box shown across the whole view of {o.cams[0]} and "
                f"{o.cams[1]}.", "calibration")
    cam = _fainter(o)
    if main == "edge":
        cams = _wavering(o)
        where = f"most in {cams[0]}" if len(cams) == 1 else f"in {cams[0]} and {cams[1]} alike"
        return (f"the lip's edge wavers round the rim beyond its noise, {where} ({share}): an edge that uneven may "
                f"be off the lip on whole arcs",
                f"Look at the rim's lip in {' and '.join(cams)}: clean the lip (brake dust, dirt), shade it from "
                f"direct sun and light it evenly; on a glossy lip the lamps it mirrors move its edge: dim or move "
                f"them, or light the wheel with a diffuse panel.", "uneven_edge")
    kept = kept_fractions(o)
    weak = o.cams[int(np.argmin(kept))]
    why = (f"the lip's edge is faint or noisy: the 3-D rim's points lie {o.circle.reprojection_rms_px:.2f} px rms "
           f"off it, the fainter edge {cam}'s ({share})")
    hint = f"Light the rim or give {cam} a longer exposure, check its focus, and clean the lip."
    blurred = blurred_views(o, config.measurement.edge_blur_limit_px)
    if blurred:
        why += "; " + " and ".join(f"{c}'s edge is blurred over {b:.1f} px" for c, b in blurred.items())
        why += f", beyond the {config.measurement.edge_blur_limit_px} px focus limit"
        hint = f"Refocus {' and '.join(blurred)} and check that the car stood still. " + hint
    if min(kept) < FULL_VIEW_COVERAGE:
        why += f"; the 3-D rim rests on {min(kept):.0%} of {weak}'s edge points"
        hint += f" Check that {weak} sees the whole rim (wheel position, tyre, arch)."
    return why, hint, "faint_edge"


def statement_parts(o: WheelObservation, angle: str, config: StationConfig, bound: bool = False) -> dict[str, float]:
    """What makes up a wheel's stated ``angle`` ("toe" or "camber"): variance (deg^2) along
    the direction that turns its axis in that angle, per part: "views" (their disagreement,
    :func:`views_covariance`, or with ``bound`` :func:`views_bound_covariance`), "calibration"
    (the calibration's share), "noise" (the points' noise and the unseen share,
    :func:`unseen_axis_covariance`) and "edge" (the rest of the fit's: the edge biases that
    vary slowly round the rim, and fits with and without some arcs that disagree). A procedure's
    spin axis states its own covariance; its capture's parts still say which part dominates."""
    c = o.circle
    d = _angle_direction(c.axis_station, angle)
    if d is None:
        return {"edge": 1.0}

    def along(cov) -> float:
        with np.errstate(invalid="ignore"):  # a fit stating inf: nan, counted as no part
            return float(d @ np.asarray(cov, float) @ d) if cov is not None else 0.0

    fit, noise = along(c.cov_axis), along(c.cov_axis_noise)
    calibration = c.calibration_share[1] / 2 if c.calibration_share else 0.0  # its trace over both directions
    views = views_bound_covariance(o, config) if bound else views_covariance(o, config)
    parts = {"views": along(views), "calibration": calibration,
             "noise": noise + along(unseen_axis_covariance(o, c.axis_station, config)),
             "edge": max(fit - noise - calibration, 0.0)}
    return {k: (float(np.degrees(np.sqrt(max(v, 0.0))) ** 2) if np.isfinite(v) else float("inf") if v > 0 else 0.0)
            for k, v in parts.items()}


WAVERING_RATIO = 2.0  # one camera's edge-bias part this many times its partner's: that camera's edge wavers


def _wavering(o: WheelObservation) -> list[str]:
    """The camera whose own edge-bias part (``cov_axis_bias_views``) is ``WAVERING_RATIO``
    times its partner's, else both: on glossy rims both views' edges move with the lamps they
    mirror, and which one is off more is a toss-up (bench/refusal_naming.py)."""
    own = o.circle.cov_axis_bias_views
    if own is None or len(own) != 2:
        return list(o.cams)
    size = [float(np.trace(c)) for c in own]
    k = int(np.argmax(size))
    return [o.cams[k]] if size[k] > WAVERING_RATIO * size[1 - k] else list(o.cams)


def _fainter(o: WheelObservation) -> str:
    """The camera of the pair whose edge steps least (median of its points' steps)."""
    steps = [float(np.median(d.points_contrast)) if d.points_contrast is not None and len(d.points_contrast)
             else float("nan") for d in o.detections]
    return o.cams[int(np.nanargmin(steps))] if not np.all(np.isnan(steps)) else o.cams[0]


def _edge_off(o: WheelObservation, config: StationConfig) -> tuple[str, str, str]:
    """(why, what to do, which of ``UNCERTAIN_REASONS``) for a disagreeing pair, naming the
    cameras whose edge is likely off
    from what each detection measured of its own edge: the one whose lip is at the sensor's
    white on more of the rim than its partner's by ``measurement.white_edge_limit`` (the edge
    read toward the tyre; a polished lip mirroring lamps puts both at the white in spots),
    else those with arcs whose bright side is not the rim's metal (a tyre lit past a shaded
    lip, a dirty lip, a glossy lip mirroring something dark: station/rim/metal_side.py; both
    where both show it, the larger share first), else the blurrier one beyond the focus limit
    (:func:`blurred_views`), else the one with the fainter edge."""
    white = {c: float(d.details.get("white_share", 0.0)) for c, d in zip(o.cams, o.detections)}
    dark = {c: float(d.details.get("metal_side_dark_share", 0.0)) for c, d in zip(o.cams, o.detections)}
    whiter, other = sorted(o.cams, key=lambda c: -white[c])
    if white[whiter] - white[other] > config.measurement.white_edge_limit:
        return (f"the lip is at the sensor's white on {white[whiter]:.0%} of {whiter}'s rim, which moves the edge "
                f"toward the tyre",
                f"Shorten {whiter}'s exposure (or its gain), or shade the wheel from the sun or the lamp that drives "
                f"the lip to white.", "white_lip")
    if max(dark.values()) > 0.0:
        cams = sorted((c for c in o.cams if dark[c] > 0.0), key=lambda c: -dark[c])
        shares = " and ".join(f"{dark[c]:.0%} of {c}'s" for c in cams)
        names = " and ".join(cams)
        return (f"on {shares} rim the lip is no brighter than the tyre beside it, so the edge found there is not "
                f"the rim's",
                f"Look at the rim in {names}: a lamp or the sun at the side lights the tyre past a shaded lip, the "
                f"lip is dirty there, or a glossy lip mirrors something dark. Shade the wheel from that light or "
                f"light it evenly (a diffuse panel), and clean the lip.", "dark_lip")
    blurred = blurred_views(o, config.measurement.edge_blur_limit_px)
    if blurred:
        cam = max(blurred, key=blurred.get)
        return (f"{cam}'s edge is blurred over {blurred[cam]:.1f} px, beyond the "
                f"{config.measurement.edge_blur_limit_px} px focus limit",
                f"Refocus {' and '.join(blurred)} and check that the car stood still.", "faint_view")
    cam = _fainter(o)
    return (f"the fainter edge is {cam}'s",
            f"Look at {cam}'s image of the rim's lip: clean the lip (brake dust, dirt), shade it from direct "
            f"sun, light it, or give {cam} a longer exposure if the rim is dark. On a glossy lip (clear-coated "
            f"dark paint, polish, chrome) the lamps it mirrors move its edge: dim or move the lamps whose "
            f"reflections sit on the lip, or light the wheel with a diffuse panel.", "faint_view")
