"""What the pages show of a result and of a vehicle spec, as JSON (one place for the screen).

Angles in degrees, as everywhere at the station's interfaces; the page formats them (decimal
degrees, or degrees and minutes as the shop chooses).
"""

from __future__ import annotations

import math

from calibration.station_frame import WHEELS
from station.records.vehicle_specs import VehicleSpec
from station.result import Measurement


def spec_window(spec: VehicleSpec | None, name: str) -> dict | None:
    """{nominal, low, high} of angle ``name`` ("FL.toe", "front.total_toe", "thrust"); a
    per-wheel name falls back to its axle's figure ("front.toe"); None: no figure."""
    if spec is None:
        return None
    s = spec.angles.get(name)
    if s is None and "." in name:
        wheel, kind = name.split(".", 1)
        axle = {"F": "front", "R": "rear"}.get(wheel[:1]) if wheel in WHEELS else None
        s = spec.angles.get(f"{axle}.{kind}") if axle else None
    if s is None:
        return None
    return {"nominal": s.nominal_deg, "low": s.low_deg, "high": s.high_deg}


def spec_view(spec: VehicleSpec | None) -> dict | None:
    """The spec as the pages use it: {key, name, windows: {angle name: window}}."""
    if spec is None:
        return None
    names = [f"{w}.{k}" for w in WHEELS for k in ("toe", "camber")] + [
        "front.total_toe", "rear.total_toe", "thrust"] + [f"{w}.{k}" for w in ("FL", "FR")
                                                          for k in ("caster", "sai", "included_angle")]
    return {"key": spec.key, "name": spec.name, "windows": {n: spec_window(spec, n) for n in names}}


def verdict(window: dict | None, value: float | None) -> bool | None:
    """True inside the window, False outside, None without a figure or a value."""
    if window is None or value is None or not math.isfinite(value):
        return None
    return window["low"] - 1e-9 <= value <= window["high"] + 1e-9


def _angle(value, std, window) -> dict:
    return {"value": value, "std": std, "ok": verdict(window, value), "window": window}


def measurement_view(result: Measurement, spec: VehicleSpec | None = None) -> dict:
    """A result as the procedure page shows it: each angle with its uncertainty and verdict, the
    failure's message and what to do (and for a cycle refused for uncertain wheels, each wheel
    and why: ``refused``), the warnings."""
    out = {"cycle_id": result.cycle_id, "job_id": result.job_id, "vehicle": result.vehicle_spec,
           "valid": result.valid, "time_utc": result.time_utc, "warnings": list(result.warnings),
           "runout_compensated": result.runout_compensated}
    if not result.valid:
        f = result.failure
        out["failure"] = {"code": f.code if f else None, "message": f.message if f else "the measurement failed",
                          "hint": f.hint if f else None}
        # a cycle refused for uncertain wheels: each wheel and why, one row each
        out["refused"] = [{"wheel": flag.wheel, "reason": flag.reason,
                           "why": (flag.text or "").removeprefix(f"{flag.wheel}: ")}
                          for flag in result.warning_flags if flag.kind == "uncertain"]
        return out
    out["wheels"] = {}
    for w in WHEELS:
        r = result.wheels[w]
        out["wheels"][w] = {"toe": _angle(r.toe_deg, r.toe_std_deg, spec_window(spec, f"{w}.toe")),
                            "camber": _angle(r.camber_deg, r.camber_std_deg, spec_window(spec, f"{w}.camber")),
                            "toe_thrust": r.toe_thrust_deg, "runout_deg": r.runout_deg}
    out["axles"] = {a: _angle(x.total_toe_deg, x.total_toe_std_deg, spec_window(spec, f"{a}.total_toe"))
                    for a, x in result.axles.items()}
    out["thrust"] = _angle(result.thrust_deg, result.thrust_std_deg, spec_window(spec, "thrust"))
    if result.steering is not None:
        out["steering"] = steering_view(result, spec)
    if result.verdicts:
        out["overall"] = result.verdicts.get("overall")
    return out


def steering_view(result: Measurement, spec: VehicleSpec | None = None) -> dict:
    """{front wheel: {caster, sai, included_angle}} of a sweep's result, each angle with its
    uncertainty and verdict."""
    return {w: {k: _angle(getattr(s, f"{k}_deg"), getattr(s, f"{k}_std_deg"), spec_window(spec, f"{w}.{k}"))
                for k in ("caster", "sai", "included_angle")}
            for w, s in result.steering.wheels.items()}


def finite(obj):
    """``obj`` with every float that is not finite as None (JSON has no NaN), numpy numbers as
    Python's, recursively through dicts and lists."""
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
