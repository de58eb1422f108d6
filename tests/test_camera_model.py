"""The camera model matches OpenCV's projection and its exact inverse, with 5, 8 and 12
distortion coefficients (OpenCV's rational and thin-prism terms)."""

import cv2
import numpy as np
import pytest

from calibration.camera_model import (CameraModel, _distortion_jacobian, look_at, matrix_to_rodrigues,
                                      rodrigues_to_matrix, undistort_normalized, distort_normalized)

RATIONAL = [-0.21, 0.09, 3e-4, -2e-4, -0.01, 0.03, -0.02, 0.01]           # k1 k2 p1 p2 k3 k4 k5 k6
PRISM = [*RATIONAL, 1.5e-3, -8e-4, -1.2e-3, 6e-4]                          # + s1 s2 s3 s4
STRONG_RATIONAL = [2.5, 1.2, 3e-4, -2e-4, 0.05, 2.8, 2.0, 0.3]              # large terms that nearly cancel


def _camera(dist):
    R, t = look_at(np.array([2.0, 1.3, 0.4]), np.array([0.78, 1.35, 0.33]))
    K = np.array([[1812.0, 0, 652.3], [0, 1809.5, 498.7], [0, 0, 1]])
    return CameraModel("cam1", 1280, 1024, K, np.array(dist, float), R, t)


@pytest.mark.parametrize("dist", [[0, 0, 0, 0, 0], [-0.21, 0.09, 3e-4, -2e-4, -0.01], [0.05, -0.04, -4e-4, 5e-4, 0.015],
                                  RATIONAL, PRISM, STRONG_RATIONAL])
def test_projection_matches_opencv(dist):
    cam = _camera(dist)
    rng = np.random.default_rng(1)
    pts = np.array([0.78, 1.35, 0.33]) + rng.uniform(-0.35, 0.35, (500, 3))
    ours = cam.project(pts)
    ref, _ = cv2.projectPoints(pts, cam.rvec, cam.t_cam_station, cam.K, cam.dist)
    np.testing.assert_allclose(ours, ref[:, 0, :], atol=1e-9)


@pytest.mark.parametrize("dist", [[-0.21, 0.09, 3e-4, -2e-4, -0.01], [0.05, -0.04, -4e-4, 5e-4, 0.015],
                                  RATIONAL, PRISM, STRONG_RATIONAL])
def test_unprojection_is_the_exact_inverse(dist):
    cam = _camera(dist)
    rng = np.random.default_rng(2)
    uv = rng.uniform([0, 0], [1279, 1023], (2000, 2))
    xy = cam.pixels_to_normalized(uv)
    np.testing.assert_allclose(cam.normalized_to_pixels(xy), uv, atol=1e-9)
    # OpenCV's iterative undistortion agrees (it stops earlier, so a looser tolerance).
    ref = cv2.undistortPoints(uv[:, None, :], cam.K, cam.dist, None, None,
                              criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))[:, 0, :]
    np.testing.assert_allclose(xy, ref, atol=1e-9)


def test_rays_hit_the_projected_points():
    cam = _camera([-0.2, 0.08, 1e-4, 1e-4, 0.0])
    pts = np.array([[0.7, 1.2, 0.2], [0.9, 1.5, 0.5], [0.8, 1.35, 0.33]])
    origin, dirs = cam.rays_station(cam.project(pts))
    to_pts = pts - origin
    cos = np.sum(dirs * to_pts, axis=1) / np.linalg.norm(to_pts, axis=1)
    np.testing.assert_allclose(cos, 1.0, atol=1e-12)


def test_rodrigues_round_trip_matches_opencv():
    rng = np.random.default_rng(3)
    for _ in range(50):
        r = rng.normal(size=3) * rng.uniform(0, 3)
        R = rodrigues_to_matrix(r)
        np.testing.assert_allclose(R, cv2.Rodrigues(r)[0], atol=1e-12)
        np.testing.assert_allclose(rodrigues_to_matrix(matrix_to_rodrigues(R)), R, atol=1e-10)


def test_look_at_puts_target_on_the_optical_axis_with_image_up():
    cam = _camera([0, 0, 0, 0, 0])
    uv = cam.project(np.array([[0.78, 1.35, 0.33], [0.78, 1.35, 0.6]]))
    np.testing.assert_allclose(uv[0], cam.K[:2, 2], atol=1e-9)
    assert uv[1, 1] < uv[0, 1]  # higher in the world = smaller v (image y down)


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="cam9: K"):
        CameraModel("cam9", 10, 10, np.eye(2))
    with pytest.raises(ValueError, match="NaN"):
        CameraModel("cam9", 10, 10, np.eye(3), dist=np.array([np.nan, 0, 0, 0, 0]))


def test_undistort_gives_nan_outside_the_lens_field():
    xy = undistort_normalized(np.array([[50.0, 50.0]]), np.array([-0.5, 0.0, 0, 0, 0]))
    assert np.all(np.isnan(xy)) or np.allclose(distort_normalized(xy, np.array([-0.5, 0, 0, 0, 0])), [[50, 50]])


@pytest.mark.parametrize("dist", [[-0.21, 0.09, 3e-4, -2e-4, -0.01], RATIONAL, PRISM, STRONG_RATIONAL])
def test_the_distortion_jacobian_is_the_derivative(dist):
    rng = np.random.default_rng(4)
    xy = rng.uniform(-0.4, 0.4, (300, 2))
    d, h = np.array(dist), 1e-6
    numeric = np.stack([(distort_normalized(xy + e, d) - distort_normalized(xy - e, d)) / (2 * h)
                        for e in ([h, 0], [0, h])], axis=2)
    np.testing.assert_allclose(_distortion_jacobian(xy, d), numeric, atol=1e-8)


def test_zero_rational_and_prism_terms_give_the_five_term_model_bit_for_bit():
    rng = np.random.default_rng(5)
    xy = rng.uniform(-0.4, 0.4, (1000, 2))
    five = np.array([-0.21, 0.09, 3e-4, -2e-4, -0.01])
    for longer in (np.r_[five, np.zeros(3)], np.r_[five, np.zeros(7)]):
        assert np.array_equal(distort_normalized(xy, longer), distort_normalized(xy, five))
        assert np.array_equal(undistort_normalized(xy, longer), undistort_normalized(xy, five))


@pytest.mark.parametrize("n, message", [(14, "tilted-sensor terms tauX tauY"), (4, "takes 5 .* 8 .* or 12"),
                                        (6, "takes 5 .* 8 .* or 12")])
def test_other_distortion_lengths_are_refused_with_the_reason(n, message):
    with pytest.raises(ValueError, match=f"cam9: dist has {n} coefficients.*{message}"):
        CameraModel("cam9", 10, 10, np.eye(3), dist=np.zeros(n))
    with pytest.raises(ValueError, match="tilted" if n == 14 else "coefficients"):
        distort_normalized(np.zeros((1, 2)), np.ones(n))
