"""The PLC register map: the one source of truth for addresses, types, scaling and word order.

Everything lives in **holding registers** (read with function 3, written with 6 or 16; the same
addresses also answer function 4). Addresses here are the 0-based addresses on the wire; the
PLC programmer's "4xxxx" numbers are ``40001 + address``. docs/plc.md is generated from this
module (:func:`markdown_tables`), never edited by hand.

Two areas:

* **PLC -> station** (``0 .. 99``, writable): the command mailbox, the job id / VIN and the
  vehicle spec id (ASCII). Only :data:`PLC_FIELDS` are writable; a write anywhere else gets
  Modbus exception 2 (illegal data address).
* **Station -> PLC** (``100 .. 299``, read-only): state, fault code, heartbeat, counters, the
  result-valid flag, the roll prompt of a compensated cycle, every angle as float32 and as scaled
  int16, pass/fail bits, each wheel's runout (one read: :data:`RESULT_BLOCK`); then the steering
  sweep's prompt, the front wheels' live steer angle and the steering results (a second read:
  :data:`STEER_BLOCK`).

Encoding (docs/conventions.md, "Modbus"):

* ``f32``: IEEE 754 single in two registers, **big-endian word order** (high word first),
  big-endian bytes in a word (ABCD). A missing angle is NaN.
* ``i16``: two's complement, **0.01 degree** per count (0.01 mm for a runout or a kingpin offset
  in mm, 1 mm for the roll prompt: a field's ``scale``), saturated to +-32766 counts; ``-32768`` (0x8000) means
  "no value".
* ``ascii``: two characters per register, the first in the high byte, padded with NUL (0).
* ``u32``: two registers, high word first.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from calibration.station_frame import WHEELS
from station.result import ANGLE_NAMES

# --- angles, in the order of docs/result-schema.md ----------------------------------------------
ANGLES = ANGLE_NAMES
OVERALL_BIT = 15  # bit of pass_bits / judged_bits that holds the overall verdict
INT16_SCALE = 100  # counts per degree
INT16_MISSING = -32768
INT16_LIMIT = 32766
MM_PER_M = 1000  # roll distances are whole millimetres (int16) on the wire

# --- values of the command, state and active-command registers ----------------------------------
COMMANDS = {0: "none", 1: "measure", 2: "calibration_check", 3: "reset_fault", 4: "acknowledge",
            5: "measure_compensated", 6: "in_position", 7: "measure_caster"}
COMMAND_CODES = {name: code for code, name in COMMANDS.items()}
STATES = {0: "idle", 1: "busy", 2: "done", 3: "fault", 4: "roll", 5: "steer"}
STATE_CODES = {name: code for code, name in STATES.items()}
MAP_VERSION = 8  # 2: warning_bits (113) added; 3: station_warning_bits (114), and bit 15 of
                 # warning_bits is RR's runner-up alone (it also meant "any warning" in 2);
                 # 4: bit 4 of station_warning_bits (a rim another size than its axle partner's);
                 # 5: runout compensation (issue 32): command 5 measure compensated, command 6 in
                 # position, state 4 roll, the roll prompt 115..118, runout_compensated and each
                 # wheel's runout 208..224 (the whole output is 100..224 now); nothing moved;
                 # 6: the steering sweep (issue 33): command 7 measure caster, state 5 steer, the
                 # steer prompt and the front wheels' live steer angle 225..231, steering_valid and
                 # each front wheel's caster, SAI, included angle and kingpin offset 232..256 (a
                 # second read, STEER_BLOCK: 100..224 stays one read); nothing moved;
                 # 7: bit 5 of station_warning_bits (a camera's grey not proportional to light)
                 # 8: uncertain_reasons (119), and warning_bits and station_warning_bits of a refused
                 # cycle as well (a 404 sets the refused wheels' bits 0-3); nothing moved
# bits of warning_bits: (first bit, kind of the result's warning_flags); bit first + i for wheel i
# of WHEELS (FL, FR, RL, RR)
WARNING_KINDS = ((0, "uncertain"), (4, "drift"), (8, "unchecked"), (12, "runner_up"))
# bits of station_warning_bits: any warning at all, the kinds of the cameras' own warnings, and
# a wheel whose rim came out another size than its axle partner's (the texts name them)
ANY_WARNING_BIT = 0
STATION_WARNING_KINDS = ((1, "exposure"), (2, "focus"), (3, "small_rim"), (4, "rim_size"), (5, "response"))
# uncertain_reasons: 4 bits per wheel (FL bits 0-3, FR 4-7, RL 8-11, RR 12-15), why the wheel was
# stated beyond the uncertainty limit (the reason of its "uncertain" warning flag); 0: not refused
UNCERTAIN_REASON_CODES = {"white_lip": 1, "dark_lip": 2, "faint_view": 3, "uneven_edge": 4, "faint_edge": 5,
                          "calibration": 6}
UNCERTAIN_REASON_BITS = 4


def uncertain_reasons_of(value: int) -> dict[str, str]:
    """uncertain_reasons -> {wheel: reason name} of the wheels refused (an unknown code: "code N")."""
    names = {code: name for name, code in UNCERTAIN_REASON_CODES.items()}
    out = {}
    for i, w in enumerate(WHEELS):
        code = (int(value) >> (UNCERTAIN_REASON_BITS * i)) & ((1 << UNCERTAIN_REASON_BITS) - 1)
        if code:
            out[w] = names.get(code, f"code {code}")
    return out


@dataclass(frozen=True)
class Field:
    """One value in the map. ``count`` is the number of registers it occupies."""

    name: str
    address: int
    type: str  # u16 | i16 | u32 | f32 | ascii | bits
    count: int
    doc: str
    writable: bool = False
    unit: str = ""
    scale: int = INT16_SCALE  # i16 only: counts per unit (0.01 deg, 0.01 mm; 1 for whole millimetres)

    @property
    def end(self) -> int:
        """One past the last register."""
        return self.address + self.count


def _angle_fields() -> list[Field]:
    out = []
    for i, name in enumerate(ANGLES):
        key = name.replace(".", "_")
        out.append(Field(f"{key}_f32", 120 + 2 * i, "f32", 2, f"{name} (NaN: no value)", unit="deg"))
    for i, name in enumerate(ANGLES):
        key = name.replace(".", "_")
        out.append(Field(f"{key}_i16", 142 + i, "i16", 1, f"{name} x 100 (-32768: no value)",
                         unit="0.01 deg"))
    return out


def _runout_fields() -> list[Field]:
    """Each wheel's runout (issue 32) after the fault reason: degrees as float32 and as int16
    (0.01 deg, like the angles), and the lip's wobble in 0.01 mm."""
    out = [Field("runout_compensated", 208, "u16", 1, "1: toe, camber, the totals and thrust of the last "
                 "valid result are of the wheels' spin axes (measured with runout compensation, command 5); "
                 "0: of the rim planes")]
    for i, w in enumerate(WHEELS):
        out.append(Field(f"{w}_runout_f32", 209 + 2 * i, "f32", 2, f"{w}: its rim's tilt against its spin axis "
                         "(NaN: not measured: no runout compensation)", unit="deg"))
    for i, w in enumerate(WHEELS):
        out.append(Field(f"{w}_runout_i16", 217 + i, "i16", 1, f"{w}: runout x 100 (-32768: not measured)",
                         unit="0.01 deg"))
    for i, w in enumerate(WHEELS):
        out.append(Field(f"{w}_runout_mm_i16", 221 + i, "i16", 1, f"{w}: the lip's wobble across its diameter "
                         "x 100 (-32768: not measured)", unit="0.01 mm"))
    return out


