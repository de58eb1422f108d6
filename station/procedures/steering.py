"""Steering geometry from a steering sweep: caster, SAI, included angle, kingpin offset.

With the brake held (a pedal depressor), the technician steers the front wheels left by the
sweep, right by the sweep, and back to straight ahead (``STEER_PLAN``); the cameras take the car
at each position. Every front wheel's pose at each capture is its rim's 3-D circle and how far
its face turned about its own axis since the last capture (roughly from the face's profile,
station/wheel/rim_pattern.py, then on the face's surface as both cameras see it,
station/wheel/face_surface.py); the steering axis is the axis that carries the wheel from one pose to the next
(station/wheel/steering_axis.py). In the car frame of the last capture (straight ahead):

- caster: the axis' tilt in side view, + its top rearward; SAI: its tilt in front view, + its
  top inward; included angle = SAI + camber (a bent strut or spindle shows in it);
- kingpin offset (scrub radius): where the axis meets the runway, inboard (+) of the point
  under the wheel centre; caster trail: how far ahead (+) of it;
- the shops' classic caster: the camber change over the sweep over the change of the sine of the
  steer angle (1.5 x the camber change over +/-20 deg), beside the exact one;
- toe-out on turns: at each end of the sweep, the inner and the outer wheel's steer angle.

Refused with a code (station/errors.py 415-418): a sweep under ``MIN_SWEEP_DEG`` either way,
one side under ``UNEVEN_SHARE`` of the other, a wheel whose poses are no turn about one axis (it
rolled: ``ROLLED_MISFIT_DEG``), a wheel whose face cannot be followed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.camera_model import CameraModel
from calibration.station_frame import SIDE
from station.config import StationConfig
from station.errors import RimPatternLost, SweepTooSmall, SweepUneven, WheelRolledWhileSteered
from station.procedures.poses import face_pose, normal_covariance
from station.result import Measurement, Steering, SteeringWheel
from station.rim.camera_response import linear_images
from station.wheel.face_surface import MIN_CELLS, face_surface, turn_on_surface
from station.wheel.rim_pattern import angular_profile, face_depth, rotation_between
from station.wheel.steering_axis import SteeringAxis, fit_steering_axis

FRONT = ("FL", "FR")
STEER_PLAN = (0.0, 1.0, -1.0, 0.0)  # where the wheels point at each capture, in sweeps (left +)
                                    # straight ahead first and last; the last is the reference
DEFAULT_SWEEP_DEG = 10.0        # how far the built-in station's cameras follow a rim (docs/procedures.md)
MIN_SWEEP_DEG = 4.0             # each way, at least
UNEVEN_SHARE = 0.5              # the shorter side at least this share of the longer
ROLLED_MISFIT_DEG = 0.25        # poses further than this from one turn about one axis: the wheel rolled
MIN_PATTERN_PEAK = 0.6          # the face followed from one capture to another correlates at least this well
PSI_FLOOR_DEG = 0.006           # the face's turn is known to this at best (both cameras agreeing)


@dataclass(frozen=True)
class WheelSweep:
    """One front wheel over the sweep: the fitted axis (full pose), the axis from its normals
    alone (to compare), its face's turn at each capture (deg), its heading change (deg, left +)."""

    axis: SteeringAxis
    axis_from_normals: SteeringAxis
    psi_deg: np.ndarray
    heading_deg: np.ndarray


def sweep_poses(results: list[Measurement], images: list[dict], models: dict[str, CameraModel],
                config: StationConfig) -> dict[str, WheelSweep]:
    """Each front wheel's steering axis from the valid ``results`` (K, the last straight ahead,
    the reference) of the captures ``images``. Raises SweepTooSmall, SweepUneven,
    WheelRolledWhileSteered or RimPatternLost naming the wheel."""
    linear = [linear_images(im, config) for im in images]
    out = {}
    for w in FRONT:
        cams = (config.pairs[w].precision, config.pairs[w].reference)
        poses = [face_pose(r, w) for r in results]
        depth, _ = face_depth({c: linear[-1][c] for c in cams}, models, poses[-1])
        reference = {c: angular_profile(linear[-1][c], models[c], poses[-1], depth) for c in cams}
        surface = face_surface({c: linear[-1][c] for c in cams}, models, poses[-1])
        if surface.usable_cells < MIN_CELLS:
            raise RimPatternLost(f"{w}: its rim's face shows too little the two cameras agree on ({surface.usable_cells} "
                                 f"usable points of its surface, at least {MIN_CELLS})",
                                 hint="clean the rim's face, add light on it, and measure again")
        psi, var_psi = [], []
        for k, (im, pose) in enumerate(zip(linear, poses)):
            found = [rotation_between(reference[c], angular_profile(im[c], models[c], pose, depth)) for c in cams]
            followed = [(c, a) for c, (a, peak) in zip(cams, found) if peak >= MIN_PATTERN_PEAK]
            if not followed:
                raise RimPatternLost(f"{w}: its rim's face does not match between the straight-ahead capture and "
                                     f"capture {k + 1} in either camera (correlation {found[0][1]:.2f}, "
                                     f"{found[1][1]:.2f})",
                                     hint="clean the rim's face, steer less far, and measure again")
            prior = float(np.mean([a for _, a in followed]))
            followed = [0.0] if k == len(poses) - 1 else \
                [turn_on_surface(surface, linear[-1][c], im[c], models[c], pose, prior) for c, _ in followed]
            psi.append(float(np.mean(followed)))
            spread = np.radians(0.0) if len(followed) < 2 else abs(followed[0] - followed[1]) / 2
            var_psi.append(np.radians(PSI_FLOOR_DEG) ** 2 + spread ** 2)
        normals = np.array([p.axis_station for p in poses])
        centers = np.array([p.center_station for p in poses])
        cov = np.array([normal_covariance(r, w, config) for r in results])
        axis = fit_steering_axis(normals, np.array(psi), centers, cov, np.array(var_psi), reference=len(poses) - 1)
        alone = fit_steering_axis(normals, np.array(psi), centers, cov, np.full(len(poses), 1e6),
                                  reference=len(poses) - 1)
        toe = np.array([r.wheels[w].toe_deg for r in results])
        heading = SIDE[w] * (toe - toe[-1])
        out[w] = WheelSweep(axis, alone, np.degrees(psi), heading)
    _check_sweep(out)
    return out


