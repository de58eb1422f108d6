"""The circle fit's uncertainty and how two fits of one wheel compare
(station/wheel/uncertainty.py), on hand-made fits and sector medians."""

from dataclasses import replace

import numpy as np
import pytest


def test_extra_points_bias_is_the_axis_change_beyond_the_noise():
    from station.wheel.fit import WheelFit
    from station.wheel.fit_compare import extra_points_bias2
    a = np.radians(0.05)
    cov = lambda s: np.diag([0.0, s, s]) ** 2  # noqa: E731 - (3,3), axis std s rad across it
    full = WheelFit("circle", np.zeros(3), np.array([1.0, 0, 0]), 0.2, cov_axis_noise=cov(np.radians(0.01)))
    tilted = np.array([np.cos(a), np.sin(a), 0.0])
    sub = WheelFit("circle", np.zeros(3), tilted, 0.2, cov_axis_noise=cov(np.radians(0.02)))
    excess = 2 * (np.radians(0.02) ** 2 - np.radians(0.01) ** 2)
    assert extra_points_bias2(full, sub) == pytest.approx(2 * (1 - np.cos(a)) - excess, rel=1e-6)
    flipped = WheelFit("circle", np.zeros(3), -tilted, 0.2, cov_axis_noise=sub.cov_axis_noise)
    assert extra_points_bias2(full, flipped) == pytest.approx(extra_points_bias2(full, sub))  # axis sign
    noisy = WheelFit("circle", np.zeros(3), tilted, 0.2, cov_axis_noise=cov(np.radians(0.2)))
    assert extra_points_bias2(full, noisy) == 0.0  # the noise explains the change


def test_fits_that_disagree_beyond_all_they_state_are_inconsistent():
    from station.wheel.fit import WheelFit
    from station.wheel.fit_compare import inconsistent
    cov = np.diag([0.0, 1.0, 1.0]) * np.radians(0.05) ** 2  # 0.05 deg each way across the axis
    a = WheelFit("circle", np.zeros(3), np.array([1.0, 0, 0]), 0.2, cov_axis=cov)

    def tilted(deg):
        t = np.radians(deg)
        return WheelFit("circle", np.zeros(3), -np.array([np.cos(t), 0, np.sin(t)]), 0.2, cov_axis=cov)

    assert not inconsistent(a, tilted(0.1))   # 0.1 deg apart: within 0.05 + 0.05 deg stated
    assert inconsistent(a, tilted(0.5))       # 0.5 deg: beyond what either states


def test_high_mode_amplitude_measures_modes_3_4_above_the_noise():
    from station.wheel.uncertainty import high_mode_amplitude
    sectors = np.arange(18)
    angle = (sectors + 0.5) * (2 * np.pi / 18) - np.pi
    se2 = np.full(18, 0.002 ** 2)
    rng = np.random.default_rng(0)
    smooth = 0.02 + 0.03 * np.cos(angle) + 0.05 * np.cos(3 * angle) + 0.03 * np.sin(4 * angle)
    amp = high_mode_amplitude(smooth + rng.normal(0, 0.002, 18), sectors, se2, 18)
    assert amp == pytest.approx(np.sqrt((0.05 ** 2 + 0.03 ** 2) / 4), rel=0.1)  # one function's share
    assert high_mode_amplitude(smooth[:10], sectors[:10], se2[:10], 18) == 0.0       # a short arc


def test_high_mode_amplitude_keeps_weak_modes():
    """A power at modes 3-4 below what one view's noise could tell is still estimated, not
    judged zero: over many noise draws its mean square comes back, and on noise alone it
    stays well under it."""
    from station.wheel.uncertainty import high_mode_amplitude
    sectors = np.arange(18)
    angle = (sectors + 0.5) * (2 * np.pi / 18) - np.pi
    sigma = 0.008
    se2 = np.full(18, sigma ** 2)
    weak = 0.003 * np.cos(3 * angle) + 0.003 * np.sin(4 * angle)
    rng = np.random.default_rng(1)
    power = [high_mode_amplitude(weak + rng.normal(0, sigma, 18), sectors, se2, 18) ** 2 for _ in range(4000)]
    noise = [high_mode_amplitude(rng.normal(0, sigma, 18), sectors, se2, 18) ** 2 for _ in range(4000)]
    true_power = (0.003 ** 2 + 0.003 ** 2) / 4   # one function's share
    assert 0.9 * true_power < np.mean(power) < 1.6 * true_power  # clipped at 0: a little above the truth
    assert np.mean(noise) < 0.6 * true_power


