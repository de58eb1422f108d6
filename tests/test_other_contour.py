"""Arcs on another concentric contour: told apart from the rim, on exact synthetic rims."""

import numpy as np
import pytest

from calibration.camera_model import CameraModel, look_at
from simulators.vehicle import random_vehicle
from station.wheel.other_contour import radial_offsets_m, refit_other_contour
from station.wheel.circle_fit import refine_circle
from station.wheel.paper import reconstruct_paper

FLANGE_M = 0.011


def _pair(wheel_x, wheel_y):
    """A precision camera near the axis and an oblique reference camera, as on the station."""
    s = np.sign(wheel_x)
    target = np.array([wheel_x, wheel_y, 0.33])
    cams = []
    for name, pos in (("P", [wheel_x + s * 1.3, wheel_y, 0.45]), ("R", [wheel_x + s * 1.2, wheel_y - np.sign(wheel_y) * 0.7, 0.3])):
        R, t = look_at(np.array(pos), target)
        K = np.array([[1800.0, 0, 640], [0, 1795.0, 512], [0, 0, 1]])
        cams.append(CameraModel(name, 1280, 1024, K, np.array([-0.15, 0.05, 0, 0, 0]), R, t))
    return cams


def _views(seed, wheel="FR", inner_arc=True, noise_px=0.1):
    """Both cameras' edge points of one wheel; with ``inner_arc`` the bottom 44 % of the rim
    follows the flange's inner edge (FLANGE_M inside) in both views, as on a dark rim lit
    from above. Returns (vehicle, wheel centre, axis, radius, cameras, pixel points per view)."""
    rng = np.random.default_rng(seed)
    v = random_vehicle(np.random.default_rng(seed))
    c, Rw = v.wheel_frame_station(wheel)
    phi = np.linspace(-np.pi, np.pi, 1500, endpoint=False)
    up = Rw[:, 1] if abs(Rw[2, 1]) > abs(Rw[2, 0]) else Rw[:, 0]          # the in-plane direction nearest z
    sign = np.sign(up[2])
    u = np.cross(Rw[:, 2], up * sign)
    r = np.full(len(phi), v.wheel.rim_radius_m)
    if inner_arc:
        r[np.sin(phi) < -0.2] -= FLANGE_M                                   # the bottom 44 %: the inner edge
    X = c + r[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * up * sign)
    cams = _pair(c[0], c[1])
    pts = [cam.project(X) + rng.normal(0, noise_px, (len(X), 2)) for cam in cams]
    return v, c, Rw[:, 2], v.wheel.rim_radius_m, cams, pts


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def test_radial_offsets_of_a_circle_are_zero_and_of_a_concentric_one_its_distance():
    v, c, w, radius, (cp, cr), _ = _views(0, inner_arc=False, noise_px=0.0)
    _, Rw = v.wheel_frame_station("FR")
    phi = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    for r, expected in ((radius, 0.0), (radius - FLANGE_M, -FLANGE_M)):
        X = c + r * (np.cos(phi)[:, None] * Rw[:, 0] + np.sin(phi)[:, None] * Rw[:, 1])
        xy = cp.pixels_to_normalized(cp.project(X))
        np.testing.assert_allclose(radial_offsets_m(cp, xy, c, w, radius), expected, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_arc_on_the_inner_edge_tilts_the_circle_and_is_told_apart(seed):
    v, c, w, radius, (cp, cr), (pp, pr) = _views(seed)
    paper = reconstruct_paper(pp, pr, cp, cr)
    circle = refine_circle(pp, pr, cp, cr, paper)
    tilted = _angle_deg(circle.axis_station, w)
    assert tilted > 0.3, "the mixture of two radii must read as a tilt (else this test tests nothing)"
    alt = refit_other_contour(pp, pr, cp, cr, circle, above_deg=0.0)
    assert alt is not None
    assert _angle_deg(alt.axis_station, w) < 0.02 < tilted / 20
    assert np.linalg.norm(alt.center_station - c) < 1e-3
    assert alt.radius_m == pytest.approx(radius, abs=2e-4)
    assert alt.other_contour_mm == pytest.approx(-1e3 * FLANGE_M, abs=0.5)
    assert alt.arcs_left_out
    assert np.trace(alt.cov_axis) < np.trace(circle.cov_axis)


def test_a_clean_rim_is_left_alone_and_a_certain_circle_is_not_tested():
    v, c, w, radius, (cp, cr), (pp, pr) = _views(3, inner_arc=False)
    circle = refine_circle(pp, pr, cp, cr, reconstruct_paper(pp, pr, cp, cr))
    assert refit_other_contour(pp, pr, cp, cr, circle, above_deg=0.0) is None
    _, _, _, _, _, (qp, qr) = _views(3)
    mixed = refine_circle(qp, qr, cp, cr, reconstruct_paper(qp, qr, cp, cr))
    assert refit_other_contour(qp, qr, cp, cr, mixed, above_deg=90.0) is None  # within the limit: no test


def test_live_keeps_the_arcs_on_the_other_contour_out_by_the_last_circle():
    from station.wheel.other_contour import on_circle

    v, c, w, radius, (cp, cr), (pp, pr) = _views(4)
    circle = refine_circle(pp, pr, cp, cr, reconstruct_paper(pp, pr, cp, cr))
    alt = refit_other_contour(pp, pr, cp, cr, circle, above_deg=0.0)
    views = [(cam, cam.pixels_to_normalized(p)) for cam, p in ((cp, pp), (cr, pr))]
    for (cam, xy), keep in zip(views, on_circle(views, alt)):
        off = radial_offsets_m(cam, xy, c, w, radius)
        inner = off < -FLANGE_M / 2                       # the points generated on the inner edge
        assert not keep[inner].any()
        assert keep[~inner].mean() > 0.97
    # and the fit of what is kept is the wheel
    keep_p, keep_r = on_circle(views, alt)
    again = refine_circle(pp[keep_p], pr[keep_r], cp, cr, alt, init_is_fitted=True)
    assert _angle_deg(again.axis_station, w) < 0.02


def test_a_wild_hypothesis_behind_a_camera_explains_nothing_and_does_not_crash():
    """A window's circle fitted far off (seen on a dark rim: radius 1e8 m, centre behind the
    cameras) once made the offset histogram's bin width negative and bincount raise."""
    from dataclasses import replace

    from station.wheel.other_contour import other_contour_points

    v, c, w, radius, (cp, cr), (pp, pr) = _views(5)
    circle = refine_circle(pp, pr, cp, cr, reconstruct_paper(pp, pr, cp, cr))
    views = [(cam, cam.pixels_to_normalized(p)) for cam, p in ((cp, pp), (cr, pr))]
    C0 = cp.center_station
    behind = C0 - 1e8 * (c - C0) / np.linalg.norm(c - C0)  # 1e8 m behind the precision camera
    r_wild = float(np.median(radial_offsets_m(cp, views[0][1], behind, circle.axis_station, 0.0)))

    def wild(mask_l, mask_r, start):  # a circle through the points' rays, far behind
        return replace(circle, center_station=behind, radius_m=r_wild)

    assert other_contour_points(views, circle, wild) is None


def test_a_view_left_without_points_on_the_rim_contour_is_no_fit_and_does_not_crash():
    """On a harsh-light wheel a labelling left one view with no point of contour 1: the fit's
    noise covariance then divided by zero (a traceback in `station measure`)."""
    from station.wheel.other_contour import fit_two_contours
    from station.wheel.uncertainty import correlation_factor

    v, c, w, radius, (cp, cr), (pp, pr) = _views(6, inner_arc=False)
    circle = refine_circle(pp, pr, cp, cr, reconstruct_paper(pp, pr, cp, cr))
    views = [(cam, cam.pixels_to_normalized(p)) for cam, p in ((cp, pp), (cr, pr))]
    labels = [np.ones(len(views[0][1]), int), np.full(len(views[1][1]), 2)]
    assert fit_two_contours(views, labels, circle) is None
    labels[1][:5] = 1                                       # five points: still no circle on them
    assert fit_two_contours(views, labels, circle) is None
    assert correlation_factor(np.zeros(0)) == 1.0
    labels[1][:] = 1                                        # and the full views are the wheel
    assert _angle_deg(fit_two_contours(views, labels, circle).axis_station, w) < 0.02
