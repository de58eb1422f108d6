"""bench/real_photos.py judges a detection by the marks' true distances to its ellipse, wherever
the marks lie: a mark far inside a steep ellipse, near its major axis, included."""

import numpy as np
import pytest

from bench.real_photos import Wheel, exact_distance_px, judge
from station.rim.ellipse import Ellipse


def test_the_distance_of_a_mark_deep_inside_a_steep_ellipse_is_exact():
    e = Ellipse(np.array([1213.0, 997.0]), np.array([340.7, 100.3]), 1.5545)   # b/a 0.29, upright
    rng = np.random.default_rng(3)
    t = rng.uniform(0, 2 * np.pi, 60)
    marks = e.point_at(t) + rng.choice([-60.0, -30.0, 30.0, 60.0], 60)[:, None] * e.normal_at(t)
    dense = e.point_at(np.linspace(0, 2 * np.pi, 60_000, endpoint=False))          # feet 0.04 px apart
    nearest = np.sqrt(((marks[:, None, :] - dense[None]) ** 2).sum(axis=2).min(axis=1))
    inside = e.radius_ratio(marks) < 1
    np.testing.assert_allclose(exact_distance_px(e, marks), np.where(inside, -nearest, nearest), atol=1e-3)


def test_a_steep_ellipse_near_the_marks_is_judged_by_their_true_distances():
    """A photograph's case: the bottom mark 28 px inside an ellipse of b/a 0.29, where the
    foot from the mark's angle runs off (to 649 px) and the ellipse was judged another contour."""
    e = Ellipse(np.array([1213.0, 996.8]), np.array([340.7, 100.3]), 1.5545)
    marks = np.array([[1198.0, 637.0], [1210.0, 1305.0], [1310.0, 983.0]])   # top, bottom, near side
    status, dist = judge(e, [Wheel((1054.0, 501.0, 1628.0, 1438.0), marks, 668.0)])
    assert status == "detected"
    assert dist == pytest.approx([20.1, 27.6, 3.0], abs=0.1)
