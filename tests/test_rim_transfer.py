"""One camera's rim carried to the other camera of its pair (station/wheel/rim_transfer.py)."""
import numpy as np
import pytest

from calibration.camera_model import CameraModel, look_at
from station.rim.ellipse_fit import fit_direct
from station.wheel.rim_transfer import carried_prior, carried_rim

CENTRE = np.array([0.78, -1.35, 0.33])   # a front-right wheel's rim centre (station, m)
RADIUS = 0.2284


def _cams():
    out = []
    for name, pos in (("a", [2.1, -1.05, 0.36]), ("b", [2.1, -1.65, 0.30])):
        R, t = look_at(np.array(pos), CENTRE)
        K = np.array([[1800.0, 0, 640], [0, 1795.0, 512], [0, 0, 1]])
        out.append(CameraModel(name, 1280, 1024, K, np.array([-0.2, 0.08, 1e-4, -2e-4, 0.0]), R, t))
    return out


def _circle(axis, radius=RADIUS, n=720):
    axis = axis / np.linalg.norm(axis)
    e1 = np.cross(axis, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return CENTRE + radius * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)


def _ideal_ellipse(cam, X):
    """The circle's ellipse in ``cam``'s ideal pixels (no distortion), as detections give it."""
    P = cam.station_to_cam(X)
    xy = P[:, :2] / P[:, 2:]
    return fit_direct(np.stack([cam.K[0, 0] * xy[:, 0] + cam.K[0, 2], cam.K[1, 1] * xy[:, 1] + cam.K[1, 2]], axis=1))


@pytest.mark.parametrize("toe_deg,camber_deg", [(0.0, 0.0), (1.5, -2.0), (-2.0, 3.0)])
def test_the_rim_carried_from_one_camera_is_where_the_other_sees_it(toe_deg, camber_deg):
    a, b = _cams()
    axis = np.array([1.0, np.radians(toe_deg), np.radians(camber_deg)])
    X = _circle(axis)
    rim = carried_rim(_ideal_ellipse(a, X), a, axis, RADIUS)
    assert np.abs(np.linalg.norm(rim - CENTRE, axis=1) - RADIUS).max() < 1e-6   # the rim itself, in 3-D
    prior, truth = carried_prior(_ideal_ellipse(a, X), a, b, axis, RADIUS), _ideal_ellipse(b, X)
    np.testing.assert_allclose(prior.center_px, truth.center_px, atol=1e-6)
    np.testing.assert_allclose(prior.axes_px, truth.axes_px, atol=1e-6)


def test_an_axis_or_a_size_a_little_off_still_lands_within_two_pixels():
    """What the search refines from: the axis of a concentric contour (0.2 deg off here; a
    ring inside a simulated dark rim's barrel gave it 0.03 deg off), the axle partner's size
    (0.2 % off; a well-measured pair gives it to 0.05 %)."""
    a, b = _cams()
    axis = np.array([1.0, 0.01, -0.02])
    X = _circle(axis)
    truth = _ideal_ellipse(b, X)
    tilted = axis / np.linalg.norm(axis) + np.array([0.0, np.radians(0.2), np.radians(0.2)])
    for prior in (carried_prior(_ideal_ellipse(a, X), a, b, tilted, RADIUS),
                  carried_prior(_ideal_ellipse(a, X), a, b, axis, 1.002 * RADIUS)):
        assert np.linalg.norm(prior.center_px - truth.center_px) < 2.0
        assert np.abs(prior.axes_px - truth.axes_px).max() < 2.0


def test_a_plane_seen_edge_on_or_no_axis_carries_nothing():
    a, b = _cams()
    X = _circle(np.array([1.0, 0.0, 0.0]))
    view = CENTRE - a.center_station
    edge_on = np.cross(view, [0, 0, 1.0])   # the plane contains the camera's line of sight
    assert carried_prior(_ideal_ellipse(a, X), a, b, edge_on, RADIUS) is None
    assert carried_prior(_ideal_ellipse(a, X), a, b, np.zeros(3), RADIUS) is None         # no axis at all
    assert carried_prior(_ideal_ellipse(a, X), a, b, np.array([np.nan, 0, 0]), RADIUS) is None