STEERING_ANGLES = (("caster", "caster"), ("sai", "SAI"), ("included_angle", "included angle (SAI + camber)"))
FRONT = ("FL", "FR")


def _steer_fields() -> list[Field]:
    """The steering sweep (issue 33), after the runout: the prompt and the live steer angle a PLC
    reads in state steer (225..231), then the result (232..256): each front wheel's caster, SAI
    and included angle in degrees as float32 and as int16 (0.01 deg, like the angles), and its
    kingpin offset in mm (float32, and int16 in 0.01 mm like the runout)."""
    out = [Field("steer_step", 225, "u16", 1, "in state steer: the steer the station waits for, 1..steer_steps; 0 in "
                 "any other state"),
           Field("steer_steps", 226, "u16", 1, "in state steer: the steer targets of the whole sweep (3); 0 in any "
                 "other state"),
           Field("steer_target_i16", 227, "i16", 1, "in state steer: where the front wheels must point, + left, "
                 "- right, 0 straight ahead (x 100); 0 in any other state", unit="0.01 deg")]
    for i, w in enumerate(FRONT):
        out.append(Field(f"{w}_steer_i16", 228 + i, "i16", 1, f"{w}'s live steer angle, + left, against its "
                         "first reading straight ahead (x 100): several readings a second in state steer, the last "
                         "kept after a steer reached until the next steer or the cycle's end; -32768: its rim not "
                         "seen in the last reading, or no reading", unit="0.01 deg"))
    out += [Field("steer_reached", 230, "u16", 1, "1: the last reading found the front wheels at the target and "
                  "standing still: the station leaves state steer and captures (the reading stays until the next "
                  "steer or the cycle's end); 0 otherwise"),
            Field("steer_readings", 231, "u16", 1, "live steer readings taken in this cycle (moves while the live "
                  "angle is fresh), wraps at 65535; 0 at the trigger and once the cycle ended"),
            Field("steering_valid", 232, "u16", 1, "1: the last valid result holds the steering geometry below "
                  "(a steering sweep, command 7); 0: none (NaN / -32768)")]
    for i, (w, (key, text)) in enumerate((w, k) for w in FRONT for k in STEERING_ANGLES):
        out.append(Field(f"{w}_{key}_f32", 233 + 2 * i, "f32", 2, f"{w}: {text} (NaN: no steering sweep)", unit="deg"))
    for i, (w, (key, text)) in enumerate((w, k) for w in FRONT for k in STEERING_ANGLES):
        out.append(Field(f"{w}_{key}_i16", 245 + i, "i16", 1, f"{w}: {text.split(' (')[0]} x 100 (-32768: no "
                         "steering sweep)", unit="0.01 deg"))
    for i, w in enumerate(FRONT):
        out.append(Field(f"{w}_kingpin_offset_mm_f32", 251 + 2 * i, "f32", 2, f"{w}: kingpin offset (scrub radius): "
                         "where the steering axis meets the runway, + inboard of the point under the wheel centre "
                         "(NaN: no steering sweep)", unit="mm"))
    for i, w in enumerate(FRONT):
        out.append(Field(f"{w}_kingpin_offset_mm_i16", 255 + i, "i16", 1, f"{w}: kingpin offset x 100 (-32768: no "
                         "steering sweep)", unit="0.01 mm"))
    return out


