"""The rims of an axle are one size: which wheel is warned of (station/wheel/rim_size.py)."""
from station.wheel.rim_size import RIM_SIZE_WARNING, size_mismatches

PARTNER = {"FL": "FR", "FR": "FL", "RL": "RR", "RR": "RL"}


def test_the_odd_rim_of_an_axle_is_named_with_how_much_and_which_way():
    (wheel, text), = size_mismatches({"FL": 0.24175, "FR": 0.2411, "RL": 0.2411, "RR": 0.2411}, PARTNER)
    assert wheel == "FL" and "0.6 mm larger in radius than FR's (0.27%)" in text and "on the tyre" in text
    (wheel, text), = size_mismatches({"FL": 0.2411, "FR": 0.2411, "RL": 0.2411, "RR": 0.2400}, PARTNER)
    assert wheel == "RR" and "1.1 mm smaller in radius than RL's" in text and "inside the flange" in text


def test_what_a_measurement_varies_by_and_a_staggered_car_are_not_warned_of():
    within = 0.2411 * (1 + 0.9 * RIM_SIZE_WARNING)
    assert size_mismatches({"FL": within, "FR": 0.2411, "RL": 0.2411, "RR": 0.2411}, PARTNER) == []
    assert size_mismatches({"FL": 0.2159, "FR": 0.2160, "RL": 0.2286, "RR": 0.2285}, PARTNER) == []  # 17/18 inch


def test_each_axle_is_judged_once_and_a_wheel_without_its_partner_not_at_all():
    found = size_mismatches({"FL": 0.2425, "FR": 0.2411, "RL": 0.2411, "RR": 0.2398}, PARTNER)
    assert sorted(w for w, _ in found) == ["FL", "RR"]
    assert size_mismatches({"FL": 0.2425, "RL": 0.2411, "RR": 0.2411}, PARTNER) == []