def test_a_fit_kept_against_a_disagreeing_one_states_their_difference():
    from station.wheel.fit import WheelFit
    from station.wheel.fit_compare import with_disagreement
    sd = np.radians(0.1)
    cov = np.diag([0.0, 1.0, 1.0]) * sd ** 2                 # +/-0.1 deg across the axis (x)
    a = WheelFit("circle", np.zeros(3), np.array([1.0, 0, 0]), 0.2, cov_axis=cov)
    t = np.radians(0.9)
    b = WheelFit("circle", np.zeros(3), -np.array([np.cos(t), np.sin(t), 0.0]), 0.2, cov_axis=cov)
    kept = with_disagreement(a, b)
    std_y = np.degrees(np.sqrt(kept.cov_axis[1, 1]))
    assert std_y == pytest.approx(np.sqrt(0.1 ** 2 + 0.5 * 0.9 ** 2), rel=0.01)  # equally sure: half the chance
    assert kept.cov_axis[2, 2] == pytest.approx(cov[2, 2])                     # nothing where they agree
    broken = replace(b, cov_axis=cov * 900)                                     # the other stated +/-3 deg
    assert np.degrees(np.sqrt(with_disagreement(a, broken).cov_axis[1, 1])) < 0.11


def test_the_grazing_choice_moves_smoothly_toward_the_subset_fit():
    """The fit of all points against the fit of a subset (the grazing points left out): the
    weight toward the subset is |b|^2 / (|b|^2 + V), b the extra points' estimated bias, V
    the variance the subset adds. A hard choice of the smaller expected error jumps by the
    whole difference where |b|^2 crosses V; the weighted fit passes through the midpoint."""
    from station.wheel.fit import WheelFit
    from station.wheel.fit_compare import toward, toward_subset_weight

    def cov(sd_deg):
        return np.diag([0.0, 1.0, 1.0]) * np.radians(sd_deg) ** 2  # across the axis (x)

    full = WheelFit("circle", np.zeros(3), np.array([1.0, 0, 0]), 0.2, cov_axis=cov(0.03),
                    cov_center=np.eye(3) * 1e-8, cov_axis_noise=cov(0.03))

    def subset(deg):  # the subset's axis ``deg`` away about z; it adds a variance V = 0.04^2 * 2
        t = np.radians(deg)
        return WheelFit("circle", np.array([0.0, 1e-3, 0]), -np.array([np.cos(t), np.sin(t), 0.0]), 0.2,
                        cov_axis=cov(0.05), cov_center=np.eye(3) * 4e-8, cov_axis_noise=cov(0.05))

    V = 2 * (np.radians(0.05) ** 2 - np.radians(0.03) ** 2)
    assert toward_subset_weight(full, subset(0.0)) == 0.0                      # no bias shown
    less_noisy = replace(subset(0.0), cov_axis=cov(0.02), cov_axis_noise=cov(0.02))
    assert toward_subset_weight(full, less_noisy) == 1.0                      # the subset surer
    # a difference whose excess over the noise equals V: exactly half way
    deg = np.degrees(np.sqrt(2 * V))
    w = toward_subset_weight(full, subset(deg))
    assert w == pytest.approx(0.5, abs=1e-6)
    mid = toward(full, subset(deg), w)
    assert np.degrees(np.arctan2(mid.axis_station[1], mid.axis_station[0])) == pytest.approx(deg / 2, rel=1e-3)
    assert mid.center_station[1] == pytest.approx(0.5e-3)
    # continuous across the old decision boundary: a small change of the bias moves it a little
    a, b = (toward(full, subset(x), toward_subset_weight(full, subset(x))) for x in (0.98 * deg, 1.02 * deg))
    assert np.degrees(np.arccos(a.axis_station @ b.axis_station)) < 0.1 * deg
    # and it states what is left: more than the full fit's noise, less than the subset's
    assert cov(0.03)[1, 1] < mid.cov_axis[1, 1] < cov(0.05)[1, 1] + np.radians(deg) ** 2
    assert toward(full, subset(deg), 0.0) is full and toward(full, subset(deg), 1.0).method == "circle"
