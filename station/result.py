"""One measurement as a typed result, from where it is made to every edge.

:func:`station.measure.measure_frames` makes a :class:`Measurement`; the cycle
(station/cycle.py) adds its id, time, calibration, job and files. The JSON of
docs/result-schema.md (version 1) is written by :meth:`Measurement.to_json` and read back by
:meth:`Measurement.from_json` (the history's stored cycles), nowhere else. The PLC registers
(station/plc/results.py), the recording (station/records/recording.py), the history and the
report read the fields. Angles in degrees, lengths in metres (docs/conventions.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from calibration.station_frame import AXLES, WHEELS

SCHEMA_VERSION = 1
# the named angles of a result: pass/fail, the PLC map, the history, the report
ANGLE_NAMES = ("FL.toe", "FL.camber", "FR.toe", "FR.camber", "RL.toe", "RL.camber",
               "RR.toe", "RR.camber", "front.total_toe", "rear.total_toe", "thrust")
# the named angles of a steering sweep (station caster): pass/fail and the report
STEERING_ANGLE_NAMES = ("FL.caster", "FL.sai", "FL.included_angle", "FR.caster", "FR.sai", "FR.included_angle")


@dataclass
class Failure:
    """Why a cycle has no valid angle: an error's code and sentence, what to do, and where
    (``camera``: a camera id, or "camA+camB" for a pair)."""

    code: int
    message: str
    hint: str | None = None
    wheel: str | None = None
    camera: str | None = None

    def to_json(self) -> dict:
        out: dict[str, Any] = {"code": self.code}
        if self.wheel is not None or self.camera is not None:
            out.update(wheel=self.wheel, camera=self.camera)
        out.update(message=self.message, hint=self.hint)
        return out

    @classmethod
    def from_json(cls, d: dict) -> Failure:
        return cls(d.get("code"), d.get("message"), d.get("hint"), d.get("wheel"), d.get("camera"))


@dataclass
class WarningFlag:
    """A warning a program may act on (docs/result-schema.md, ``warning_flags``)."""

    kind: str
    wheel: str | None = None
    camera: str | None = None
    because_of: list[str] | None = None   # "centreline": the wheels whose rim is in doubt
    text: str | None = field(default=None, compare=False)  # its warning's sentence (not in the JSON)
    reason: str | None = None  # "uncertain": why (station.stated_uncertainty.UNCERTAIN_REASONS)

    def to_json(self) -> dict:
        out: dict[str, Any] = {"kind": self.kind, "wheel": self.wheel}
        if self.camera is not None:
            out["camera"] = self.camera
        if self.because_of is not None:
            out["because_of"] = list(self.because_of)
        if self.reason is not None:
            out["reason"] = self.reason
        return out

    @classmethod
    def from_json(cls, d: dict) -> WarningFlag:
        return cls(d.get("kind"), d.get("wheel"), d.get("camera"), d.get("because_of"), reason=d.get("reason"))


@dataclass
class WheelQuality:
    """How well one wheel's 3-D rim is determined (docs/result-schema.md, ``quality``)."""

    score: float
    points_left: int
    points_right: int
    epipolar_rms_px: float
    reprojection_rms_px: float
    grazing_left_out: bool
    arcs_left_out: bool
    faint_left_out: bool
    other_contour_mm: float | None
    view_disagreement_deg: float | None = None  # each camera's own rim axis against its partner's

    def to_json(self) -> dict:
        return dict(vars(self))


@dataclass
class WheelResult:
    """One wheel's angles (deg), their standard uncertainty, and its 3-D rim (station frame).
    A synthetic result (``station serve --dry-run``) has the angles only."""

    toe_deg: float
    camber_deg: float
    toe_thrust_deg: float | None = None        # front wheels: toe against the thrust line
    toe_std_deg: float | None = None
    camber_std_deg: float | None = None
    center_station_m: list[float] | None = None  # (3,)
    axis_station: list[float] | None = None      # (3,) outward unit spin axis
    rim_radius_m: float | None = None
    quality: WheelQuality | None = None
    runout_deg: float | None = None             # with runout compensation: the rim's tilt against the spin axis,
    runout_phase_deg: float | None = None       # its direction on the rim (from the station's up, at the last capture),
    runout_mm: float | None = None              # and the lip's wobble across its diameter


