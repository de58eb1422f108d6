"""Each camera's own rim axis (station/wheel/view_agreement.py): exact on a clean rim's edge,
turned by an arc of one view lying off the edge, and what that adds to the uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from simulators.world import SimWorld
from station.config import load_config
from station.wheel.view_agreement import disagreement_covariance, view_agreement

RADIUS_M = 0.2159


@pytest.fixture(scope="module")
def fl_pair():
    """The built-in station's FL cameras (cam3, cam4) and a rim at the FL wheel, axis outward
    with 0.4 deg of toe and -0.8 deg of camber."""
    world = SimWorld.from_config(load_config(None))
    cams = (world.cameras["cam3"], world.cameras["cam4"])
    center = np.array([-0.78, 1.35, 0.33])
    toe, camber = np.radians(0.4), np.radians(-0.8)
    axis = np.array([-np.cos(camber) * np.cos(toe), np.cos(camber) * np.sin(toe), np.sin(camber)])
    return cams, center, axis / np.linalg.norm(axis)


def rim_points(center, axis, n=720):
    """(n,3) points on the rim circle, and their angles (n,) from the rim's top."""
    e_up = np.array([0.0, 0.0, 1.0]) - axis * axis[2]
    e_up /= np.linalg.norm(e_up)
    e_side = np.cross(axis, e_up)
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return center + RADIUS_M * (np.cos(phi)[:, None] * e_up + np.sin(phi)[:, None] * e_side), phi


def test_both_views_of_a_clean_rim_give_its_axis(fl_pair):
    cams, center, axis = fl_pair
    pts, _ = rim_points(center, axis)
    views = [cam.project(pts) for cam in cams]
    # start from an axis and centre a little off, as a pair's fit may be
    tilted = axis + np.radians(0.05) * np.array([0.0, 0.0, 1.0])
    agreement = view_agreement(views, cams, center + [0.002, -0.001, 0.001], tilted / np.linalg.norm(tilted), RADIUS_M)
    for own in agreement.axes_station:
        assert np.degrees(np.arccos(min(1.0, own @ axis))) < 0.002
    assert agreement.angle_deg < 0.003
    assert np.all(agreement.bias_deg_per_px > 0.1)  # views 13 deg off the axis: tenths of a degree per px
    assert np.all(disagreement_covariance(agreement, 0.05) == 0)


def test_an_arc_off_the_edge_in_one_view_turns_its_axis_and_adds_half_the_excess(fl_pair):
    cams, center, axis = fl_pair
    pts, phi = rim_points(center, axis)
    views = [cam.project(pts) for cam in cams]
    # cam3 sees the bottom third of the rim 1.2 px outside the flange edge (a dark lip's shading)
    image_center = cams[0].project(center[None])[0]
    bottom = np.cos(phi) < -0.5
    out = views[0][bottom] - image_center
    views[0] = views[0].copy()
    views[0][bottom] += 1.2 * out / np.linalg.norm(out, axis=1, keepdims=True)
    agreement = view_agreement(views, cams, center, axis, RADIUS_M)
    assert agreement.angle_deg > 0.2                     # tenths of a degree, where a clean rim gives thousandths
    own_r = agreement.axes_station[1]
    assert np.degrees(np.arccos(min(1.0, own_r @ axis))) < 0.005  # cam4 still sees the true axis
    cov = disagreement_covariance(agreement, 0.05)
    std_deg = np.degrees(np.sqrt(np.linalg.eigvalsh(cov)[1:]))   # the two directions across the axis
    excess = np.sqrt(agreement.angle_deg ** 2 - np.sum(agreement.std_deg ** 2)
                     - np.sum((0.05 * agreement.bias_deg_per_px) ** 2))
    assert std_deg == pytest.approx([excess / 2, excess / 2], rel=1e-6)
    assert abs(axis @ cov @ axis) < 1e-3 * np.trace(cov)  # (next to) nothing along the axis itself
    assert np.all(disagreement_covariance(agreement, 5.0) == 0)  # within what a 5 px bias explains: nothing added


def test_a_view_with_too_few_points_has_no_axis_of_its_own(fl_pair):
    cams, center, axis = fl_pair
    pts, _ = rim_points(center, axis, n=10)
    assert view_agreement([cam.project(pts) for cam in cams], cams, center, axis, RADIUS_M) is None
    assert np.all(disagreement_covariance(None, 0.05) == 0)


def test_an_arc_on_another_contour_far_from_the_pairs_circle_is_not_a_disagreement(fl_pair):
    """Points the pair's fit left out (another contour, 5 px inside: the lip's inner edge) are
    not on the rim the pair's circle rests on, and each view's own axis is fitted without them."""
    cams, center, axis = fl_pair
    pts, phi = rim_points(center, axis)
    views = [cam.project(pts) for cam in cams]
    image_center = cams[0].project(center[None])[0]
    bottom = np.cos(phi) < -0.5
    out = views[0][bottom] - image_center
    views[0] = views[0].copy()
    views[0][bottom] -= 5.0 * out / np.linalg.norm(out, axis=1, keepdims=True)
    assert view_agreement(views, cams, center, axis, RADIUS_M).angle_deg < 0.003
