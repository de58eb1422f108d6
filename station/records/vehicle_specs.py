"""Vehicle alignment specifications (config/vehicles.yaml) and the pass/fail of a result.

A spec gives, for every angle the station checks, a nominal value and a symmetric tolerance in
degrees, and where the figure came from. The file is validated when loaded: every problem is one
:class:`ConfigError` naming the file, the vehicle and the key. Angle names (docs/result-schema.md):
``FL.toe, FL.camber, FR.toe, FR.camber, RL.toe, RL.camber, RR.toe, RR.camber, front.total_toe,
rear.total_toe, thrust``, and of a steering sweep (``station caster``) ``FL.caster, FL.sai,
FL.included_angle`` and the same of FR. The file is written per axle (``front.camber`` applies to
FL and FR). The steering keys may be left out (files written before the station measured
caster), which is the same as ``null``; the others must all be there.
"""

from __future__ import annotations

import difflib
import math
import numbers
import os
from dataclasses import dataclass
from pathlib import Path


from station.config import read_yaml
from station.errors import ConfigError
from station.result import ANGLE_NAMES, STEERING_ANGLE_NAMES, Measurement

# the keys a vehicle's entry in the file must have, and the angle names each one sets
FILE_KEYS = {
    "front.camber": ("FL.camber", "FR.camber"),
    "front.toe": ("FL.toe", "FR.toe"),
    "front.total_toe": ("front.total_toe",),
    "rear.camber": ("RL.camber", "RR.camber"),
    "rear.toe": ("RL.toe", "RR.toe"),
    "rear.total_toe": ("rear.total_toe",),
    "thrust": ("thrust",),
}
STEERING_FILE_KEYS = {
    "front.caster": ("FL.caster", "FR.caster"),
    "front.sai": ("FL.sai", "FR.sai"),
    "front.included_angle": ("FL.included_angle", "FR.included_angle"),
}
_ALL_FILE_KEYS = {**FILE_KEYS, **STEERING_FILE_KEYS}
_PLAUSIBLE_DEG = {"front.caster": 20.0, "front.sai": 20.0, "front.included_angle": 25.0}  # others: 15
_ANGLE_FIELDS = ("nominal_deg", "tolerance_deg", "source")
_EPS = 1e-9  # values printed to the tolerance's last digit still pass


@dataclass(frozen=True)
class AngleSpec:
    nominal_deg: float
    tolerance_deg: float
    source: str = ""

    @property
    def low_deg(self) -> float:
        return self.nominal_deg - self.tolerance_deg

    @property
    def high_deg(self) -> float:
        return self.nominal_deg + self.tolerance_deg

    def check(self, value_deg: float) -> bool:
        return abs(value_deg - self.nominal_deg) <= self.tolerance_deg + _EPS


@dataclass(frozen=True)
class VehicleSpec:
    key: str
    name: str
    source: str
    angles: dict  # angle name -> AngleSpec, or None where the maker gives no figure


def load_vehicle_specs(path: str | os.PathLike) -> dict[str, VehicleSpec]:
    """Read and validate a vehicles file. Returns {spec key: VehicleSpec}. Raises ConfigError."""
    path = Path(path)
    raw = read_yaml(path, "vehicle specification file",
                    "set `vehicle_specs:` in config/station.yaml to the vehicles file")

    def bad(where: str, what: str) -> ConfigError:
        return ConfigError(f"{path}: {where}: {what}",
                           hint="fix the entry; docs/history-and-reports.md describes the vehicles file")

    if not isinstance(raw, dict) or raw.get("version") != 1:
        raise bad("version", "expected `version: 1` at the top of the file")
    vehicles = raw.get("vehicles")
    if not isinstance(vehicles, dict) or not vehicles:
        raise bad("vehicles", "expected a mapping of vehicle keys to specifications")
    extra = set(raw) - {"version", "vehicles"}
    if extra:
        raise bad(sorted(extra)[0], "unknown top-level key; expected version and vehicles")
    specs: dict[str, VehicleSpec] = {}
    for key, entry in vehicles.items():
        where = f"vehicle {key!r}"
        if not isinstance(entry, dict):
            raise bad(where, "expected a mapping with name, source and angles")
        for field in ("name", "source"):
            if not isinstance(entry.get(field), str) or not entry[field].strip():
                raise bad(f"{where}: {field}", "missing (every vehicle says what it is and where its figures came from)")
        unknown = set(entry) - {"name", "source", "angles"}
        if unknown:
            raise bad(f"{where}: {sorted(unknown)[0]}", "unknown key; expected name, source, angles")
        angles_raw = entry.get("angles")
        if not isinstance(angles_raw, dict):
            raise bad(f"{where}: angles", "missing; expected a mapping of " + ", ".join(FILE_KEYS))
        for k in angles_raw:
            if k not in _ALL_FILE_KEYS:
                close = difflib.get_close_matches(str(k), _ALL_FILE_KEYS, n=1)
                raise bad(f"{where}: angles.{k}", "unknown angle" + (f" (did you mean {close[0]!r}?)" if close
                                                                     else f"; expected {', '.join(_ALL_FILE_KEYS)}"))
        angles: dict[str, AngleSpec | None] = {}
        for file_key, names in _ALL_FILE_KEYS.items():
            if file_key not in angles_raw and file_key not in STEERING_FILE_KEYS:
                raise bad(f"{where}: angles.{file_key}",
                          "missing (write `null` if the maker publishes no figure)")
            spec = _angle(angles_raw.get(file_key), f"{where}: angles.{file_key}", bad,
                          _PLAUSIBLE_DEG.get(file_key, 15.0))
            for name in names:
                angles[name] = spec
        specs[str(key)] = VehicleSpec(str(key), entry["name"].strip(), entry["source"].strip(), angles)
    return specs