@dataclass
class AxleResult:
    total_toe_deg: float
    setback_m: float | None = None
    setback_deg: float | None = None
    track_m: float | None = None
    total_toe_std_deg: float | None = None


@dataclass
class CameraDetection:
    """One camera's rim detection, summarised: the ellipse (ideal pixels) or why there is none."""

    ok: bool
    reason: str | None = None
    center_px: list[float] | None = None
    axes_px: list[float] | None = None
    angle_deg: float | None = None
    score: float | None = None
    coverage: float | None = None
    points: int | None = None
    white_share: float | None = None
    metal_side_dark_share: float | None = None  # station/rim/metal_side.py

    def to_json(self) -> dict:
        if not self.ok:
            return {"ok": False, "reason": self.reason}
        return {k: v for k, v in vars(self).items() if k != "reason"}

    @classmethod
    def from_json(cls, d: dict) -> CameraDetection:
        return cls(**{k: d.get(k) for k in cls.__dataclass_fields__})


@dataclass
class SteeringWheel:
    """A front wheel's steering geometry from a steering sweep (station/procedures/steering.py):
    angles in degrees with their standard uncertainty, lengths in metres."""

    caster_deg: float
    caster_std_deg: float
    sai_deg: float
    sai_std_deg: float
    included_angle_deg: float                # SAI + camber
    included_angle_std_deg: float
    kingpin_offset_m: float                  # scrub radius: the axis meets the runway inboard (+) of the wheel
    caster_trail_m: float                    # ... and ahead (+) of the point under its centre
    caster_classic_deg: float                # the shops' rule (camber change over the sweep), to compare
    caster_from_normals_deg: float           # the axis from the rim normals alone, to compare
    sai_from_normals_deg: float
    steer_left_deg: float                    # how far the wheel was steered each way (heading, left +)
    steer_right_deg: float
    misfit_deg: float                        # the poses' RMS distance from one turn about the axis

    @classmethod
    def from_json(cls, d: dict) -> SteeringWheel:
        return cls(**{k: d.get(k) for k in cls.__dataclass_fields__})


@dataclass
class Steering:
    """The steering sweep's result: the sweep asked for (deg each way), each front wheel's
    geometry, and toe-out on turns at each end ({"left"|"right": {"inner_wheel", "inner_deg",
    "outer_deg"}})."""

    sweep_deg: float
    wheels: dict[str, SteeringWheel]
    toe_out_on_turns: dict

    def to_json(self) -> dict:
        return {"sweep_deg": self.sweep_deg, "wheels": {w: vars(r).copy() for w, r in self.wheels.items()},
                "toe_out_on_turns": self.toe_out_on_turns}

    @classmethod
    def from_json(cls, d: dict) -> Steering:
        return cls(float(d.get("sweep_deg") or 0.0),
                   {w: SteeringWheel.from_json(r) for w, r in (d.get("wheels") or {}).items() if isinstance(r, dict)},
                   dict(d.get("toe_out_on_turns") or {}))


