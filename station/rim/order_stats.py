"""``np.median`` and ``np.percentile`` of small 1-D float arrays, the same values by the same
arithmetic without numpy's generic machinery (axes, out, keepdims, methods, weights).

The detector takes some 40 medians and percentiles of arrays of 10^2-10^3 values per image,
where numpy's wrappers cost 6-20 us a call against 1-3 us for the partition itself. Both
functions are checked equal to numpy's, bit for bit, in tests/test_rim_order_stats.py.
"""

from __future__ import annotations

import numpy as np


def median(x: np.ndarray):
    """``np.median(x)`` of a 1-D float array x (N,): the middle value, or the mean of the two
    middle values as np.mean takes it ((a + b) / 2); NaN if x holds a NaN or is empty."""
    x = np.asarray(x)
    if x.ndim != 1 or x.dtype.kind != "f":
        return np.median(x)
    n = len(x)
    if n == 0:
        return np.float64(np.nan)
    h = n // 2
    even = n % 2 == 0
    part = np.partition(x, [h - 1, h, -1] if even else [h, -1])  # -1: a NaN sorts last
    if np.isnan(part[-1]):
        return np.float64(np.nan)
    return (part[h - 1] + part[h]) / 2 if even else part[h]


def percentile(x: np.ndarray, q: float) -> float:
    """``np.percentile(x, q)`` (linear method) of a 1-D finite float64 array x (N,), N >= 1,
    for one percentile q (0..100): numpy's virtual index and its two-sided interpolation."""
    n = len(x)
    at = (n - 1) * (q / 100)          # the virtual index
    if at >= n - 1:
        return float(x.max())
    lo = int(np.floor(at))
    part = np.partition(x, [lo, lo + 1])
    a, b, gamma = part[lo], part[lo + 1], at - lo
    diff = b - a
    return float(b - diff * (1 - gamma) if gamma >= 0.5 else a + diff * gamma)