def steering_geometry(reference: Measurement, sweep: dict[str, WheelSweep], results: list[Measurement],
                      sweep_deg: float) -> Steering:
    """The steering result in ``reference``'s car frame (its last, straight-ahead capture)."""
    R_a = np.asarray(reference.alignment_frame["R_station_align"])
    wheels = {}
    for w, s in sweep.items():
        caster, sai, cov = _caster_sai(s.axis, R_a, w)
        camber = reference.wheels[w]
        included_std = float(np.sqrt(cov[1, 1] + camber.camber_std_deg ** 2))
        scrub, trail = _kingpin_offset(s.axis, np.asarray(camber.center_station_m, float), R_a, w)
        left, right = int(np.argmax(s.heading_deg)), int(np.argmin(s.heading_deg))
        cambers = np.array([r.wheels[w].camber_deg for r in results])
        classic = float(np.degrees(-SIDE[w] * np.radians(cambers[left] - cambers[right])
                                   / (np.sin(np.radians(s.heading_deg[left])) - np.sin(np.radians(s.heading_deg[right])))))
        alone_caster, alone_sai, _ = _caster_sai(s.axis_from_normals, R_a, w)
        wheels[w] = SteeringWheel(
            caster_deg=caster, caster_std_deg=float(np.sqrt(cov[0, 0])), sai_deg=sai, sai_std_deg=float(np.sqrt(cov[1, 1])),
            included_angle_deg=sai + camber.camber_deg, included_angle_std_deg=included_std,
            kingpin_offset_m=scrub, caster_trail_m=trail, caster_classic_deg=classic,
            caster_from_normals_deg=alone_caster, sai_from_normals_deg=alone_sai,
            steer_left_deg=float(s.heading_deg[left]), steer_right_deg=float(s.heading_deg[right]),
            misfit_deg=s.axis.misfit_deg)
    turns = {}
    for side, pick in (("left", np.argmax), ("right", np.argmin)):
        k = int(pick(sweep["FL"].heading_deg))
        inner, outer = ("FL", "FR") if side == "left" else ("FR", "FL")
        turns[side] = {"inner_wheel": inner, "inner_deg": float(abs(sweep[inner].heading_deg[k])),
                       "outer_deg": float(abs(sweep[outer].heading_deg[k]))}
    return Steering(sweep_deg=float(sweep_deg), wheels=wheels, toe_out_on_turns=turns)


def _caster_sai(axis: SteeringAxis, R_a: np.ndarray, wheel: str) -> tuple[float, float, np.ndarray]:
    """(caster deg, SAI deg, their (2,2) covariance deg^2) of the axis in the car frame R_a."""
    def angles(u):
        x, y, z = R_a.T @ u
        return np.degrees([np.arctan2(-y, z), np.arctan2(-SIDE[wheel] * x, z)])

    u = axis.direction_station
    value = angles(u)
    h = 1e-7
    J = np.stack([(angles(u + h * e) - angles(u - h * e)) / (2 * h) for e in np.eye(3)], axis=1)   # (2,3)
    cov = J @ np.nan_to_num(axis.cov_direction) @ J.T
    return float(value[0]), float(value[1]), cov


def _kingpin_offset(axis: SteeringAxis, center_station: np.ndarray, R_a: np.ndarray, wheel: str) -> tuple[float, float]:
    """(kingpin offset m, caster trail m): where the axis meets the runway (station z = 0)
    against the point under the wheel centre, inboard (+) and ahead (+)."""
    u, p = axis.direction_station, axis.point_station
    ground = p - u * (p[2] / u[2])
    d = ground - np.array([center_station[0], center_station[1], 0.0])
    return float(d @ (-SIDE[wheel] * R_a[:, 0])), float(d @ R_a[:, 1])


def _check_sweep(sweep: dict[str, WheelSweep]) -> None:
    for w, s in sweep.items():
        left, right = float(np.max(s.heading_deg)), float(-np.min(s.heading_deg))
        if min(left, right) < MIN_SWEEP_DEG:
            raise SweepTooSmall(f"{w}: steered {left:.1f} deg left and {right:.1f} deg right; at least "
                                f"{MIN_SWEEP_DEG:.0f} deg each way are needed", hint="steer to the targets shown and hold")
        if min(left, right) < UNEVEN_SHARE * max(left, right):
            raise SweepUneven(f"{w}: steered {left:.1f} deg left but {right:.1f} deg right", 
                              hint="steer as far each way (the targets shown) and measure again")
        if s.axis.misfit_deg > ROLLED_MISFIT_DEG:
            raise WheelRolledWhileSteered(
                f"{w}: its poses are {s.axis.misfit_deg:.2f} deg from one turn about one axis (at most "
                f"{ROLLED_MISFIT_DEG}): it rolled or slipped while steered, or its face's turn was misread",
                hint="hold the brake with a pedal depressor, steer slowly on the turn plates, steer less far if the "
                     "rim was seen very obliquely, and measure again")
