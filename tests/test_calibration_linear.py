"""The paper's closed form (eqs 4-22) on exact synthetic correspondences, and its refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration.box_linear import default_triplets, paper_box_calibration, triplet_system
from calibration.box_target import box_pose_on_floor
from calibration.camera_model import CameraModel, look_at
from calibration.errors import CalibrationError
from station.config import load_box

BOX_YAML = Path(__file__).resolve().parent.parent / "config" / "box.yaml"


@pytest.fixture(scope="module")
def box():
    return load_box(BOX_YAML)


def _camera(K, position=(2.08, 1.35, 0.33), yaw=35.0):
    R0, t0 = look_at(np.array(position), np.array([0.78, 1.35, 0.33]))
    Rb, tb = box_pose_on_floor([0.78, 1.35, 0.0], yaw)
    # camera relative to the box frame: x_cam = R0 (Rb B + tb) + t0
    return CameraModel("c", 1280, 1024, K, np.zeros(5), R0 @ Rb, R0 @ tb + t0)


@pytest.mark.parametrize("K", [np.array([[1800.0, 0, 640.0], [0, 1800.0, 512.0], [0, 0, 1]]),
                               np.array([[1812.7, 0, 655.3], [0, 1795.2, 498.1], [0, 0, 1]]),
                               np.array([[950.0, 0, 610.0], [0, 960.0, 530.0], [0, 0, 1]])])
@pytest.mark.parametrize("use_vertices", [True, False])
def test_paper_equations_recover_K_R_t_exactly(box, K, use_vertices):
    cam = _camera(K)
    points = box.vertices if use_vertices else box.points_box
    uv = cam.project(points)
    res = paper_box_calibration(points, uv)
    assert np.abs(res.K - K).max() / K[0, 0] < 1e-9
    assert np.abs(res.R - cam.R_cam_station).max() < 1e-9
    assert np.linalg.norm(res.t - cam.t_cam_station) / np.linalg.norm(cam.t_cam_station) < 1e-9
    z_true = cam.station_to_cam(points)[:, 2]
    assert np.abs(res.depths - z_true).max() / z_true.max() < 1e-9
    assert abs(np.linalg.det(res.R) - 1) < 1e-12
    # the null vector: smallest singular value ~0, the next one clearly not
    assert res.singular_values[-1] < 1e-9 * res.singular_values[0]
    assert res.singular_values[-2] > 1e-6 * res.singular_values[0]


def test_six_visible_vertices_suffice(box):
    """From a camera at the fixture, six vertices (two faces) are visible: enough for eq. 11."""
    K = np.array([[1800.0, 0, 640.0], [0, 1800.0, 512.0], [0, 0, 1]])
    cam = _camera(K)
    idx = np.array([0, 1, 2, 4, 5, 6])  # faces ny and px
    res = paper_box_calibration(box.vertices[idx], cam.project(box.vertices[idx]))
    assert np.abs(res.K - K).max() < 1e-7


def test_preconditioning_changes_nothing_on_exact_data_and_both_tolerate_noise(box):
    K = np.array([[1800.0, 0, 640.0], [0, 1800.0, 512.0], [0, 0, 1]])
    cam = _camera(K)
    uv = cam.project(box.points_box)
    a = paper_box_calibration(box.points_box, uv, precondition=True)
    assert np.abs(a.K - K).max() < 1e-8
    rng = np.random.default_rng(5)
    err_plain, err_pre = [], []
    for _ in range(10):
        noisy = uv + rng.normal(0, 0.3, uv.shape)
        err_plain.append(abs(paper_box_calibration(box.points_box, noisy).K[0, 0] - 1800))
        err_pre.append(abs(paper_box_calibration(box.points_box, noisy, precondition=True).K[0, 0] - 1800))
    # 0.3 px of noise: the algebraic closed form stays within ~1% of the focal length
    assert np.mean(err_pre) < 20 and np.mean(err_plain) < 20


def test_kronecker_rows_vanish_on_the_true_K_R(box):
    K = np.array([[1800.0, 0, 640.0], [0, 1790.0, 512.0], [0, 0, 1]])
    cam = _camera(K)
    uv = cam.project(box.vertices)
    P = triplet_system(box.vertices, np.c_[uv, np.ones(8)], default_triplets(8))
    assert P.shape == (3 * 56, 9)
    x = (K @ cam.R_cam_station).ravel(order="F")
    assert np.abs(P @ x).max() < 1e-9 * np.abs(P).max() * np.abs(x).max()


def test_coplanar_points_are_refused(box):
    K = np.array([[1800.0, 0, 640.0], [0, 1800.0, 512.0], [0, 0, 1]])
    cam = _camera(K)
    face = box.face("px").charuco_box
    with pytest.raises(CalibrationError, match="one plane"):
        paper_box_calibration(face, cam.project(face))


def test_too_few_points_are_refused(box):
    with pytest.raises(CalibrationError, match="at least 4"):
        paper_box_calibration(box.vertices[:3], np.zeros((3, 2)))


def test_nan_pixels_are_refused(box):
    uv = np.zeros((8, 2))
    uv[2] = np.nan
    with pytest.raises(CalibrationError, match="NaN"):
        paper_box_calibration(box.vertices, uv)
