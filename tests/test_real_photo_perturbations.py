"""bench/real_photos.py's perturbations move the marks with the photograph: a bright dot at a
marked rim point lands where the perturbed mark says, so the bench judges the perturbed photo
against the right wheel. Synthetic images only (the photographs stay in ../shared)."""

import numpy as np
import pytest

from bench.real_photos import PERTURBATIONS, Wheel, perturbed


@pytest.mark.parametrize("kind", [k for k in PERTURBATIONS if k not in ("darker", "dark", "blurred")])
def test_a_marked_point_moves_with_the_photograph(kind):
    image = np.zeros((300, 400), np.uint8)
    mark = np.array([[250.0, 90.0]])
    image[88:93, 248:253] = 255                                   # a 5 px dot round the mark
    wheel = Wheel((200.0, 40.0, 300.0, 140.0), mark, 100.0)
    out, (moved,) = perturbed(image, [wheel], kind)
    y, x = np.nonzero(out > 127)
    np.testing.assert_allclose([x.mean(), y.mean()], moved.rim_points[0], atol=0.6)
    x1, y1, x2, y2 = moved.box
    assert x1 <= moved.rim_points[0, 0] <= x2 and y1 <= moved.rim_points[0, 1] <= y2


def test_frontal_stretches_the_largest_wheel_until_its_rim_is_near_round():
    from bench.real_photos import FRONTAL_RATIO

    image = np.zeros((600, 800), np.uint8)
    rim = np.array([[400.0, 200.0], [400.0, 400.0], [430.0, 300.0]])   # top, bottom, near side: b/a 0.3
    wheel = Wheel((340.0, 160.0, 460.0, 440.0), rim, 200.0)
    small = Wheel((40.0, 40.0, 80.0, 120.0), np.array([[60.0, 50.0], [60.0, 110.0], [70.0, 80.0]]), 60.0)
    out, (moved, _) = perturbed(image, [wheel, small], "frontal")
    top, bottom, side = moved.rim_points
    assert abs(side[0] - 0.5 * (top[0] + bottom[0])) == pytest.approx(FRONTAL_RATIO * 100.0, rel=0.02)
    assert bottom[1] - top[1] == pytest.approx(200.0)
    assert out.shape[0] < image.shape[0] and out.shape[1] > 2 * out.shape[0]     # cut round it, stretched 3x


def test_another_tone_curve_keeps_black_and_white_and_moves_the_greys():
    image = np.array([[0, 64, 128, 255]], np.uint8)
    wheel = Wheel((0.0, 0.0, 3.0, 0.0), np.zeros((0, 2)), 1.0)
    contrast, _ = perturbed(image, [wheel], "contrast")
    flat, _ = perturbed(image, [wheel], "flat")
    assert contrast[0, 0] == flat[0, 0] == 0 and contrast[0, 3] == flat[0, 3] == 255
    assert contrast[0, 2] == round(255 * (128 / 255) ** 1.5) and flat[0, 2] == round(255 * (128 / 255) ** 0.7)
