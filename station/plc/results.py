"""A measurement result (station.result.Measurement) -> the values of the result registers.

The server writes what :func:`result_registers` returns in one step on the event loop, so a
PLC never reads a half-written result.
"""

from __future__ import annotations

import math

from calibration.station_frame import WHEELS
from station.errors import MeasurementError
from station.plc import register_map as rm
from station.result import Measurement


def _angle_path(name: str) -> str:
    """Where a named angle lives in the result's JSON (docs/result-schema.md), for messages."""
    head, _, kind = name.partition(".")
    if head in WHEELS:
        return f"wheels.{head}.{kind}_deg"
    if kind:
        return f"axles.{head}.{kind}_deg"
    return f"{head}_deg"


def result_angles(result: Measurement, required: bool = True) -> dict[str, float | None]:
    """{angle name: degrees or None} in :data:`register_map.ANGLES` order. Raises
    MeasurementError naming the key when a valid result lacks an angle (unless not
    ``required``: a calibration check reports no angles) or holds a non-number."""
    out = {}
    for name in rm.ANGLES:
        value = result.angle(name)
        if value is None:
            if required:
                raise MeasurementError(f"the measurement result lacks {_angle_path(name)}; "
                                       "it does not follow docs/result-schema.md")
            out[name] = None
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise MeasurementError(f"the measurement result has {_angle_path(name)} = {value!r}, "
                                   "not a finite number of degrees")
        out[name] = float(value)
    return out


def result_verdicts(result: Measurement) -> tuple[int, int]:
    """(pass_bits, judged_bits): bit i for angle i, bit 15 overall. An angle is judged when
    the result holds a pass/fail for it (only with a vehicle spec)."""
    verdict = result.verdicts or {}
    passed = judged = 0
    for i, name in enumerate(rm.ANGLES):
        v = verdict.get(name)
        if isinstance(v, bool):
            judged |= 1 << i
            passed |= int(v) << i
    if isinstance(verdict.get("overall"), bool):
        judged |= 1 << rm.OVERALL_BIT
        passed |= int(verdict["overall"]) << rm.OVERALL_BIT
    return passed, judged


def result_warning_bits(result: Measurement) -> int:
    """warning_bits (register_map.WARNING_KINDS, per wheel) from the result's ``warning_flags``."""
    first = dict((kind, bit) for bit, kind in rm.WARNING_KINDS)
    bits = 0
    for flag in result.warning_flags:
        if flag.kind in first and flag.wheel in WHEELS:
            bits |= 1 << (first[flag.kind] + WHEELS.index(flag.wheel))
    return bits


def result_uncertain_reasons(result: Measurement) -> int:
    """uncertain_reasons: per wheel, 4 bits (register_map.UNCERTAIN_REASON_CODES) of the reason
    of its ``uncertain`` flag; 0 for a wheel without one (or an unknown reason)."""
    bits = 0
    for flag in result.warning_flags:
        code = rm.UNCERTAIN_REASON_CODES.get(flag.reason or "", 0) if flag.kind == "uncertain" else 0
        if code and flag.wheel in WHEELS:
            bits |= code << (rm.UNCERTAIN_REASON_BITS * WHEELS.index(flag.wheel))
    return bits


def warning_registers(result: Measurement) -> dict[int, list[int]]:
    """{address: values} of warning_bits, station_warning_bits and uncertain_reasons: of a valid
    result, and of a refused one (a 404 names its wheels and why)."""
    return {rm.FIELDS["warning_bits"].address: [result_warning_bits(result)],
            rm.FIELDS["station_warning_bits"].address: [result_station_warning_bits(result)],
            rm.FIELDS["uncertain_reasons"].address: [result_uncertain_reasons(result)]}


def result_station_warning_bits(result: Measurement) -> int:
    """station_warning_bits: ANY_WARNING_BIT for any warning (text or flag), and the bit of each
    kind of register_map.STATION_WARNING_KINDS among the ``warning_flags``."""
    kinds = {flag.kind for flag in result.warning_flags}
    bits = sum(1 << bit for bit, kind in rm.STATION_WARNING_KINDS if kind in kinds)
    if bits or kinds or result.warnings:
        bits |= 1 << rm.ANY_WARNING_BIT
    return bits