PLC_FIELDS = [
    Field("command", 0, "u16", 1, "command mailbox: 1 measure, 2 calibration check, 3 reset fault, "
          "4 acknowledge, 5 measure with runout compensation, 6 in position (the car rolled as state 4 "
          "asked), 7 measure caster (a steering sweep: the station asks for each steer in state 5); "
          "consumed on receipt (reads back 0)", writable=True),
    Field("job_id", 1, "ascii", 16, "job id / VIN for the next cycle, up to 32 ASCII characters",
          writable=True),
    Field("vehicle_spec", 17, "ascii", 16, "vehicle spec id for the next cycle (e.g. "
          "dodge-caravan-2007), up to 32 ASCII characters; empty: no pass/fail", writable=True),
]
STATION_FIELDS = [
    Field("state", 100, "u16", 1, "0 idle, 1 busy, 2 done, 3 fault, 4 roll (roll the car as 115..118 say, "
          "then write command 6), 5 steer (the front wheels are to be steered as 225..227 say; the station "
          "goes on by itself once they stand there)"),
    Field("fault_code", 101, "u16", 1, "station error code of the failed cycle (`station errors`); "
          "0 unless state is fault"),
    Field("heartbeat", 102, "u16", 1, "increments every heartbeat period, wraps at 65535"),
    Field("cycle_counter", 103, "u16", 1, "cycles finished (done or fault), wraps at 65535"),
    Field("result_valid", 104, "u16", 1, "1: the angles below belong to the last finished cycle "
          "and may be used; 0 while busy and after a failed cycle"),
    Field("active_command", 105, "u16", 1, "command of the running or last cycle"),
    Field("reject_code", 106, "u16", 1, "error code of the last refused command (501..508)"),
    Field("reject_count", 107, "u16", 1, "refused commands so far, wraps at 65535"),
    Field("pass_bits", 108, "bits", 1, "bit i: angle i within the spec; bit 15: overall pass"),
    Field("judged_bits", 109, "bits", 1, "bit i: angle i was judged against a spec; bit 15: overall"),
    Field("cycle_time_us", 110, "u32", 2, "time the measurement itself took", unit="us"),
    Field("map_version", 112, "u16", 1, f"version of this register map ({MAP_VERSION})"),
    Field("warning_bits", 113, "bits", 1, "warnings of the last finished cycle, valid or refused, bit first + "
          "wheel (FL 0, FR 1, RL 2, RR 3): 0 the wheel's toe or camber is less certain than the limit, 4 the pair's "
          "calibration may have drifted, 8 the pair's calibration could not be checked, 12 a runner-up "
          "rim candidate was taken (the texts: the result's `warnings`)"),
    Field("station_warning_bits", 114, "bits", 1, "warnings of the last finished cycle, valid or refused: bit 0 "
          "any warning at all; bits 1-3 a camera's own: 1 its rim edge reaches the sensor's white (shorten the "
          "exposure), 2 its rim edge is blurred (refocus), 3 its rim is too small in the image (the "
          "texts name the camera); 4 a wheel's rim came out another size than its axle partner's (its "
          "angles may be off: the texts name the wheel); 5 a camera's grey is not proportional to light as "
          "configured (a gamma or LUT on: the texts name the camera)"),
    Field("roll_step", 115, "u16", 1, "in state roll: the roll the station waits for, 1..roll_steps; 0 in "
          "any other state"),
    Field("roll_steps", 116, "u16", 1, "in state roll: the rolls of the whole procedure (5); 0 in any other "
          "state"),
    Field("roll_distance_mm", 117, "i16", 1, "in state roll: how far to roll the car now, + forward, - back; "
          "0 in any other state", unit="mm", scale=1),
    Field("roll_position_mm", 118, "i16", 1, "in state roll: where the car must stand after this roll, from "
          "where it stood at the trigger, + forward; 0 in any other state", unit="mm", scale=1),
    Field("uncertain_reasons", 119, "u16", 1, "why each wheel of a cycle refused with fault 404 is less certain "
          "than the limit, 4 bits per wheel (FL bits 0-3, FR 4-7, RL 8-11, RR 12-15): 0 not refused; its two "
          "cameras see the rim's axis differently because 1 one camera's lip is at the sensor's white (shorten "
          "its exposure, shade the wheel), 2 on arcs the lip is no brighter than the tyre (shade or light the "
          "wheel evenly, clean the lip), 3 one camera's edge is fainter (clean and light the lip); 4 the lip's "
          "edge wavers round the rim (clean it, light it evenly, diffuse light on a glossy lip); 5 the lip's "
          "edge is faint or noisy (light the rim, a longer exposure, focus); 6 the calibration's share "
          "(calibrate again). The texts: fault_reason and the result's warnings"),
    *_angle_fields(),
    Field("result_job_id", 160, "ascii", 16, "job id of the cycle the result belongs to"),
    Field("fault_reason", 176, "ascii", 32, "readable reason of the fault, up to 64 characters"),
    *_runout_fields(),
    *_steer_fields(),
]
FIELDS = {f.name: f for f in PLC_FIELDS + STATION_FIELDS}

