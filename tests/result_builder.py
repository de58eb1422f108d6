"""Build measurement results in the schema of docs/result-schema.md, for the history, recording,
spec and report tests (the measurement pipeline is tested elsewhere). Fixed seeds."""

from __future__ import annotations

import copy

import numpy as np

WHEELS = ("FL", "FR", "RL", "RR")
SIDE = {"FL": -1, "FR": 1, "RL": -1, "RR": 1}


def make_result(seed: int = 0, *, cycle: int = 1, job_id: str | None = "JOB-1",
                vehicle_spec: str | None = "dodge-caravan-2007", time_utc: str | None = None,
                toe: dict | None = None, camber: dict | None = None, valid: bool = True,
                recording: str | None = None) -> dict:
    """A plausible valid result; ``toe``/``camber`` override per-wheel angles (deg)."""
    rng = np.random.default_rng(seed)
    toe = {**{w: float(np.round(rng.normal(0.05, 0.05), 4)) for w in WHEELS}, **(toe or {})}
    camber = {**{w: float(np.round(rng.normal(0.0, 0.15), 4)) for w in WHEELS}, **(camber or {})}
    centers = {"FL": [-0.78, 1.35, 0.33], "FR": [0.78, 1.35, 0.33], "RL": [-0.78, -1.35, 0.33],
               "RR": [0.78, -1.35, 0.33]}
    wheels = {}
    for w in WHEELS:
        s = SIDE[w]
        t, c = np.radians(toe[w]), np.radians(camber[w])
        axis = np.array([s * np.cos(t) * np.cos(c), np.sin(t), -np.sin(c)])
        wheels[w] = {
            "toe_deg": toe[w], "toe_std_deg": 0.004, "camber_deg": camber[w], "camber_std_deg": 0.005,
            "center_station_m": centers[w], "axis_station": (axis / np.linalg.norm(axis)).tolist(),
            "rim_radius_m": 0.2159,
            "quality": {"score": 0.97, "points_left": 1450, "points_right": 1380,
                        "epipolar_rms_px": 0.12, "reprojection_rms_px": 0.09},
        }
    thrust = (toe["RL"] - toe["RR"]) / 2
    wheels["FL"]["toe_thrust_deg"] = toe["FL"] - thrust
    wheels["FR"]["toe_thrust_deg"] = toe["FR"] + thrust
    time_utc = time_utc or f"2026-11-22T10:{cycle // 60:02d}:{cycle % 60:02d}.000Z"
    cycle_id = f"20261122T10{cycle // 60:02d}{cycle % 60:02d}Z-{cycle:04d}"
    result = {
        "schema_version": 1, "cycle_id": cycle_id, "time_utc": time_utc, "station": "test bay",
        "software_version": "0.1.0", "calibration_id": "cal-20261122T090000Z", "job_id": job_id,
        "vehicle_spec": vehicle_spec, "valid": valid, "failure": None, "warnings": [],
        "wheels": wheels,
        "axles": {"front": {"total_toe_deg": toe["FL"] + toe["FR"], "total_toe_std_deg": 0.006,
                            "setback_m": 0.001, "setback_deg": 0.04, "track_m": 1.56},
                  "rear": {"total_toe_deg": toe["RL"] + toe["RR"], "total_toe_std_deg": 0.006,
                           "setback_m": 0.0, "setback_deg": 0.0, "track_m": 1.56}},
        "thrust_deg": thrust, "thrust_std_deg": 0.003,
        "wheelbase_m": {"left": 2.70, "right": 2.70},
        "timing_s": {"capture": 0.08, "detect": 0.09, "reconstruct": 0.03, "angles": 0.001, "total": 0.21},
        "captures_dir": None, "recording": recording,
    }
    if not valid:
        result["failure"] = {"code": 401, "message": "RR cam7: no closed rim contour"}
        for w in WHEELS:
            result["wheels"][w] = {}
        result["axles"] = {}
        result["thrust_deg"] = None
    return result


def with_spec(result: dict, spec) -> dict:
    """The result with pass/fail filled in from a VehicleSpec (as the pipeline does)."""
    from station.records.vehicle_specs import apply_spec
    out = copy.deepcopy(result)
    apply_spec(out, spec)
    return out