def result_runout(result: Measurement) -> dict[str, tuple[float | None, float | None]]:
    """{wheel: (runout_deg, runout_mm)} of a compensated result, each None when not measured.
    Raises MeasurementError naming the key when a compensated result lacks a wheel's runout or
    holds a non-number (a result without compensation has none: all None)."""
    out = {}
    for w in WHEELS:
        wheel = result.wheels.get(w)
        values = []
        for key in ("runout_deg", "runout_mm"):
            value = getattr(wheel, key, None) if result.runout_compensated else None
            if value is None:
                if result.runout_compensated:
                    raise MeasurementError(f"the compensated measurement result lacks wheels.{w}.{key}; "
                                           "it does not follow docs/result-schema.md")
            elif isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise MeasurementError(f"the measurement result has wheels.{w}.{key} = {value!r}, not a finite number")
            values.append(None if value is None else float(value))
        out[w] = (values[0], values[1])
    return out


def runout_registers(runout: dict[str, tuple[float | None, float | None]], compensated: bool) -> dict[int, list[int]]:
    """{address: values} of ``runout_compensated`` and each wheel's runout (deg as f32 and i16, mm as i16)."""
    out = {rm.FIELDS["runout_compensated"].address: [int(compensated)]}
    for w in WHEELS:
        deg, mm = runout.get(w, (None, None))
        out[rm.FIELDS[f"{w}_runout_f32"].address] = rm.f32_to_regs(deg)
        out[rm.FIELDS[f"{w}_runout_i16"].address] = [rm.to_i16(deg, rm.FIELDS[f"{w}_runout_i16"].scale)]
        out[rm.FIELDS[f"{w}_runout_mm_i16"].address] = [rm.to_i16(mm, rm.FIELDS[f"{w}_runout_mm_i16"].scale)]
    return out


STEERING_KEYS = tuple(f"{key}_deg" for key, _ in rm.STEERING_ANGLES) + ("kingpin_offset_m",)


def result_steering(result: Measurement, required: bool = False) -> dict[str, dict[str, float]] | None:
    """{front wheel: {caster_deg, sai_deg, included_angle_deg, kingpin_offset_m}} of a steering
    sweep's result, None for a result without one. Raises MeasurementError naming the key when a
    result lacks the steering geometry though ``required`` (a steering sweep's), lacks a front
    wheel's value or holds a non-number."""
    if result.steering is None:
        if required:
            raise MeasurementError("the steering sweep's result lacks steering; it does not follow "
                                   "docs/result-schema.md")
        return None
    out = {}
    for w in rm.FRONT:
        wheel = result.steering.wheels.get(w)
        out[w] = {}
        for key in STEERING_KEYS:
            value = getattr(wheel, key, None)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise MeasurementError(f"the measurement result has steering.wheels.{w}.{key} = {value!r}, not a "
                                       "finite number")
            out[w][key] = float(value)
    return out


def steering_registers(steering: dict[str, dict[str, float]] | None) -> dict[int, list[int]]:
    """{address: values} of ``steering_valid`` and each front wheel's caster, SAI, included angle
    (deg as f32 and i16) and kingpin offset (mm as f32 and i16); None: no steering (NaN, -32768)."""
    out = {rm.FIELDS["steering_valid"].address: [int(steering is not None)]}
    for w in rm.FRONT:
        values = (steering or {}).get(w, {})
        for key, _ in rm.STEERING_ANGLES:
            deg = values.get(f"{key}_deg")
            out[rm.FIELDS[f"{w}_{key}_f32"].address] = rm.f32_to_regs(deg)
            out[rm.FIELDS[f"{w}_{key}_i16"].address] = [rm.deg_to_i16(deg)]
        m = values.get("kingpin_offset_m")
        mm = None if m is None else m * rm.MM_PER_M
        out[rm.FIELDS[f"{w}_kingpin_offset_mm_f32"].address] = rm.f32_to_regs(mm)
        out[rm.FIELDS[f"{w}_kingpin_offset_mm_i16"].address] = [rm.to_i16(mm, rm.FIELDS[f"{w}_kingpin_offset_mm_i16"].scale)]
    return out


