"""Each camera's own rim axis (station/wheel/view_agreement.py): exact on a clean rim's edge,
turned by an arc of one view lying off the edge, how far the pair's axis follows it, and what
that adds to the uncertainty and to the bound a wheel is refused by."""

from __future__ import annotations

import numpy as np
import pytest

from simulators.world import SimWorld
from station.config import load_config
from station.wheel.view_agreement import disagreement_bound_covariance, disagreement_covariance, view_agreement

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


def test_an_arc_off_the_edge_in_one_view_turns_its_axis_and_its_bound_is_half_the_excess(fl_pair):
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
    cov = disagreement_bound_covariance(agreement, 0.05)
    std_deg = np.degrees(np.sqrt(np.linalg.eigvalsh(cov)[1:]))   # the two directions across the axis
    excess = np.sqrt(agreement.angle_deg ** 2 - np.sum(agreement.std_deg ** 2)
                     - np.sum((0.05 * agreement.bias_deg_per_px) ** 2))
    assert std_deg == pytest.approx([excess / 2, excess / 2], rel=1e-6)
    assert abs(axis @ cov @ axis) < 1e-3 * np.trace(cov)  # (next to) nothing along the axis itself
    assert np.all(disagreement_bound_covariance(agreement, 5.0) == 0)  # within what a 5 px bias explains: nothing added
    assert np.all(disagreement_covariance(agreement, 5.0) == 0)


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


def _biased(points_px: np.ndarray, image_center: np.ndarray, mode: int, phase: float, amplitude_px: float):
    """Points (N,2) moved along their image radius by amplitude cos(mode * angle + phase)."""
    out = points_px - image_center
    angle = np.arctan2(out[:, 1], out[:, 0])
    return points_px + (amplitude_px * np.cos(mode * angle + phase))[:, None] * out / np.linalg.norm(out, axis=1,
                                                                                                      keepdims=True)


def test_the_pair_follows_a_views_own_tilt_by_the_share_its_fit_predicts(fl_pair):
    """A slow edge bias in one view alone (modes 1 and 2, four phases) turns that view's own
    axis and the pair's; the pair's turn over the view's is the share the linearised fit
    predicts (``ViewAgreement.follow`` for that view), and it is well under the whole."""
    from station.wheel.circle_fit import CircleFitSettings, refine_circle
    from station.wheel.fit import WheelFit
    from station.wheel.view_agreement import view_axis

    cams, center, axis = fl_pair
    pts, _ = rim_points(center, axis)
    views = [cam.project(pts) for cam in cams]
    settings = CircleFitSettings(occlusion_test=False, grazing_test=False, faint_test=False)
    init = WheelFit("circle", center + [0.003, -0.002, 0.001], axis, RADIUS_M + 0.002)
    clean = refine_circle(views[0], views[1], cams[0], cams[1], init, settings=settings)
    pair_per_px = np.array(clean.tilt_per_px_views)
    agreement = view_agreement(views, cams, clean.center_station, clean.axis_station, clean.radius_m, pair_per_px)
    image_center = cams[0].project(center[None])[0]
    pair_turns, own_turns = [], []
    for mode in (1, 2):
        for phase in (0.0, np.pi / 2):
            biased = _biased(views[0], image_center, mode, phase, 0.2)
            fit = refine_circle(biased, views[1], cams[0], cams[1], init, settings=settings)
            pair_turns.append(np.degrees(np.linalg.norm(fit.axis_station - clean.axis_station)))
            own = view_axis(biased, cams[0], center, axis, RADIUS_M)[0]
            own_turns.append(np.degrees(np.linalg.norm(own - agreement.axes_station[0])))
    share = np.sqrt(np.sum(np.square(pair_turns)) / np.sum(np.square(own_turns)))
    assert share == pytest.approx(pair_per_px[0] / agreement.bias_deg_per_px[0], rel=0.05)
    assert 0.2 < share < 0.8
    assert 0.2 < agreement.follow < 0.8


def test_the_stated_share_is_what_the_pair_follows_and_the_bound_is_half_in_every_direction(fl_pair):
    """The views' disagreement beyond what they explain: stated as ``follow`` of it spread over
    the two directions across the axis; the refusal's bound as half of it in each."""
    from station.wheel.view_agreement import ViewAgreement

    cams, center, axis = fl_pair
    across = np.cross(axis, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    base = dict(axes_station=np.array([axis, axis]), std_deg=np.zeros(2), bias_deg_per_px=np.array([0.4, 0.5]),
                disagreement_station=np.radians(0.3) * across)
    agreement = ViewAgreement(**base, pair_deg_per_px=np.array([0.2, 0.15]))
    follow = np.sqrt(np.mean([(0.2 / 0.4) ** 2, (0.15 / 0.5) ** 2]))
    assert agreement.follow == pytest.approx(follow)
    excess2 = 0.3 ** 2 - np.sum((0.05 * base["bias_deg_per_px"]) ** 2)
    stated = np.degrees(np.sqrt(np.linalg.eigvalsh(disagreement_covariance(agreement, 0.05))[1:]))
    assert stated == pytest.approx(np.sqrt(excess2 / 2) * follow * np.ones(2), rel=1e-6)
    bound = np.degrees(np.sqrt(np.linalg.eigvalsh(disagreement_bound_covariance(agreement, 0.05))[1:]))
    assert bound == pytest.approx(np.sqrt(excess2) / 2 * np.ones(2), rel=1e-6)
    assert np.all(bound > stated)
    # where the pair's fit did not say how far it follows, the statement is the bound's share
    unsaid = ViewAgreement(**base)
    assert np.trace(disagreement_covariance(unsaid, 0.05)) == pytest.approx(
        np.trace(disagreement_bound_covariance(unsaid, 0.05)), rel=1e-9)
