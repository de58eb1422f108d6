"""station/ui/units.py against values computed by hand."""

from __future__ import annotations

import math

import pytest

from station.ui.units import format_angle, rim_diameter_m, toe_mm, toe_mm_view

RIM_17_IN_M = 17 * 0.0254  # 431.8 mm


@pytest.mark.parametrize("deg, text", [
    (0.25, "+0°15'"), (-1.5, "-1°30'"), (0.0, "+0°00'"), (1.0, "+1°00'"),
    (0.999, "+1°00'"),          # 59.94' rounds up to the next degree, not to 0°60'
    (-0.004, "+0°00'"),         # rounds to zero: no sign of a value that is not there
    (2.31, "+2°19'"),           # 0.31 x 60 = 18.6'
    (-0.1, "-0°06'"),
])
def test_degrees_and_minutes(deg, text):
    assert format_angle(deg, "dms") == text


def test_decimal_degrees_and_missing_values():
    assert format_angle(0.25) == "+0.25°"
    assert format_angle(-1.5, digits=3) == "-1.500°"
    assert format_angle(-0.001) == "+0.00°"
    for bad in (None, math.nan, math.inf, "0.1", True):
        assert format_angle(bad) == "–"
        assert format_angle(bad, "dms") == "–"


def test_toe_in_mm_at_the_rim():
    # 431.8 mm x sin(0.1 deg) = 431.8 x 0.00174533 = 0.7536 mm
    assert toe_mm(0.1, RIM_17_IN_M) == pytest.approx(0.7536, abs=1e-4)
    assert toe_mm_view(0.1, RIM_17_IN_M) == 0.8
    # 15-inch rim (381 mm), -0.25 deg: -381 x 0.0043633 = -1.662 mm
    assert toe_mm(-0.25, 0.381) == pytest.approx(-1.6624, abs=1e-4)
    assert toe_mm_view(-0.25, 0.381) == -1.7
    assert toe_mm_view(-0.001, RIM_17_IN_M) == 0.0 and str(toe_mm_view(-0.001, RIM_17_IN_M)) == "0.0"
    for toe, d in ((None, 0.4), (0.1, None), (0.1, 0.0), (0.1, -0.4), (math.nan, 0.4), (0.1, math.inf)):
        assert toe_mm(toe, d) is None and toe_mm_view(toe, d) is None


def test_the_rim_diameter_is_the_specs_or_twice_the_measured_radius():
    assert rim_diameter_m(0.2159) == pytest.approx(0.4318)
    assert rim_diameter_m(0.2159, 0.381) == 0.381
    assert rim_diameter_m(None, None) is None
    assert rim_diameter_m(math.nan) is None and rim_diameter_m(-0.2) is None
    assert rim_diameter_m(0.2, 0.0) == pytest.approx(0.4)