def result_registers(result: Measurement, job_id: str | None, angles_required: bool = True,
                     steering_required: bool = False) -> dict[int, list[int]]:
    """{address: register values} for a finished, valid result (``steering_required``: a
    steering sweep's, which must hold the steering geometry)."""
    angles = result_angles(result, angles_required)
    passed, judged = result_verdicts(result)
    out: dict[int, list[int]] = {}
    for name, value in angles.items():
        key = name.replace(".", "_")
        out[rm.FIELDS[f"{key}_f32"].address] = rm.f32_to_regs(value)
        out[rm.FIELDS[f"{key}_i16"].address] = [rm.deg_to_i16(value)]
    out[rm.FIELDS["pass_bits"].address] = [passed]
    out[rm.FIELDS["judged_bits"].address] = [judged]
    out.update(warning_registers(result))
    out.update(runout_registers(result_runout(result), bool(result.runout_compensated)))
    out.update(steering_registers(result_steering(result, steering_required)))
    f = rm.FIELDS["result_job_id"]
    out[f.address] = rm.ascii_to_regs(job_id, f.count)
    return out


def cleared_registers() -> dict[int, list[int]]:
    """{address: values} of an empty result: NaN, no-value int16, no verdicts, no job."""
    out: dict[int, list[int]] = {}
    for name in rm.ANGLES:
        key = name.replace(".", "_")
        out[rm.FIELDS[f"{key}_f32"].address] = rm.f32_to_regs(None)
        out[rm.FIELDS[f"{key}_i16"].address] = [rm.deg_to_i16(None)]
    out[rm.FIELDS["pass_bits"].address] = [0]
    out[rm.FIELDS["judged_bits"].address] = [0]
    out[rm.FIELDS["warning_bits"].address] = [0]
    out[rm.FIELDS["station_warning_bits"].address] = [0]
    out[rm.FIELDS["uncertain_reasons"].address] = [0]
    out[rm.FIELDS["result_job_id"].address] = [0] * rm.FIELDS["result_job_id"].count
    out.update(runout_registers({}, False))
    out.update(steering_registers(None))
    return out


def roll_prompt_registers(step: int = 0, steps: int = 0, distance_mm: int = 0, position_mm: int = 0) -> dict[int, list[int]]:
    """{address: values} of the roll prompt (115..118); all 0: no roll asked for."""
    return {rm.FIELDS["roll_step"].address: [step & 0xFFFF], rm.FIELDS["roll_steps"].address: [steps & 0xFFFF],
            rm.FIELDS["roll_distance_mm"].address: [rm.to_i16(distance_mm, 1)],
            rm.FIELDS["roll_position_mm"].address: [rm.to_i16(position_mm, 1)]}


def steer_prompt_registers(step: int = 0, steps: int = 0, target_deg: float = 0.0) -> dict[int, list[int]]:
    """{address: values} of the steer prompt (225..227); all 0: no steer asked for."""
    return {rm.FIELDS["steer_step"].address: [step & 0xFFFF], rm.FIELDS["steer_steps"].address: [steps & 0xFFFF],
            rm.FIELDS["steer_target_i16"].address: [rm.deg_to_i16(target_deg)]}


def steer_live_registers(angles: dict[str, float] | None = None, reached: bool = False,
                         readings: int = 0) -> dict[int, list[int]]:
    """{address: values} of a live steer reading (228..231): each front wheel's steer angle
    (-32768 for a wheel not in ``angles``), whether it stands at the target, the readings so far.
    No arguments: no reading."""
    angles = angles or {}
    out = {rm.FIELDS[f"{w}_steer_i16"].address: [rm.deg_to_i16(angles.get(w))] for w in rm.FRONT}
    out[rm.FIELDS["steer_reached"].address] = [int(bool(reached))]
    out[rm.FIELDS["steer_readings"].address] = [readings & 0xFFFF]
    return out
