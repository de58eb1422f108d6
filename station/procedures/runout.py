"""Runout compensation by rolling: toe and camber of the wheels' spin axes, not of their rims.

The car is rolled back and forward along the runways while the cameras take it at a few
positions (``ROLL_PLAN``, the last where it started). At each capture every wheel's rim gives its
3-D circle (the normal of its lip plane) and its face's angular profile; the profiles tell how far
each wheel turned between the captures (station/wheel/rim_pattern.py), and the normals turned by
those angles fix each wheel's spin axis (station/wheel/runout.py), joined with the axis of the
face's own rigid motion (station/wheel/face_motion.py: the lip's edge moves with the view, the
face's points do not); the lip centres turning about the hubs fix where each hub is
(station/wheel/hub_center.py). The result is the last capture's
measurement with the spin axes in place of the rim normals and the car frame on the hubs, each
wheel's runout beside.

Refused, with a code (station/errors.py 411-414): a roll too short to turn the wheels
``MIN_ROLL_DEG``; a wheel whose turn does not match the car's travel (it slipped, or was turned
by hand); a car that moved across the runways or turned; a rim whose face cannot be followed.
A runout beyond ``measurement.runout_limit_deg`` is measured and compensated but warned of (a
bent rim).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibration.camera_model import CameraModel
from calibration.station_frame import SIDE, WHEELS
from station.config import StationConfig
from station.errors import CarMovedSideways, RimPatternLost, RollTooShort, WheelSlipped
from station.measure import fill_angles
from station.procedures.poses import face_pose, normal_covariance
from station.result import Measurement, WarningFlag
from station.rim.camera_response import linear_images
from station.stated_uncertainty import refuse_uncertain_wheels
from station.wheel.rim_pattern import FacePose, angular_profile, face_depth, rotation_between
from station.wheel.face_motion import face_spin_axis, with_face
from station.wheel.hub_center import hub_centers
from station.wheel.runout import SpinAxis, fit_spin_axis
from station.wheel.view_agreement import ViewAgreement, disagreement_bound_covariance

ROLL_DISTANCE_M = 0.15         # how far the car is rolled each way: about 25 deg of a wheel's turn
ROLL_PLAN = (0.0, -1.0, -0.5, 0.5, 1.0, 0.0)  # where the car stands at each capture, in roll distances; the last is the
#                                                result's; the stops between the ends see the lip from views of their own
MIN_POSITIONS = 4              # a position whose measurement failed is left out while this many remain
TYRE_BEYOND_LIP_M = 0.10       # a rolling radius to expect from the lip's (only to tell a rim's N-fold symmetry apart)
MIN_ROLL_DEG = 10.0            # the captures must turn every wheel through at least this
MIN_PATTERN_PEAK = 0.7         # a face followed from one capture to another correlates at least this well
PATTERN_AGREEMENT_DEG = 0.5    # and both cameras of the pair agree on its turn within this,
FALLBACK_DEG = 1.0             # else the one within this of the turn the car's travel predicts is taken
SLIP_SHARE = 0.04              # a wheel's rolling radius (its centre's travel over its turn) off the car's by more: slipped
SIDEWAYS_M = 0.015             # a wheel centre off the line of the car's travel by more: the car moved across or turned


@dataclass(frozen=True)
class WheelRoll:
    """One wheel over the captures: its spin axis fit, the turn at each capture (deg, relative to
    the last), its rolling radius (m, NaN when it hardly turned), its face's depth behind the lip,
    its lip centre's offset from its hub at the last capture (3,) m and that offset's (3,3)
    covariance (station/wheel/hub_center.py); the face points whose motion joined the lip's spin
    axis (station/wheel/face_motion.py; 0: the lip's alone)."""

    spin: SpinAxis
    roll_deg: np.ndarray
    rolling_radius_m: float
    face_depth_m: float
    hub_offset_station: np.ndarray
    cov_hub_offset: np.ndarray
    face_points: int = 0
    views: ViewAgreement | None = None


def wheel_rolls(results: list[Measurement], images: list[dict], models: dict[str, CameraModel],
                config: StationConfig) -> dict[str, WheelRoll]:
    """Each wheel's spin axis from valid measurements ``results`` (K, with their observations)
    of the captures ``images`` (K dicts of camera -> image), the last one the reference.
    Raises RimPatternLost, RollTooShort, WheelSlipped or CarMovedSideways naming the wheel."""
    linear = [linear_images(im, config) for im in images]
    forward = np.asarray(results[-1].alignment_frame["R_station_align"])[:, 1]
    seen = {w: _follow(w, results, linear, models, config, forward) for w in WHEELS}
    radius = _car_rolling_radius(seen)
    views = {w: _typical_views([r.observations[w] for r in results]) for w in WHEELS}
    spins, turns, own, face_points = {}, {}, {}, {}
    for w, f in seen.items():
        theta = _turns(w, f, radius)
        _check_travel(w, f.poses, forward)
        if np.degrees(np.ptp(theta)) < MIN_ROLL_DEG:
            raise RollTooShort(f"{w}: the captures turned the wheel through only {np.degrees(np.ptp(theta)):.1f} deg "
                               f"(at least {MIN_ROLL_DEG:.0f} needed to find its spin axis)",
                               hint=f"roll the car about {ROLL_DISTANCE_M * 100:.0f} cm each way when asked")
        cov = np.array([normal_covariance(r, w, config) for r in results])
        spins[w] = lip_spin_axis(np.array([p.axis_station for p in f.poses]), theta, cov, f.poses[-1].radius_m,
                                 views[w], config.measurement.view_edge_bias_px)
        cams = (config.pairs[w].precision, config.pairs[w].reference)
        face = face_spin_axis([(im[cams[0]], im[cams[1]]) for im in linear], (models[cams[0]], models[cams[1]]),
                              f.poses, theta)
        joined = None if face is None else with_face(spins[w], face, f.poses[-1].radius_m)  # or the lip's alone
        face_points[w] = 0 if joined is None else face.points
        spins[w] = joined or spins[w]
        turned = np.abs(theta) > np.radians(MIN_ROLL_DEG / 2)
        own[w] = float(np.median(-SIDE[w] * f.travel[turned] / theta[turned])) if turned.any() else float("nan")
        _check_each_turn(w, theta, f.travel, own[w])
        turns[w] = theta
    _check_slip(own)
    hubs = hub_centers(np.array([[p.center_station for p in seen[w].poses] for w in WHEELS]),
                       np.array([turns[w] for w in WHEELS]), np.array([spins[w].axis_station for w in WHEELS]),
                       forward)
    return {w: WheelRoll(spins[w], np.degrees(turns[w]), own[w], seen[w].depth, hubs.offset_station[i],
                         hubs.cov_offset[i], face_points[w], views[w])
            for i, w in enumerate(WHEELS)}


def lip_spin_axis(normals_station: np.ndarray, theta_rad: np.ndarray, cov_normals: np.ndarray, radius_m: float,
                  views: ViewAgreement | None, edge_bias_px: float) -> SpinAxis:
    """The spin axis the lip's normals (K,3) at the turns ``theta_rad`` (K,) give, with their
    (K,3,3) covariances (station/wheel/runout.py), its covariance holding the disagreement of
    the typical capture's two views (``views``, beyond what ``edge_bias_px`` explains,
    station/wheel/view_agreement.py): a bias of the lip's edge that stays where the light puts
    it, alike at every capture, which the face's own motion does not share; joined with the
    face's axis, a lip whose views disagree weighs that much less. The procedure takes the
    disagreement's bound (``disagreement_bound_covariance``, what a single capture is refused
    by): with it the compensated angles state 0.91-0.99 of their error (docs/procedures.md)."""
    spin = fit_spin_axis(normals_station, theta_rad, cov_normals, radius_m)
    return replace(spin, cov_axis=spin.cov_axis + disagreement_bound_covariance(views, edge_bias_px))


def _typical_views(observations: list) -> ViewAgreement | None:
    """The views' agreement (station/wheel/view_agreement.py) of the capture whose two views
    disagree the median amount among ``observations`` (one wheel's, K captures; the lower middle
    when K is even). An edge bias where the light puts it shows at every capture; one capture's
    edge decided the other way (new noise at the same place gives the usual agreement) is one
    normal of the several the spin axis rests on, and the face's axis checks it."""
    views = [o.views for o in observations if o.views is not None]
    if not views:
        return None
    return sorted(views, key=lambda v: v.angle_deg)[(len(views) - 1) // 2]


@dataclass(frozen=True)
class _Followed:
    """One wheel over the captures: its 3-D circles (K), its centre's travel along the car's
    forward (K,) m, its face's depth, and each camera's turn from the face (K, 2) rad with its
    correlation peak (K, 2)."""

    poses: list[FacePose]
    travel: np.ndarray
    depth: float
    turns: np.ndarray
    peaks: np.ndarray


def _follow(wheel: str, results: list[Measurement], linear: list[dict], models: dict[str, CameraModel],
            config: StationConfig, forward: np.ndarray) -> _Followed:
    cams = (config.pairs[wheel].precision, config.pairs[wheel].reference)
    poses = [face_pose(r, wheel) for r in results]
    depth, _ = face_depth({c: linear[-1][c] for c in cams}, models, poses[-1])
    reference = {c: angular_profile(linear[-1][c], models[c], poses[-1], depth) for c in cams}
    travel = np.array([(p.center_station - poses[-1].center_station) @ forward for p in poses])
    prior = -SIDE[wheel] * travel / (poses[-1].radius_m + TYRE_BEYOND_LIP_M)
    found = np.array([[rotation_between(reference[c], angular_profile(im[c], models[c], pose, depth), a) for c in cams]
                      for im, pose, a in zip(linear, poses, prior)])                     # (K, 2, 2)
    lost = np.nonzero((found[:, :, 1] < MIN_PATTERN_PEAK).all(axis=1))[0]
    if len(lost):
        k = lost[0]
        raise RimPatternLost(f"{wheel}: the rim's face does not match between captures in either camera (correlation "
                             f"{found[k, 0, 1]:.2f} and {found[k, 1, 1]:.2f}, at least {MIN_PATTERN_PEAK} needed): "
                             "a plain, dirty or covered face",
                             hint="clean the rim's face and measure again, or measure without --compensate")
    return _Followed(poses, travel, depth, found[:, :, 0], found[:, :, 1])


def _agree(f: _Followed) -> np.ndarray:
    """(K,) whether both cameras follow the face and agree on the wheel's turn at each capture."""
    return ((np.abs(np.degrees(f.turns[:, 0] - f.turns[:, 1])) <= PATTERN_AGREEMENT_DEG)
            & (f.peaks >= MIN_PATTERN_PEAK).all(axis=1))


def _car_rolling_radius(followed: dict[str, _Followed]) -> float:
    """The car's rolling radius (m): the median of every wheel's travel over its turn at the
    captures where both its cameras agree and it turned; NaN when there is none."""
    ratios = []
    for w, f in followed.items():
        theta = f.turns.mean(axis=1)
        use = _agree(f) & (np.abs(theta) > np.radians(MIN_ROLL_DEG / 2))
        ratios += list(-SIDE[w] * f.travel[use] / theta[use])
    return float(np.median(ratios)) if ratios else float("nan")


def _turns(wheel: str, f: _Followed, radius_m: float) -> np.ndarray:
    """(K,) the wheel's turn at each capture (rad): both cameras' mean where they agree; where
    they do not (one camera lost the face or sees it changed, a caliper through the spokes), the
    camera that follows the face and is nearer the turn the car's travel predicts over its
    rolling radius, if near enough."""
    theta = f.turns.mean(axis=1)
    for k in np.nonzero(~_agree(f))[0]:
        a, b = np.degrees(f.turns[k])
        predicted = np.degrees(-SIDE[wheel] * f.travel[k] / radius_m) if np.isfinite(radius_m) else np.nan
        followed = [t for t, peak in zip((a, b), f.peaks[k]) if peak >= MIN_PATTERN_PEAK]
        pick = min(followed, key=lambda t: abs(t - predicted)) if np.isfinite(predicted) else np.nan
        if not abs(pick - predicted) <= FALLBACK_DEG:
            raise RimPatternLost(f"{wheel}: its two cameras disagree on how far the wheel turned ({a:.2f} and {b:.2f} "
                                 f"deg), and the car's travel cannot tell which is right",
                                 hint="check both cameras' view of the rim's face and measure again")
        theta[k] = np.radians(pick)
    return theta


def compensated(reference: Measurement, rolls: dict[str, WheelRoll], config: StationConfig) -> Measurement:
    """``reference`` (the last capture's valid measurement) with each wheel's toe and camber of
    its spin axis, their uncertainty from the fit, and its runout; a warning per rim whose runout
    exceeds ``measurement.runout_limit_deg``."""
    return with_spin_axes(reference, {w: r.spin for w, r in rolls.items()}, config,
                          {w: (r.hub_offset_station, r.cov_hub_offset) for w, r in rolls.items()},
                          {w: r.views for w, r in rolls.items() if r.views is not None})


def with_spin_axes(reference: Measurement, spins: dict[str, SpinAxis], config: StationConfig,
                   hub_offsets: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
                   views: dict[str, ViewAgreement] | None = None) -> Measurement:
    """A copy of the valid ``reference`` whose angles are of the spin axes ``spins`` (one per
    wheel, with their covariance: it holds the normals' unseen share and the views' disagreement
    already), each wheel's runout beside; ``runout_compensated`` set; a warning per rim that runs
    out beyond the limit. With ``hub_offsets`` (per wheel: its lip centre's offset from its hub
    (3,) m and its (3,3) covariance), the car frame rests on the hubs instead of the lip centres.
    With ``views`` (per wheel: the views' agreement of its typical capture, ``_typical_views``)
    that, not the reference's, is reported with each wheel. A spin axis less certain than
    ``measurement.uncertainty_limit_deg`` makes it invalid, as a single capture's rim plane
    would (station.stated_uncertainty.refuse_uncertain_wheels)."""
    result = replace(reference, wheels={}, axles={}, warnings=list(reference.warnings),
                     warning_flags=list(reference.warning_flags), timing_s=dict(reference.timing_s))
    fits = {w: replace(o.circle, axis_station=spins[w].axis_station, cov_axis=spins[w].cov_axis)
            for w, o in reference.observations.items()}
    for w, (offset, cov) in (hub_offsets or {}).items():
        c = fits[w]
        fits[w] = replace(c, center_station=np.asarray(c.center_station, float) - offset,
                          cov_center=np.asarray(c.cov_center, float) + cov)
    observations = {w: replace(o, views=views[w]) if views and w in views else o
                    for w, o in reference.observations.items()}
    fill_angles(result, fits, observations, config, floors=False)
    limit = config.measurement.runout_limit_deg
    for w, s in spins.items():
        result.wheels[w] = replace(result.wheels[w], runout_deg=s.runout_deg, runout_phase_deg=s.runout_phase_deg,
                                   runout_mm=s.runout_mm)
        if s.runout_deg > limit:
            result.warn(f"{w}: its rim runs out {s.runout_deg:.2f} deg ({s.runout_mm:.1f} mm across the lip) against its "
                        f"spin axis, beyond the {limit} deg limit: a bent rim or a wheel seated askew on its hub; toe "
                        "and camber are of the spin axis, but check the rim and its mounting",
                        WarningFlag("runout", w))
    result.runout_compensated = True
    result.failure = refuse_uncertain_wheels(result, observations, config)
    result.valid = result.failure is None
    return result


def _check_travel(wheel: str, poses: list[FacePose], forward: np.ndarray) -> None:
    """CarMovedSideways when the wheel's centre left the line of the car's travel."""
    d = np.array([p.center_station - poses[-1].center_station for p in poses])
    across = d - np.outer(d @ forward, forward)
    off = float(np.max(np.linalg.norm(across[:, :2], axis=1)))
    if off > SIDEWAYS_M:
        raise CarMovedSideways(f"{wheel}: its centre moved {off * 1000:.0f} mm across the line of the car's travel while "
                               f"it was rolled (at most {SIDEWAYS_M * 1000:.0f} mm)",
                               hint="roll the car straight along the runways, steering straight ahead, and start again")


def _check_each_turn(wheel: str, theta: np.ndarray, travel_m: np.ndarray, radius_m: float) -> None:
    """WheelSlipped when the wheel's turn at one capture (``theta`` (K,) rad) is off what its
    centre's travel (``travel_m`` (K,)) over its own rolling radius predicts by more than
    ``SLIP_SHARE`` of the whole roll's turn: a slip at one position, which the median radius over
    the captures does not show."""
    if not np.isfinite(radius_m):
        return
    off = np.abs(theta + SIDE[wheel] * travel_m / radius_m)
    k = int(np.argmax(off))
    if off[k] > SLIP_SHARE * np.ptp(theta):
        raise WheelSlipped(f"{wheel}: at capture {k + 1} of {len(theta)} it had turned {np.degrees(off[k]):.1f} deg off what "
                           f"the car's travel over its rolling radius of {radius_m * 1000:.0f} mm predicts: it slipped, or "
                           "was turned or braked",
                           hint="release the brakes, roll the car slowly on a clean runway and start again")


def _check_slip(rolling_radius_m: dict[str, float]) -> None:
    """WheelSlipped when a wheel's rolling radius (m, NaN when it hardly turned) is off the car's
    median (the four roll together)."""
    radii = {w: r for w, r in rolling_radius_m.items() if np.isfinite(r)}
    if len(radii) < 3:
        return
    median = float(np.median(list(radii.values())))
    for w, r in radii.items():
        if abs(r / median - 1) > SLIP_SHARE:
            raise WheelSlipped(f"{w}: its turn does not match the car's travel (rolling radius {r * 1000:.0f} mm against "
                               f"the other wheels' {median * 1000:.0f} mm): it slipped, or was turned or braked",
                               hint="release the brakes, roll the car slowly on a clean runway and start again")
