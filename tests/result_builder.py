"""Build measurement results (station.result.Measurement) for the history, recording, spec and
report tests (the measurement pipeline is tested elsewhere). Fixed seeds."""

from __future__ import annotations

import copy

import numpy as np

from calibration.station_frame import SIDE, WHEELS
from station.result import AxleResult, Failure, Measurement, Steering, SteeringWheel, WheelQuality, WheelResult


def make_result(seed: int = 0, *, cycle: int = 1, job_id: str | None = "JOB-1",
                vehicle_spec: str | None = "dodge-caravan-2007", time_utc: str | None = None,
                toe: dict | None = None, camber: dict | None = None, valid: bool = True,
                recording: str | None = None, verdicts: dict | None = None,
                warnings: list[str] | None = None) -> Measurement:
    """A plausible valid result; ``toe``/``camber`` override per-wheel angles (deg)."""
    rng = np.random.default_rng(seed)
    toe = {**{w: float(np.round(rng.normal(0.05, 0.05), 4)) for w in WHEELS}, **(toe or {})}
    camber = {**{w: float(np.round(rng.normal(0.0, 0.15), 4)) for w in WHEELS}, **(camber or {})}
    centers = {"FL": [-0.78, 1.35, 0.33], "FR": [0.78, 1.35, 0.33], "RL": [-0.78, -1.35, 0.33],
               "RR": [0.78, -1.35, 0.33]}
    thrust = (toe["RL"] - toe["RR"]) / 2
    time_utc = time_utc or f"2026-11-22T10:{cycle // 60:02d}:{cycle % 60:02d}.000Z"
    cycle_id = f"20261122T10{cycle // 60:02d}{cycle % 60:02d}Z-{cycle:04d}"
    result = Measurement(station="test bay", valid=valid, warnings=list(warnings or []),
                         timing_s={"capture": 0.08, "detect": 0.09, "reconstruct": 0.03, "angles": 0.001,
                                   "total": 0.21},
                         cycle_id=cycle_id, time_utc=time_utc, software_version="0.1.0",
                         calibration_id="cal-20261122T090000Z", job_id=job_id, vehicle_spec=vehicle_spec,
                         recording=recording, verdicts=verdicts)
    if not valid:
        result.failure = Failure(401, "RR cam7: no closed rim contour")
        return result
    for w in WHEELS:
        s = SIDE[w]
        t, c = np.radians(toe[w]), np.radians(camber[w])
        axis = np.array([s * np.cos(t) * np.cos(c), np.sin(t), -np.sin(c)])
        result.wheels[w] = WheelResult(
            toe_deg=toe[w], camber_deg=camber[w], toe_std_deg=0.004, camber_std_deg=0.005,
            toe_thrust_deg={"FL": toe[w] - thrust, "FR": toe[w] + thrust}.get(w),
            center_station_m=centers[w], axis_station=(axis / np.linalg.norm(axis)).tolist(), rim_radius_m=0.2159,
            quality=WheelQuality(score=0.97, points_left=1450, points_right=1380, epipolar_rms_px=0.12,
                                 reprojection_rms_px=0.09, grazing_left_out=False, arcs_left_out=False,
                                 faint_left_out=False, other_contour_mm=None))
    result.axles = {"front": AxleResult(toe["FL"] + toe["FR"], 0.001, 0.04, 1.56, 0.006),
                    "rear": AxleResult(toe["RL"] + toe["RR"], 0.0, 0.0, 1.56, 0.006)}
    result.thrust_deg, result.thrust_std_deg = thrust, 0.003
    result.wheelbase_m = {"left": 2.70, "right": 2.70}
    return result


def with_spec(result: Measurement, spec) -> Measurement:
    """The result with pass/fail filled in from a VehicleSpec (as the pipeline does)."""
    from station.records.vehicle_specs import apply_spec
    out = copy.deepcopy(result)
    apply_spec(out, spec)
    return out


def with_steering(result: Measurement, caster: dict, sai: dict, sweep_deg: float = 20.0) -> Measurement:
    """The result with a steering sweep's geometry ({wheel: deg} of caster and SAI; the included
    angle is SAI + the wheel's camber), toe-out on turns at both ends of a 20 deg sweep."""
    wheels = {w: SteeringWheel(caster_deg=caster[w], caster_std_deg=0.02, sai_deg=sai[w], sai_std_deg=0.03,
                               included_angle_deg=sai[w] + result.wheels[w].camber_deg, included_angle_std_deg=0.03,
                               kingpin_offset_m=0.012 if w == "FL" else 0.015, caster_trail_m=0.02,
                               caster_classic_deg=caster[w] + 0.1, caster_from_normals_deg=caster[w],
                               sai_from_normals_deg=sai[w] + 0.3, steer_left_deg=sweep_deg, steer_right_deg=-sweep_deg,
                               misfit_deg=0.004) for w in ("FL", "FR")}
    turns = {"left": {"inner_wheel": "FL", "inner_deg": 20.0, "outer_deg": 18.6},
             "right": {"inner_wheel": "FR", "inner_deg": 20.0, "outer_deg": 18.8}} if sweep_deg >= 20 else {}
    result.steering = Steering(sweep_deg, wheels, turns)
    return result