PLC_AREA = (0, 100)  # [start, end) of the PLC -> station area
STATION_AREA = (100, 300)  # [start, end) of the station -> PLC area
RESULT_BLOCK = (100, 225)  # one read (<= 125 registers): the whole station output up to map version 5
STEER_BLOCK = (225, 257)  # a second read: the steer prompt, the live steer angle, the steering results
STEER_STATUS_END = 232  # registers 225..231: what a PLC polls in state steer
RESULT_BLOCK_V4 = (100, 208)  # the whole output up to map version 4: a PLC reading only it still works
STATUS_END = 120  # registers 100..119: state, codes, counters, flags (what a PLC polls)
COMMAND = FIELDS["command"].address


def _check_map() -> None:
    """Fields must not overlap and must sit in their area (checked at import)."""
    taken: dict[int, str] = {}
    for f in FIELDS.values():
        lo, hi = PLC_AREA if f.writable else STATION_AREA
        if not (lo <= f.address and f.end <= hi):
            raise AssertionError(f"{f.name} outside its area")
        for a in range(f.address, f.end):
            if a in taken:
                raise AssertionError(f"{f.name} overlaps {taken[a]} at {a}")
            taken[a] = f.name
    blocks = (RESULT_BLOCK, STEER_BLOCK)
    assert all(hi - lo <= 125 for lo, hi in blocks)
    assert all(any(lo <= f.address and f.end <= hi for lo, hi in blocks) for f in STATION_FIELDS)


_check_map()


