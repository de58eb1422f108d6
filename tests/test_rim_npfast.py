"""station.rim.npfast gives numpy's results, bit for bit (the detector's results must not
move by a rounding)."""

import numpy as np
import pytest

from station.rim.npfast import finite_rows, median, percentile, percentiles, row_norms, row_sq_sums, rows


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


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_percentiles_are_numpys(dtype):
    rng = np.random.default_rng(7)
    for n in list(range(1, 30)) + [96, 1000, 20000, 36423]:
        for x in ((rng.random(n) * 300).astype(dtype), np.round(rng.normal(size=n) * 4).astype(dtype)):
            for qs in ([50.0, 90.0], [1.0, 99.5], [0, 100], [50.0, 95.0]):
                got, want = percentiles(x, qs), np.percentile(x, qs)
                assert got.dtype == want.dtype and np.array_equal(got, want)
    x = (rng.random((60, 70)) * 255).astype(np.float32)[::3, ::2]  # a strided 2-D view, as the callers pass
    assert np.array_equal(percentiles(x, [1.0, 99.5]), np.percentile(x, [1.0, 99.5]))
    assert np.isnan(percentiles(np.array([1.0, np.nan]), [50.0, 90.0])).all()


def test_row_norms_are_numpys():
    rng = np.random.default_rng(3)
    for n in (1, 7, 1200, 30000):
        for dtype in (np.float64, np.float32):
            x = (rng.normal(size=(n, 2)) * 300).astype(dtype)
            want = np.linalg.norm(x, axis=1)
            assert np.array_equal(row_norms(x), want) and row_norms(x).dtype == want.dtype


def test_row_helpers_are_numpys():
    rng = np.random.default_rng(5)
    for n in (1, 7, 1200, 7000):
        for k in (2, 5):
            x = rng.normal(size=(n, k)) * 100
            x[rng.random((n, k)) < 0.05] = np.nan
            x[rng.random((n, k)) < 0.02] = np.inf
            assert np.array_equal(finite_rows(x), np.isfinite(x).all(axis=1))
        x = rng.normal(size=(n, 2)) * 300
        assert np.array_equal(row_sq_sums(x), (x ** 2).sum(axis=1))


def test_rows_is_fancy_indexing():
    rng = np.random.default_rng(9)
    a = rng.normal(size=(300, 2))
    for index in (rng.integers(0, 300, 50), np.sort(rng.integers(-300, 300, 400)), rng.random(300) < 0.3,
                  np.zeros(0, np.int64), np.zeros(300, bool)):
        got, want = rows(a, index), a[index]
        assert np.array_equal(got, want) and got.shape == want.shape and got.flags["C_CONTIGUOUS"]
    assert np.array_equal(rows(rng.normal(size=(40, 5, 5)), np.arange(40) % 3 == 0).shape, (14, 5, 5))
    with pytest.raises(IndexError):
        rows(a, np.ones(299, bool))
