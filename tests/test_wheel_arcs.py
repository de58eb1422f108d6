"""The tests of a view's arcs (station/wheel/arcs.py) on residuals alone: which arcs the sidewall
test keeps, which stray, and the floor an arc's offset is judged against."""

import numpy as np
import pytest

from station.rim.npfast import sector_medians
from station.wheel.arcs import (HIDDEN_SECTORS, STRAY_MIN_PX, arc_median_noise, hidden_arcs, inward_arcs, stray_arcs, stray_floor_px)


def test_hidden_arcs_keeps_doubtful_arcs_that_agree_and_drops_those_inside():
    phi = np.linspace(-np.pi, np.pi, 2400, endpoint=False)
    rng = np.random.default_rng(0)
    r = rng.normal(0, 0.1, len(phi))
    safe = np.abs(phi) < 2.0                      # the arc near angle pi could be hidden
    inside = phi > 2.5                            # on part of it the edge is 2 px inside
    r[inside] -= 2.0
    keep = hidden_arcs(r, safe, phi, noise_px=0.3)
    assert keep[safe].all()
    assert keep[inside].mean() < 0.25             # whole 15-degree arcs go (a sector half inside stays)
    doubtful_agreeing = ~safe & (phi < -2.1)      # doubtful, but where the edge agrees
    assert keep[doubtful_agreeing].all()


def test_sector_medians_equal_numpy_per_sector():
    rng = np.random.default_rng(2)
    lab = rng.integers(0, 9, 500)
    lab[lab == 4] = 5                                           # one empty sector
    r = rng.normal(0, 1, 500)
    med, count = sector_medians(r, lab, 10)
    assert np.array_equal(count, np.bincount(lab, minlength=10))
    for k in range(10):
        assert (np.isnan(med[k]) if count[k] == 0 else med[k] == np.median(r[lab == k]))


def test_inward_arcs_flags_whole_arcs_inside_and_nothing_outside():
    phi = np.linspace(-np.pi, np.pi, 2400, endpoint=False)
    rng = np.random.default_rng(1)
    r = rng.normal(0, 0.1, len(phi))
    assert not inward_arcs(r, phi, noise_px=0.3).any()          # noise alone: nothing
    inside, outside = (phi > 0.3) & (phi < 0.8), (phi > -2.0) & (phi < -1.5)
    r[inside] -= 0.8
    r[outside] += 0.8                                           # occlusion never moves an edge outward
    flagged = inward_arcs(r, phi, noise_px=0.3)
    assert flagged[inside].mean() > 0.75 and not flagged[outside].any()
    sector = 2 * np.pi / HIDDEN_SECTORS                 # whole arcs: at most one arc's width more
    assert np.all((phi[flagged] > 0.3 - sector) & (phi[flagged] < 0.8 + sector))
    few = np.abs(phi) < 0.5                                     # fewer than 6 arcs: no judgement
    assert not inward_arcs(r[few], phi[few], noise_px=0.3).any()
    stray = stray_arcs(r, phi, noise_px=0.3)                    # ... and both sides
    assert stray[inside].mean() > 0.75 and stray[outside].mean() > 0.75
    assert not stray[(phi > 1.5) & (phi < 2.5)].any()


def test_arc_median_noise_is_the_standard_error_of_one_arcs_median():
    phi = np.linspace(-np.pi, np.pi, 2400, endpoint=False)      # 100 points per arc
    rng = np.random.default_rng(4)
    for sigma in (0.05, 0.15):
        r = rng.normal(0, sigma, len(phi))
        expected = 1.2533 * sigma / 10
        assert arc_median_noise(r, phi) == pytest.approx(expected, rel=0.15)
        lab = ((phi + np.pi) / (2 * np.pi) * HIDDEN_SECTORS).astype(int)
        biased = r + rng.normal(0, 0.1, HIDDEN_SECTORS)[lab]   # arcs' own biases are not noise
        assert arc_median_noise(biased, phi) == pytest.approx(expected, rel=0.15)
    few = np.abs(phi) < 0.5
    assert arc_median_noise(r[few], phi[few]) == float("inf")


def test_the_stray_floor_follows_the_views_noise():
    """With the medians known to 0.006 px, an arc 0.1 px off strays; the old fixed 0.3 px kept
    it. Noise alone flags no arc, and the floor never exceeds the loss scale."""
    phi = np.linspace(-np.pi, np.pi, 2400, endpoint=False)
    arc = (phi > 0.3) & (phi < 1.3)
    for seed in range(20):
        r = np.random.default_rng(seed).normal(0, 0.05, len(phi))
        floor = stray_floor_px(r, phi, 0.3)
        assert 0.02 < floor < 0.05
        assert not stray_arcs(r, phi, floor).any()
        r[arc] += 0.1
        floor = stray_floor_px(r, phi, 0.3)
        assert stray_arcs(r, phi, floor)[arc].mean() > 0.75 and not stray_arcs(r, phi, 0.3).any()
    noisy = np.random.default_rng(1).normal(0, 2.0, len(phi))
    assert stray_floor_px(noisy, phi, 0.3) == 0.3
    exact = 1e-13 * np.sin(7 * phi)                             # noise-free points: no arc is judged on rounding
    assert stray_floor_px(exact, phi, 0.3) == STRAY_MIN_PX
    assert not stray_arcs(exact, phi, stray_floor_px(exact, phi, 0.3)).any()