@dataclass
class Measurement:
    """A cycle's result. ``valid`` False: no angle may be used, ``failure`` says why.

    The angles (``wheels``, ``axles``, ``thrust_deg``, ...) are set on a valid result only, and
    on a cycle refused for a wheel less certain than the limit (code 404), whose JSON leaves
    them out: the recording and the benchmarks show what was refused. The
    cycle's fields (``cycle_id`` ... ``recording``) are None outside a cycle (a benchmark's
    measurement of images). ``truth`` and ``errors`` (measured - true, deg) come from a
    simulation; ``verdicts`` ("pass" in the JSON) from a vehicle specification.
    ``observations``: each wheel's detections and fits (station.wheel.pair.WheelObservation), for
    the recording and ``station live``; never serialised.
    """

    station: str
    valid: bool = False
    failure: Failure | None = None
    warnings: list[str] = field(default_factory=list)
    warning_flags: list[WarningFlag] = field(default_factory=list)
    wheels: dict[str, WheelResult] = field(default_factory=dict)
    axles: dict[str, AxleResult] = field(default_factory=dict)
    thrust_deg: float | None = None
    thrust_std_deg: float | None = None
    wheelbase_m: dict[str, float] | None = None           # {"left", "right"}
    centreline_deg: float | None = None
    paper_front_angles_deg: dict[str, float] | None = None  # eqs 39-42
    alignment_frame: dict | None = None                   # {"origin_station_m", "R_station_align"}
    timing_s: dict[str, float] = field(default_factory=dict)
    method: str | None = None
    runout_compensated: bool = False  # toe and camber of the wheels' spin axes (True) or of the rim planes
    steering: Steering | None = None  # a steering sweep's caster, SAI, included angle (station caster)
    detections: dict[str, CameraDetection] | None = None
    cycle_id: str | None = None
    time_utc: str | None = None
    software_version: str | None = None
    calibration_id: str | None = None
    job_id: str | None = None
    vehicle_spec: str | None = None
    captures_dir: str | None = None
    exposures: dict[str, float] | None = None  # cameras taken again shorter: factor of the configured exposure
    truth: dict | None = None
    errors: dict[str, Any] | None = None
    verdicts: dict[str, bool | None] | None = None
    recording: str | None = None
    simulation_seed: int | None = None
    observations: dict = field(default_factory=dict, repr=False)

    # --- building ------------------------------------------------------------------------------
    def warn(self, text: str, flag: WarningFlag | None = None) -> None:
        """A warning's sentence, and the flag a program may act on (it keeps the sentence)."""
        self.warnings.append(text)
        if flag is not None:
            flag.text = text
            self.warning_flags.append(flag)

    def has_flag(self, kind: str, wheel: str | None = None) -> bool:
        return any(f.kind == kind and (wheel is None or f.wheel == wheel) for f in self.warning_flags)

    def add_truth(self, truth: dict) -> None:
        """Simulation only: attach the truth and each angle's error (measured - true): against
        the spin axes' alignment when runout is compensated, else against the rim planes' (the
        truth's ``rim_toe_deg``/``rim_camber_deg``, the same when the rims do not run out)."""
        self.truth = truth
        if not self.valid and not (self.wheels and self.axles):
            return
        prefix = "" if self.runout_compensated else "rim_"
        true = {w: {k: t.get(prefix + k, t[k]) for k in ("toe_deg", "camber_deg")} for w, t in truth["wheels"].items()}
        errors: dict[str, Any] = {}
        for w in WHEELS:
            m, t = self.wheels[w], true[w]
            errors[w] = {"toe_error_deg": m.toe_deg - t["toe_deg"], "camber_error_deg": m.camber_deg - t["camber_deg"]}
        for axle, (left, right) in AXLES.items():
            errors[f"{axle}.total_toe"] = self.axles[axle].total_toe_deg - true[left]["toe_deg"] - true[right]["toe_deg"]
        errors["thrust"] = self.thrust_deg - (true["RL"]["toe_deg"] - true["RR"]["toe_deg"]) / 2
        if self.steering is not None:
            for w, r in self.steering.wheels.items():
                t = truth["wheels"][w]
                errors[w].update({f"{k}_error_deg": getattr(r, f"{k}_deg") - t[f"{k}_deg"]
                                  for k in ("caster", "sai", "included_angle") if f"{k}_deg" in t})
        self.errors = errors

    def angle(self, name: str) -> float | None:
        """The value (deg) of a named angle of ANGLE_NAMES or STEERING_ANGLE_NAMES, or None."""
        head, _, kind = name.partition(".")
        if name in STEERING_ANGLE_NAMES:
            wheel = self.steering.wheels.get(head) if self.steering is not None else None
            return None if wheel is None else getattr(wheel, f"{kind}_deg", None)
        if head in self.wheels:
            return getattr(self.wheels[head], f"{kind}_deg", None)
        if head in self.axles:
            return self.axles[head].total_toe_deg
        return self.thrust_deg if name == "thrust" else None

    # --- the JSON of docs/result-schema.md ----------------------------------------------------
    def to_json(self) -> dict:
        """The result as docs/result-schema.md (version 1) gives it: plain JSON types."""
        out: dict[str, Any] = {"schema_version": SCHEMA_VERSION, "station": self.station, "valid": self.valid,
                               "failure": None if self.failure is None else self.failure.to_json(),
                               "warnings": list(self.warnings),
                               "warning_flags": [f.to_json() for f in self.warning_flags],
                               "wheels": {w: self._wheel_json(w, r) for w, r in self.wheels.items()} if self.valid else {},
                               "axles": {a: _present(vars(r)) for a, r in self.axles.items()} if self.valid else {},
                               "thrust_deg": self.thrust_deg if self.valid else None}
        out.update(_present({"thrust_std_deg": self.thrust_std_deg, "wheelbase_m": self.wheelbase_m,
                             "centreline_deg": self.centreline_deg,
                             "paper_front_angles_deg": self.paper_front_angles_deg,
                             "alignment_frame": self.alignment_frame, "exposures": self.exposures}))
        out["timing_s"] = dict(self.timing_s)
        if self.method is not None:
            out["method"] = self.method
            out["runout_compensated"] = self.runout_compensated
        if self.steering is not None:
            out["steering"] = self.steering.to_json()
        if self.detections is not None:
            out["detections"] = {c: d.to_json() for c, d in self.detections.items()}
        if self.cycle_id is not None:
            out.update(cycle_id=self.cycle_id, time_utc=self.time_utc, software_version=self.software_version,
                       calibration_id=self.calibration_id, job_id=self.job_id, vehicle_spec=self.vehicle_spec,
                       captures_dir=self.captures_dir)
        out.update(_present({"truth": self.truth, "errors": self.errors, "pass": self.verdicts,
                             "recording": self.recording, "simulation_seed": self.simulation_seed}))
        return out

    def _wheel_json(self, wheel: str, r: WheelResult) -> dict:
        runout = ("runout_deg", "runout_phase_deg", "runout_mm")
        out = _present({k: v for k, v in vars(r).items() if k != "quality" and k not in runout})
        if r.quality is not None:
            out["quality"] = r.quality.to_json()
        out.update(_present({k: getattr(r, k) for k in runout}))
        if self.errors and wheel in self.errors:
            out.update(self.errors[wheel])
        if self.verdicts is not None:
            out["pass"] = {"toe": self.verdicts.get(f"{wheel}.toe"), "camber": self.verdicts.get(f"{wheel}.camber")}
            out["pass"].update({k: self.verdicts[f"{wheel}.{k}"] for k in ("caster", "sai", "included_angle")
                                if f"{wheel}.{k}" in self.verdicts})
        return out

    @classmethod
    def from_json(cls, d: dict) -> Measurement:
        """A result read back from its JSON (a stored cycle). Keys it lacks stay None."""
        wheels = {}
        for w, e in (d.get("wheels") or {}).items():
            if not isinstance(e, dict) or "toe_deg" not in e:
                continue
            q = e.get("quality")
            wheels[w] = WheelResult(**{k: e.get(k) for k in WheelResult.__dataclass_fields__ if k != "quality"},
                                    quality=WheelQuality(**{k: q.get(k) for k in WheelQuality.__dataclass_fields__})
                                    if isinstance(q, dict) else None)
        axles = {a: AxleResult(**{k: e.get(k) for k in AxleResult.__dataclass_fields__})
                 for a, e in (d.get("axles") or {}).items() if isinstance(e, dict) and "total_toe_deg" in e}
        plain = {k: d.get(k) for k in ("station", "thrust_deg", "thrust_std_deg", "wheelbase_m", "centreline_deg",
                                       "paper_front_angles_deg", "alignment_frame", "method", "cycle_id", "time_utc",
                                       "software_version", "calibration_id", "job_id", "vehicle_spec",
                                       "captures_dir", "exposures", "truth", "errors", "recording",
                                       "simulation_seed")}
        detections = d.get("detections")
        return cls(**plain, valid=bool(d.get("valid", False)), runout_compensated=bool(d.get("runout_compensated", False)),
                   failure=Failure.from_json(d["failure"]) if isinstance(d.get("failure"), dict) else None,
                   warnings=list(d.get("warnings") or []),
                   warning_flags=[WarningFlag.from_json(f) for f in d.get("warning_flags") or [] if isinstance(f, dict)],
                   wheels=wheels, axles=axles, timing_s=dict(d.get("timing_s") or {}),
                   detections=None if detections is None else
                   {c: CameraDetection.from_json(x) for c, x in detections.items()},
                   verdicts=d.get("pass"),
                   steering=Steering.from_json(d["steering"]) if isinstance(d.get("steering"), dict) else None)


def _present(d: dict) -> dict:
    """``d`` without its None values."""
    return {k: v for k, v in d.items() if v is not None}
