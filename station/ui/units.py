"""Angles and toe as the shop reads them: decimal degrees or degrees and minutes, toe in mm at the rim.

Pure functions, no state. The pages format with the same rules (station/ui/static/common.js,
``Station.angle``, with the typographic minus and prime "−0°15′"); these are the reference the
tests check by hand-computed values.
"""

from __future__ import annotations

import math

ANGLE_FORMATS = ("decimal", "dms")


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def format_angle(value_deg: float | None, fmt: str = "decimal", digits: int = 2) -> str:
    """``+0.25`` -> "+0.25°" (decimal) or "+0°15'" (dms: whole minutes, rounded). No value: "–"."""
    if not _finite(value_deg):
        return "–"
    if fmt == "dms":
        minutes = round(abs(value_deg) * 60)
        sign = "-" if value_deg < 0 and minutes else "+"
        return f"{sign}{minutes // 60}°{minutes % 60:02d}'"
    text = f"{abs(value_deg):.{digits}f}"
    sign = "-" if value_deg < 0 and float(text) != 0 else "+"
    return f"{sign}{text}°"


def toe_mm(toe_deg: float | None, rim_diameter_m: float | None) -> float | None:
    """Toe as a length at the rim: the rim diameter x sin(toe), in mm (same sign as the toe);
    None without a toe or a usable diameter."""
    if not _finite(toe_deg) or not _finite(rim_diameter_m) or rim_diameter_m <= 0:
        return None
    return rim_diameter_m * 1000.0 * math.sin(math.radians(toe_deg))


def rim_diameter_m(measured_radius_m: float | None, spec_diameter_m: float | None = None) -> float | None:
    """The diameter toe in mm is taken at: the specification's when it gives one, else twice the
    wheel's measured rim radius; None when neither is known."""
    if _finite(spec_diameter_m) and spec_diameter_m > 0:
        return float(spec_diameter_m)
    if _finite(measured_radius_m) and measured_radius_m > 0:
        return 2.0 * float(measured_radius_m)
    return None


def toe_mm_view(toe_deg: float | None, rim_diameter: float | None) -> float | None:
    """:func:`toe_mm` rounded to one decimal, as the JSON carries it."""
    mm = toe_mm(toe_deg, rim_diameter)
    return None if mm is None else round(mm, 1) + 0.0  # + 0.0: no "-0.0"
