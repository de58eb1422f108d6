"""station.rim.order_stats gives numpy's median and percentile, bit for bit (the detector's
results must not move by a rounding)."""

import numpy as np
import pytest

from station.rim.order_stats import median, percentile


@pytest.mark.parametrize("seed", range(4))
def test_median_is_numpys(seed):
    rng = np.random.default_rng(seed)
    for n in list(range(1, 40)) + [99, 100, 615, 1228, 1229]:
        for x in (rng.normal(size=n) * 50, np.round(rng.normal(size=n) * 3), np.abs(rng.normal(size=n))):
            got, want = median(x.copy()), np.median(x)
            assert got == want and type(got) is type(want)


def test_median_nan_and_empty():
    assert np.isnan(median(np.array([1.0, np.nan, 2.0])))
    assert np.isnan(median(np.array([], float)))
    assert median(np.array([3, 1, 2])) == 2  # integers: numpy's own


@pytest.mark.parametrize("q", [1.0, 50, 80, 90, 99.5, 100])
def test_percentile_is_numpys(q):
    rng = np.random.default_rng(int(q * 10))
    for n in list(range(1, 50)) + [96, 200, 1000]:
        for x in (rng.normal(size=n) * 50, np.round(rng.normal(size=n) * 3)):
            assert percentile(x.copy(), q) == np.percentile(x, q)