def _angle(v, where: str, bad, plausible_deg: float) -> AngleSpec | None:
    if v is None:
        return None
    if not isinstance(v, dict):
        raise bad(where, f"expected {{nominal_deg, tolerance_deg, source}} or null, got {v!r}")
    for field in _ANGLE_FIELDS:
        if field not in v:
            raise bad(f"{where}.{field}", "missing")
    unknown = set(v) - set(_ANGLE_FIELDS)
    if unknown:
        raise bad(f"{where}.{sorted(unknown)[0]}", f"unknown key; expected {', '.join(_ANGLE_FIELDS)}")
    nums = {}
    for field in ("nominal_deg", "tolerance_deg"):
        x = v[field]
        try:
            number = math.nan if isinstance(x, bool) or not isinstance(x, (int, float)) else float(x)
        except OverflowError:  # an integer of hundreds of digits
            number = math.inf
        if not math.isfinite(number):
            raise bad(f"{where}.{field}", f"expected a number of degrees, got {x!r}"[:200])
        nums[field] = number
    if not 0 < nums["tolerance_deg"] <= 10:
        raise bad(f"{where}.tolerance_deg", f"expected a tolerance in (0, 10] degrees, got {nums['tolerance_deg']}")
    if abs(nums["nominal_deg"]) > plausible_deg:
        raise bad(f"{where}.nominal_deg", f"{nums['nominal_deg']} degrees is not a plausible alignment figure")
    if not isinstance(v["source"], str) or not v["source"].strip():
        raise bad(f"{where}.source", "expected a sentence saying where the figure came from")
    return AngleSpec(nums["nominal_deg"], nums["tolerance_deg"], v["source"].strip())


def get_spec(specs: dict[str, VehicleSpec], key: str, path: str | os.PathLike = "vehicles.yaml") -> VehicleSpec:
    """The spec named ``key``; ConfigError with the close names when there is none."""
    if key in specs:
        return specs[key]
    close = difflib.get_close_matches(key, specs, n=3)
    raise ConfigError(f"{path}: no vehicle specification {key!r}"
                      + (f"; did you mean {', '.join(close)}?" if close else ""),
                      hint=f"known vehicles: {', '.join(sorted(specs))}")


def angle_value(result: Measurement, name: str) -> float | None:
    """The value (deg) of one named angle in a result, or None (none, or not a finite number)."""
    v = result.angle(name)
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
        return None
    return float(v)


def evaluate(result: Measurement, spec: VehicleSpec) -> dict:
    """Pass/fail of every angle against ``spec``: ``{name: True|False|None, ..., "overall": bool}``.

    None: no figure in the spec, or no value in the result. Overall is True only for a valid
    result where no angle fails and every angle with a figure has a value. The steering angles
    (caster, SAI, included angle) are judged on a steering sweep's result only.
    """
    out: dict[str, bool | None] = {}
    complete = True
    for name in ANGLE_NAMES + (STEERING_ANGLE_NAMES if result.steering is not None else ()):
        s = spec.angles.get(name)
        value = angle_value(result, name)
        if s is None:
            out[name] = None
        elif value is None:
            out[name] = None
            complete = False
        else:
            out[name] = s.check(value)
    out["overall"] = bool(result.valid and complete
                          and all(v is not False for k, v in out.items()))
    return out


def apply_spec(result: Measurement, spec: VehicleSpec) -> dict:
    """The pass/fail of ``result`` against ``spec``, kept on it (``verdicts``; "pass" in its
    JSON, per angle and per wheel); returns the verdicts."""
    verdict = evaluate(result, spec)
    result.vehicle_spec = spec.key
    result.verdicts = verdict
    return verdict
