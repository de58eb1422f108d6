"""Odometry estimators on synthetic points (no images): the paper's eqs 43-48 are exact on
exact data, the robust variant survives outliers that break the pseudo-inverse."""

import numpy as np
import pytest

from calibration.camera_model import rodrigues_to_matrix
from calibration.triangulation import paper_from_opencv
from station.odometry.paper_vo import (compose_positions, homogeneous_matrix, paper_step,
                                       split_transform, transform_matrix)
from station.odometry.robust_vo import RobustSettings, kabsch, robust_step
from station.odometry.trajectory import Trajectory, distance_travelled, step_errors, summarize

F_PX = 480.0


def _rig():
    return paper_from_opencv(np.eye(3), np.array([-0.3, 0.0, 0.0]))


def _motion():
    """P = A Q + b: camera at step i seen from step i-1 (a yaw turn and a forward move)."""
    A = rodrigues_to_matrix(np.array([0.01, 0.12, -0.005]))
    b = np.array([0.05, -0.02, 0.4])
    return A, b


def _observations(n=300, seed=0, noise_px=0.0, outlier_frac=0.0):
    rng = np.random.default_rng(seed)
    P = np.column_stack([rng.uniform(-4, 4, n), rng.uniform(-1.5, 1.0, n), rng.uniform(2, 9, n)])
    A, b = _motion()
    Q = (P - b) @ A                                  # Q = A^T (P - b), rows
    R, t = _rig()
    R_rl, t_rl = np.eye(3), np.array([-0.3, 0.0, 0.0])

    def obs(X):
        pl = X / X[:, 2:]
        Xr = X @ R_rl.T + t_rl
        pr = Xr / Xr[:, 2:]
        pl[:, :2] += rng.normal(0, noise_px / F_PX, (n, 2))
        pr[:, :2] += rng.normal(0, noise_px / F_PX, (n, 2))
        return pl, pr

    pl0, pr0 = obs(P)
    pl1, pr1 = obs(Q)
    m = rng.random(n) < outlier_frac                 # wrong temporal matches
    perm = rng.permutation(np.flatnonzero(m))
    pl1[m], pr1[m] = pl1[perm], pr1[perm]
    return pl0, pr0, pl1, pr1, R, t, A, b


def test_homogeneous_matrices_and_split_are_eqs_43_to_46():
    pts = np.arange(12.0).reshape(4, 3)
    H = homogeneous_matrix(pts)
    assert H.shape == (4, 4)
    np.testing.assert_array_equal(H[3], 1)
    np.testing.assert_array_equal(H[:3], pts.T)
    A, b = _motion()
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = A, b
    R_bar, t_bar = split_transform(M)
    np.testing.assert_array_equal(R_bar, A.T)
    np.testing.assert_array_equal(t_bar, b)


def test_paper_step_exact_on_exact_data():
    pl0, pr0, pl1, pr1, R, t, A, b = _observations()
    est = paper_step(pl0, pr0, pl1, pr1, R, t)
    np.testing.assert_allclose(est.R_bar, A.T, atol=1e-9)
    np.testing.assert_allclose(est.t_bar, b, atol=1e-9)
    # and M's last row is exactly [0 0 0 1] since Q's last row is ones
    P = homogeneous_matrix(est.points_prev)
    M = transform_matrix(P, P)
    np.testing.assert_allclose(M, np.eye(4), atol=1e-9)


def test_composition_eq47_equals_eq48_and_trajectory():
    rng = np.random.default_rng(3)
    R_bars = np.array([rodrigues_to_matrix(rng.normal(0, 0.2, 3)) for _ in range(6)])
    t_bars = rng.normal(0, 0.5, (6, 3))
    B = compose_positions(R_bars, t_bars)
    # eq. 48, explicit: B_i = B_0 + sum_m (prod_{n<m} R_bar_n^T) t_bar_m, R_bar_0 = I
    for i in range(1, 7):
        acc, total = np.eye(3), np.zeros(3)
        for m in range(1, i + 1):
            total += acc @ t_bars[m - 1]
            acc = acc @ R_bars[m - 1].T
        np.testing.assert_allclose(B[i], total, atol=1e-12)
    traj = Trajectory()
    for Rb, tb in zip(R_bars, t_bars):
        traj.append(Rb, tb)
    np.testing.assert_allclose(traj.positions, B, atol=1e-12)


def test_kabsch_exact_and_batched():
    _, _, _, _, _, _, A, b = _observations()
    rng = np.random.default_rng(4)
    Q = rng.normal(size=(50, 3))
    P = Q @ A.T + b
    A1, b1 = kabsch(P, Q)
    np.testing.assert_allclose(A1, A, atol=1e-12)
    np.testing.assert_allclose(b1, b, atol=1e-12)
    A2, b2 = kabsch(np.stack([P, P]), np.stack([Q, Q]))
    assert A2.shape == (2, 3, 3)
    np.testing.assert_allclose(A2[1], A, atol=1e-12)
    # a reflection is never returned
    A3, _ = kabsch(P * [1, 1, -1], Q)
    assert np.linalg.det(A3) == pytest.approx(1.0)


def test_robust_survives_outliers_that_break_the_pseudo_inverse():
    pl0, pr0, pl1, pr1, R, t, A, b = _observations(noise_px=0.3, outlier_frac=0.3, seed=5)
    paper = paper_step(pl0, pr0, pl1, pr1, R, t)
    robust = robust_step(pl0, pr0, pl1, pr1, R, t, F_PX)
    err_paper = np.linalg.norm(paper.t_bar - b)
    err_robust = np.linalg.norm(robust.t_bar - b)
    assert err_robust < 0.005
    assert err_paper > 20 * err_robust
    # the robust step is a rotation; the paper's block is not
    np.testing.assert_allclose(robust.R_bar @ robust.R_bar.T, np.eye(3), atol=1e-12)
    assert np.abs(paper.R_bar @ paper.R_bar.T - np.eye(3)).max() > 1e-3
    # about 30 % of the matches are wrong (a few permuted onto themselves stay right)
    assert 0.6 * len(pl0) < robust.inliers.sum() < 0.8 * len(pl0)


def test_robust_refinement_helps_under_noise():
    pl0, pr0, pl1, pr1, R, t, A, b = _observations(noise_px=0.5, seed=6)
    plain = robust_step(pl0, pr0, pl1, pr1, R, t, F_PX, RobustSettings(refine=False))
    refined = robust_step(pl0, pr0, pl1, pr1, R, t, F_PX, RobustSettings(refine=True))
    e_plain = np.linalg.norm(plain.t_bar - b)
    e_ref = np.linalg.norm(refined.t_bar - b)
    assert e_ref < e_plain
    assert e_ref < 0.01


def test_robust_returns_none_with_too_few_points():
    pl0, pr0, pl1, pr1, R, t, *_ = _observations(n=5)
    assert robust_step(pl0, pr0, pl1, pr1, R, t, F_PX) is None


def test_errors_and_drift():
    B_true = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [1, 0, 2.0]])
    B_est = B_true + np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.2, 0], [0, 0, 0.3]])
    np.testing.assert_allclose(step_errors(B_est, B_true), [0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(distance_travelled(B_true), [0, 1, 2, 3])
    s = summarize(B_est, B_true)
    assert s.n_steps == 3
    assert s.mean_m == pytest.approx(0.2)
    assert s.std_m == pytest.approx(np.std([0.1, 0.2, 0.3]))
    assert s.drift_pct == pytest.approx(10.0)
    assert s.max_drift_pct == pytest.approx(10.0)
