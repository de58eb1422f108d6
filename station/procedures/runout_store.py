"""The runout found by rolling, kept with the job and applied to its later measurements.

A runout compensation (station/procedures/runout.py) finds each wheel's spin axis; the rim's
tilt against it is a property of the rim as mounted, so it holds for the rest of the visit. It is
kept in ``<data_dir>/runout/<job>.json``: the tilt per wheel, where the wheel stood, and each
camera's angular profile of the rim's face (the phase reference). A later
measurement of the same job (``station measure --job``, ``station live --job``) finds how far
each wheel has turned since from its face's pattern, turns the tilt with it and tilts the rim
normal it measured back onto the spin axis: toe and camber of the spin axis again, while the
technician adjusts. It is not applied (the result says so, and stays of the rim plane) when the
station was recalibrated since, a wheel's face cannot be followed, or the car moved farther than
a roll: then measure with ``--compensate`` again.

Shapes: profiles (S,) per camera; axes (3,) unit, station frame; covariances (3,3) rad^2.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.camera_model import CameraModel
from calibration.station_frame import SIDE, WHEELS
from station.config import StationConfig
from station.errors import StorageError
from station.procedures.runout import (MIN_PATTERN_PEAK, PATTERN_AGREEMENT_DEG, ROLL_DISTANCE_M, TYRE_BEYOND_LIP_M,
                                       WheelRoll, with_spin_axes)
from station.records.atomic_file import write_text_atomic
from station.result import Measurement, WarningFlag
from station.rim.camera_response import linear_images
from station.stated_uncertainty import unseen_axis_covariance, views_bound_covariance
from station.wheel.rim_pattern import FacePose, angular_profile, ring_basis, rotation_between
from station.wheel.runout import SpinAxis, rotation_matrix

FORMAT = 1
MAX_TRAVEL_M = 2 * ROLL_DISTANCE_M  # a car rolled farther since is measured with --compensate again
MAX_ACROSS_M = 0.03                  # a wheel centre this far across the car's travel: the car was moved


@dataclass(frozen=True)
class KeptWheel:
    """One wheel's runout as kept: tilt (deg) and phase (deg, in the ring basis of the rim
    normal ``normal_station`` at the kept capture), lip wobble (mm), the spin axis' covariance,
    the wheel's centre then, the face's depth behind the lip, each camera's profile, the lip
    centre's offset from the hub then (3,) m and its (3,3) covariance (zero in files kept before
    hubs were found)."""

    runout_deg: float
    runout_phase_deg: float
    runout_mm: float
    cov_axis: np.ndarray
    center_station_m: np.ndarray
    normal_station: np.ndarray
    face_depth_m: float
    profiles: dict[str, np.ndarray]
    hub_offset_station_m: np.ndarray
    cov_hub_offset: np.ndarray


@dataclass(frozen=True)
class KeptRunout:
    job_id: str
    cycle_id: str
    calibration_id: str
    forward_station: np.ndarray
    wheels: dict[str, KeptWheel]


def runout_path(config: StationConfig, job_id: str) -> Path:
    from station.records.report import safe_filename

    return config.data_path("runout", safe_filename(job_id) + ".json")


def keep_runout(config: StationConfig, result: Measurement, rolls: dict[str, WheelRoll], images: dict,
                models: dict[str, CameraModel]) -> Path | None:
    """Keep the runout of a compensated ``result`` (its last capture ``images``) with its job; a
    result without a job id keeps nothing. StorageError when the data disk refuses."""
    if not result.job_id:
        return None
    linear = linear_images(images, config)
    wheels = {}
    for w in WHEELS:
        c = result.observations[w].circle
        pose = FacePose(np.asarray(c.center_station, float), np.asarray(c.axis_station, float), float(c.radius_m))
        cams = (config.pairs[w].precision, config.pairs[w].reference)
        s = rolls[w].spin
        wheels[w] = {"runout_deg": s.runout_deg, "runout_phase_deg": s.runout_phase_deg, "runout_mm": s.runout_mm,
                     "cov_axis": np.asarray(s.cov_axis).tolist(), "center_station_m": pose.center_station.tolist(),
                     "normal_station": pose.axis_station.tolist(), "face_depth_m": rolls[w].face_depth_m,
                     "profiles": {cam: np.round(angular_profile(linear[cam], models[cam], pose, rolls[w].face_depth_m),
                                                4).tolist() for cam in cams},
                     "hub_offset_station_m": np.asarray(rolls[w].hub_offset_station).tolist(),
                     "cov_hub_offset": np.asarray(rolls[w].cov_hub_offset).tolist()}
    doc = {"format": FORMAT, "job_id": result.job_id, "cycle_id": result.cycle_id,
           "calibration_id": result.calibration_id, "time_utc": result.time_utc,
           "forward_station": np.asarray(result.alignment_frame["R_station_align"])[:, 1].tolist(), "wheels": wheels}
    path = runout_path(config, result.job_id)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps(doc))
    except OSError as e:
        raise StorageError(f"{path}: cannot keep the runout of job {result.job_id!r}: {e.strerror or e}",
                           hint="free space on the data disk, or make it writable") from e
    return path


def load_kept_runout(config: StationConfig, job_id: str) -> KeptRunout | None:
    """The runout kept for ``job_id``, or None (none kept, or unreadable: the caller says so)."""
    path = runout_path(config, job_id)
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text())
        wheels = {w: KeptWheel(float(d["runout_deg"]), float(d["runout_phase_deg"]), float(d["runout_mm"]),
                               np.asarray(d["cov_axis"], float), np.asarray(d["center_station_m"], float),
                               np.asarray(d["normal_station"], float), float(d["face_depth_m"]),
                               {c: np.asarray(p, float) for c, p in d["profiles"].items()},
                               np.asarray(d.get("hub_offset_station_m", np.zeros(3)), float).reshape(3),
                               np.asarray(d.get("cov_hub_offset", np.zeros((3, 3))), float).reshape(3, 3))
                  for w, d in doc["wheels"].items()}
        if doc.get("format") != FORMAT or set(wheels) != set(WHEELS):
            raise ValueError("not a runout file of this station's format")
        return KeptRunout(str(doc["job_id"]), str(doc["cycle_id"]), str(doc["calibration_id"]),
                          np.asarray(doc["forward_station"], float), wheels)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise StorageError(f"{path}: the runout kept for job {job_id!r} cannot be read ({e})",
                           hint="measure with --compensate again: it keeps a new one") from e


def apply_kept_runout_to(config: StationConfig, result: Measurement, images: dict,
                         models: dict[str, CameraModel]) -> Measurement:
    """``result`` (valid, of the rim planes) with the runout kept for its job applied: toe and
    camber of the spin axes. Unchanged, with a warning why, when it cannot be applied; unchanged
    and silent when none is kept."""
    try:
        kept = load_kept_runout(config, result.job_id)
    except StorageError as e:
        result.warn(f"runout not applied: {e}", WarningFlag("runout_not_applied"))
        return result
    if kept is None:
        return result
    if kept.calibration_id != result.calibration_id:
        return _not_applied(result, "the station was recalibrated since it was measured")
    linear = linear_images(images, config)
    spins, hubs = {}, {}
    for w in WHEELS:
        k, c = kept.wheels[w], result.observations[w].circle
        pose = FacePose(np.asarray(c.center_station, float), np.asarray(c.axis_station, float), float(c.radius_m))
        moved = pose.center_station - k.center_station_m
        travel = float(moved @ kept.forward_station)
        across = float(np.linalg.norm((moved - travel * kept.forward_station)[:2]))
        if abs(travel) > MAX_TRAVEL_M or across > MAX_ACROSS_M:
            return _not_applied(result, f"{w} moved {abs(travel) * 100:.0f} cm along and {across * 1000:.0f} mm across "
                                        "the runways since")
        prior = -SIDE[w] * travel / (pose.radius_m + TYRE_BEYOND_LIP_M)
        turns = [rotation_between(ref, angular_profile(linear[cam], models[cam], pose, k.face_depth_m), prior)
                 for cam, ref in k.profiles.items()]
        if min(p for _, p in turns) < MIN_PATTERN_PEAK:
            return _not_applied(result, f"{w}: its rim's face no longer matches the kept one")
        angles = np.degrees([a for a, _ in turns])
        if np.ptp(angles) > PATTERN_AGREEMENT_DEG:
            return _not_applied(result, f"{w}: its cameras disagree on how far the wheel turned")
        turn = float(np.radians(np.mean(angles)))
        spins[w] = spin_from_runout(pose.axis_station, k, turn,
                                    np.asarray(c.cov_axis, float) + views_bound_covariance(result.observations[w], config)
                                    + unseen_axis_covariance(result.observations[w], pose.axis_station, config))
        # the lip centre's offset from the hub turns with the wheel, as its tilt does
        R = rotation_matrix(spins[w].axis_station, turn)
        hubs[w] = (R @ k.hub_offset_station_m, R @ k.cov_hub_offset @ R.T)
    out = with_spin_axes(result, spins, config, hubs)
    out.warnings.append(f"runout compensated with the runout kept for job {kept.job_id!r} "
                        f"(cycle {kept.cycle_id})")
    return out


def spin_from_runout(normal_station: np.ndarray, kept: KeptWheel, turn_rad: float, cov_normal: np.ndarray) -> SpinAxis:
    """The spin axis of a rim whose normal is ``normal_station`` (3,), turned by ``turn_rad``
    since the kept runout was measured: the tilt's direction turns with the rim."""
    n = np.asarray(normal_station, float) / np.linalg.norm(normal_station)
    tilt = np.radians(kept.runout_deg)
    phase = np.radians(kept.runout_phase_deg) + turn_rad
    e1, e2 = ring_basis(n)
    axis = n * np.cos(tilt) - np.sin(tilt) * (np.cos(phase) * e1 + np.sin(phase) * e2)
    cov = np.where(np.isfinite(cov_normal), cov_normal, 0.0) + np.where(np.isfinite(kept.cov_axis), kept.cov_axis, 0.0)
    return SpinAxis(axis, cov, n, kept.runout_deg, float(np.degrees(phase)) % 360.0, kept.runout_mm, 0.0)


def rotation_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3,3) the smallest rotation that turns the unit vector ``a`` (3,) onto ``b`` (3,)."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    k = np.cross(a, b)
    s, c = np.linalg.norm(k), float(a @ b)
    if s < 1e-15:
        return np.eye(3)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]]) / s
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _not_applied(result: Measurement, why: str) -> Measurement:
    result.warn(f"the runout kept for job {result.job_id!r} is not applied: {why}; toe and camber are of the rim "
                "planes (measure with --compensate to find the runout again)", WarningFlag("runout_not_applied"))
    return result
