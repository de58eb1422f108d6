"""The accuracy bench's range of stated std / RMS under honest statements (bench/accuracy.py)."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from bench.accuracy import GROUPS, honest_ratio_range

TOE = GROUPS["toe"]  # the four wheels' toe, as the bench names them


def _rows(stated: np.ndarray) -> list[dict]:
    """Cycles of four wheels' stated toe (deg), as the bench keeps them."""
    return [dict(zip(TOE, map(float, row))) for row in stated.reshape(-1, 4)]


def test_equal_statements_give_the_chi_square_range():
    n = 80
    lo, hi = honest_ratio_range(_rows(np.full(n, 0.005)), TOE)
    # ratio = 1 / sqrt(chi2_n / n): its 5th percentile from chi2's 95th, and the other way round
    assert abs(lo - 1 / np.sqrt(chi2.ppf(0.95, n) / n)) < 0.02
    assert abs(hi - 1 / np.sqrt(chi2.ppf(0.05, n) / n)) < 0.02


def test_a_few_large_statements_widen_the_range():
    even = honest_ratio_range(_rows(np.full(40, 0.005)), TOE)
    stated = np.full(40, 0.005)
    stated[:2] = 0.04  # two wheels whose views disagree, stated eight times the rest
    uneven = honest_ratio_range(_rows(stated), TOE)
    assert uneven[1] - uneven[0] > 2 * (even[1] - even[0])
    assert uneven[1] > 1.5  # honest statements of these sizes put it beyond 1.5 more than one time in twenty
