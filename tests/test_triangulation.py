"""Triangulation: the paper's eq. 24 is exact on exact rays, agrees with OpenCV, and the
optimal variant does better under image noise."""

import cv2
import numpy as np
import pytest

from calibration.camera_model import rodrigues_to_matrix
from calibration.triangulation import (correct_matches, essential_matrix, homogeneous,
                                       opencv_from_paper, paper_from_opencv,
                                       reprojection_error, triangulate_dlt, triangulate_optimal,
                                       triangulate_paper, triangulate_paper_full)


def _pair(seed=0):
    """A verged stereo pair in OpenCV form and its paper form."""
    R_rl = rodrigues_to_matrix(np.array([0.02, -0.25, 0.01]))
    t_rl = np.array([-0.6, 0.02, 0.08])
    R, t = paper_from_opencv(R_rl, t_rl)
    return R_rl, t_rl, R, t


def _points(n=400, seed=1):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-0.7, 0.7, n), rng.uniform(1.5, 6, n)])


def _observe(X, R_rl, t_rl):
    Xr = X @ R_rl.T + t_rl
    return X / X[:, 2:], Xr / Xr[:, 2:]


def test_conversion_round_trip_and_eq25():
    R_rl, t_rl, R, t = _pair()
    X = _points(10)
    Xr = X @ R_rl.T + t_rl
    np.testing.assert_allclose(Xr @ R + t, X, atol=1e-12)  # P_l = R^T P_r + t (row form)
    R2, t2 = opencv_from_paper(R, t)
    np.testing.assert_allclose(R2, R_rl, atol=1e-15)
    np.testing.assert_allclose(t2, t_rl, atol=1e-15)


def test_paper_eq24_exact_on_exact_rays():
    R_rl, t_rl, R, t = _pair()
    X = _points()
    p_l, p_r = _observe(X, R_rl, t_rl)
    P, gap = triangulate_paper(p_l, p_r, R, t, return_gap=True)
    np.testing.assert_allclose(P, X, atol=1e-9)
    assert gap.max() < 1e-9
    full = triangulate_paper_full(p_l, p_r, R, t)
    np.testing.assert_allclose(full.z_l, X[:, 2], atol=1e-9)
    np.testing.assert_allclose(full.z_r, (X @ R_rl.T + t_rl)[:, 2], atol=1e-9)


def test_gap_is_the_distance_between_skew_rays():
    # Left ray along z through the origin; right camera 1 m to the right (t = (1,0,0)) with
    # a ray along z offset vertically by shifting it: the right ray's direction chosen so
    # the rays are skew with a known 0.1 m separation along y.
    R = np.eye(3)
    t = np.array([1.0, 0.1, 0.0])          # right centre at (1, 0.1, 0) in the left frame
    p_l = np.array([[0.0, 0.0, 1.0]])       # ray x=0,y=0
    p_r = np.array([[-1.0 / 4.0, 0.0, 1.0]])  # from (1,0.1,0) toward (0,0.1,4)
    full = triangulate_paper_full(p_l, p_r, R, t)
    assert full.gap[0] == pytest.approx(0.1, abs=1e-12)
    np.testing.assert_allclose(full.points_l[0], [0, 0, 4], atol=1e-12)
    np.testing.assert_allclose(full.midpoint_l[0], [0, 0.05, 4], atol=1e-12)


def test_parallel_rays_give_nan():
    R = np.eye(3)
    t = np.array([0.5, 0, 0])
    p = np.array([[0.1, 0.2, 1.0]])
    P = triangulate_paper(p, p, R, t)
    assert np.all(np.isnan(P))


def test_agrees_with_cv2_triangulatePoints_under_noise():
    R_rl, t_rl, R, t = _pair()
    X = _points(300, seed=3)
    p_l, p_r = _observe(X, R_rl, t_rl)
    rng = np.random.default_rng(4)
    p_l[:, :2] += rng.normal(0, 2e-4, (len(X), 2))
    p_r[:, :2] += rng.normal(0, 2e-4, (len(X), 2))
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([R_rl, t_rl[:, None]])
    Xh = cv2.triangulatePoints(P1, P2, p_l[:, :2].T.copy(), p_r[:, :2].T.copy())
    X_cv = (Xh[:3] / Xh[3]).T
    np.testing.assert_allclose(triangulate_dlt(p_l, p_r, R, t), X_cv, atol=1e-9)
    # eq. 24 and the optimal method are different estimators: close to OpenCV's, not equal.
    d = np.linalg.norm(triangulate_paper(p_l, p_r, R, t) - X_cv, axis=1)
    assert np.median(d) < 5e-3 and d.max() < 0.1
    d = np.linalg.norm(triangulate_optimal(p_l, p_r, R, t) - X_cv, axis=1)
    assert np.median(d) < 5e-3


def test_correct_matches_equals_hartley_sturm():
    R_rl, t_rl, R, t = _pair()
    X = _points(200, seed=5)
    p_l, p_r = _observe(X, R_rl, t_rl)
    rng = np.random.default_rng(6)
    p_l[:, :2] += rng.normal(0, 1e-3, (len(X), 2))
    p_r[:, :2] += rng.normal(0, 1e-3, (len(X), 2))
    E = essential_matrix(R, t)
    cl, cr = correct_matches(p_l, p_r, E)
    np.testing.assert_allclose(np.einsum("ij,jk,ik->i", cr, E, cl), 0, atol=1e-12)
    # OpenCV's correctMatches(F, pts1, pts2) enforces pts2^T F pts1 = 0.
    a, b = cv2.correctMatches(E, p_l[None, :, :2].copy(), p_r[None, :, :2].copy())
    np.testing.assert_allclose(cl[:, :2], a[0], atol=1e-9)
    np.testing.assert_allclose(cr[:, :2], b[0], atol=1e-9)


def test_optimal_has_lower_reprojection_error_than_paper():
    R_rl, t_rl, R, t = _pair()
    X = _points(500, seed=7)
    p_l, p_r = _observe(X, R_rl, t_rl)
    rng = np.random.default_rng(8)
    p_l[:, :2] += rng.normal(0, 5e-4, (len(X), 2))
    p_r[:, :2] += rng.normal(0, 5e-4, (len(X), 2))
    e_paper = reprojection_error(triangulate_paper(p_l, p_r, R, t), p_l, p_r, R, t)
    e_opt = reprojection_error(triangulate_optimal(p_l, p_r, R, t), p_l, p_r, R, t)
    assert np.all(e_opt <= e_paper + 1e-12)
    assert e_opt.mean() < 0.8 * e_paper.mean()
    # and 3-D accuracy: the optimal points are at least as close to the truth on average
    err_paper = np.linalg.norm(triangulate_paper(p_l, p_r, R, t) - X, axis=1).mean()
    err_opt = np.linalg.norm(triangulate_optimal(p_l, p_r, R, t) - X, axis=1).mean()
    assert err_opt < err_paper


def test_homogeneous_and_shape_checks():
    np.testing.assert_array_equal(homogeneous(np.array([[1.0, 2.0]])), [[1, 2, 1]])
    with pytest.raises(ValueError):
        triangulate_paper(np.zeros((3, 3)), np.zeros((4, 3)), np.eye(3), np.zeros(3))