# --- encoding -----------------------------------------------------------------------------------
def f32_to_regs(x: float | None) -> list[int]:
    """float -> [high word, low word] (ABCD). None -> NaN."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", math.nan if x is None else float(x)))
    return [hi, lo]


def regs_to_f32(regs) -> float:
    return struct.unpack(">f", struct.pack(">HH", int(regs[0]), int(regs[1])))[0]


def u32_to_regs(x: int) -> list[int]:
    x = max(0, min(int(x), 0xFFFFFFFF))
    return [x >> 16, x & 0xFFFF]


def regs_to_u32(regs) -> int:
    return (int(regs[0]) << 16) | int(regs[1])


def to_i16(x: float | None, scale: int = INT16_SCALE) -> int:
    """A value -> ``scale`` counts per unit as an unsigned register value (two's complement),
    saturated to +-INT16_LIMIT counts; None or not finite -> INT16_MISSING."""
    if x is None or not math.isfinite(x):
        return INT16_MISSING & 0xFFFF
    n = max(-INT16_LIMIT, min(INT16_LIMIT, round(float(x) * scale)))
    return n & 0xFFFF


def from_i16(reg: int, scale: int = INT16_SCALE) -> float | int | None:
    n = reg - 0x10000 if reg & 0x8000 else reg
    if n == INT16_MISSING:
        return None
    return n if scale == 1 else n / scale


def deg_to_i16(x: float | None) -> int:
    """Degrees -> 0.01 degree counts as an unsigned register value (two's complement)."""
    return to_i16(x, INT16_SCALE)


def i16_to_deg(reg: int) -> float | None:
    return from_i16(reg, INT16_SCALE)


def ascii_to_regs(text: str | None, count: int) -> list[int]:
    """Text -> ``count`` registers, two characters each, high byte first, NUL padded.
    Longer text is cut; characters outside ASCII become '?'."""
    raw = (text or "").encode("ascii", "replace")[: 2 * count].ljust(2 * count, b"\0")
    return [(raw[2 * i] << 8) | raw[2 * i + 1] for i in range(count)]


def regs_to_ascii(regs) -> str:
    """Registers -> text up to the first NUL, surrounding spaces stripped. Raises ValueError
    if a byte is not printable ASCII."""
    raw = b"".join(struct.pack(">H", int(r)) for r in regs).split(b"\0", 1)[0]
    if any(b < 0x20 or b > 0x7E for b in raw):
        raise ValueError(f"not printable ASCII: {raw!r}")
    return raw.decode("ascii").strip()


def decode_block(regs, start: int = RESULT_BLOCK[0]) -> dict:
    """A block of registers read from ``start`` -> {field name: decoded value} for every field
    wholly inside it (the PLC side of the map; used by the simulator, tests and mbpoll checks)."""
    out: dict = {}
    for f in FIELDS.values():
        if f.address < start or f.end > start + len(regs):
            continue
        r = regs[f.address - start: f.end - start]
        if f.type in ("u16", "bits"):
            out[f.name] = int(r[0])
        elif f.type == "i16":
            out[f.name] = from_i16(int(r[0]), f.scale)
        elif f.type == "u32":
            out[f.name] = regs_to_u32(r)
        elif f.type == "f32":
            out[f.name] = regs_to_f32(r)
        else:
            try:
                out[f.name] = regs_to_ascii(r)
            except ValueError:
                out[f.name] = None
    return out


def angles_from_block(block: dict, kind: str = "f32") -> dict[str, float | None]:
    """Decoded block -> {angle name: degrees or None} from the float32 or the int16 copy."""
    out = {}
    for name in ANGLES:
        v = block[f"{name.replace('.', '_')}_{kind}"]
        out[name] = None if v is None or (isinstance(v, float) and math.isnan(v)) else v
    return out


# --- documentation ------------------------------------------------------------------------------
def _table(fields: list[Field]) -> list[str]:
    rows = ["| address | 4xxxx | registers | name | type | unit | meaning |",
            "|---:|---:|---:|---|---|---|---|"]
    for f in fields:
        rows.append(f"| {f.address} | {40001 + f.address} | {f.count} | `{f.name}` | {f.type} | "
                    f"{f.unit} | {f.doc} |")
    return rows


def markdown_tables() -> str:
    """The register tables of docs/plc.md, generated from this module."""
    lines = ["### PLC -> station (writable)", ""] + _table(PLC_FIELDS)
    lines += ["", "### Station -> PLC (read-only)", ""] + _table(STATION_FIELDS)
    lines += ["", "### Angle index (bit i of `pass_bits` / `judged_bits`)", "",
              "| bit | angle |", "|---:|---|"]
    lines += [f"| {i} | `{name}` |" for i, name in enumerate(ANGLES)]
    lines += [f"| {OVERALL_BIT} | overall |"]
    lines += ["", "### Command and state values", "", "| command | meaning |", "|---:|---|"]
    lines += [f"| {c} | {n} |" for c, n in COMMANDS.items()]
    lines += ["", "| state | meaning |", "|---:|---|"]
    lines += [f"| {c} | {n} |" for c, n in STATES.items()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown_tables(), end="")
