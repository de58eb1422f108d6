"""detect_rim on the simulated station's images (simulators/world.py): both cameras of a pair,
truth = the true rim circle projected by the true camera (ideal pinhole pixels)."""

import numpy as np
import pytest

pytest.importorskip("simulators.world")

from simulators.world import SimWorld  # noqa: E402
from station.config import load_config  # noqa: E402
from station.rim import detect_rim  # noqa: E402
from station.rim.ellipse_fit import fit_direct  # noqa: E402

WHEEL_OF = {"cam5": "RL", "cam6": "RL", "cam1": "FR", "cam2": "FR", "cam3": "FL", "cam4": "FL",
            "cam7": "RR", "cam8": "RR"}


@pytest.fixture(scope="module")
def world():
    return SimWorld.from_config(load_config())


def _truth(world, scene, cam_id):
    v, cam = scene.vehicle, world.cameras[cam_id]
    c, Rw = v.wheel_frame_station(WHEEL_OF[cam_id])
    ang = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    circ = c + v.wheel.rim_radius_m * (np.cos(ang)[:, None] * Rw[:, 0] + np.sin(ang)[:, None] * Rw[:, 1])
    xc = cam.station_to_cam(circ)
    K = cam.K
    return fit_direct(xc[:, :2] / xc[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]])


def _check_pair(world, seed, cams, centre_tol, rms_tol):
    scene = world.vehicle_scene(seed)
    world.set_scene(scene)
    for cam_id in cams:
        cam = world.cameras[cam_id]
        det = detect_rim(world.render(cam_id), camera=cam, camera_id=cam_id)
        truth = _truth(world, scene, cam_id)
        K = cam.K
        ideal = det.points_norm * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
        d, _ = truth.distance(ideal)
        assert np.linalg.norm(det.ellipse.center_px - truth.center_px) < centre_tol, cam_id
        assert np.abs(det.ellipse.axes_px - truth.axes_px).max() < centre_tol, cam_id
        assert np.sqrt(np.mean(d**2)) < rms_tol, cam_id
        assert len(det.points_px) >= load_config().measurement.min_rim_points
        # the rim, not the tyre outline (about 1.4x larger) or the hub
        assert 0.97 < det.ellipse.axes_px[0] / truth.axes_px[0] < 1.03


def test_precision_and_reference_camera_of_one_pair(world):
    _check_pair(world, 1, ("cam5", "cam6"), centre_tol=0.5, rms_tol=0.3)


def test_the_rim_not_the_hub(world):
    # seed 5: a hub with a dark gap all round scores like a rim (closed, dark band outside,
    # a concentric contour outside); the larger tyre-bordered rim must win. The rim's lower
    # half is shaded so that the visible edge is ~2.5 px inside there: 1.5 px tolerance.
    _check_pair(world, 5, ("cam7",), centre_tol=1.5, rms_tol=1.5)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 5])
def test_all_cameras_of_more_vehicles(world, seed):
    # measured (bench/rim_detection.py): seed 3 within 0.14 px; seed 5 up to 1.45 px on the
    # cameras where the flange's lower half is shaded dark (docs/rim-detection.md, limits)
    _check_pair(world, seed, tuple(WHEEL_OF), centre_tol=1.6, rms_tol=1.5)


def test_the_rim_not_the_hub_when_its_tyre_band_is_lit(world):
    # seed 2, cam4: the tyre band just outside the rim is lit on part of the perimeter (ring
    # 0.7), the hub has a dark gap all round (ring 1.0); on the coarse search image the rim's
    # coverage (0.9) then scored below the hub's. A closed concentric contour more than 2.2x
    # larger makes a candidate the hub whatever its band (docs/rim-detection.md).
    _check_pair(world, 2, ("cam4",), centre_tol=1.0, rms_tol=1.0)
