"""The soft-L1 Levenberg-Marquardt solver against scipy's least_squares on the same problem."""

import numpy as np
from scipy.optimize import least_squares

from station.wheel.robust_lsq import soft_l1_cost, soft_l1_least_squares


def _circle_problem(seed: int):
    """Points (N,2) on a circle of centre (3, -2), radius 5, noise 0.02, 15 % gross outliers;
    residuals and Jacobian of the distance to a circle p = (cx, cy, r)."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 2 * np.pi, 400)
    pts = np.stack([3 + 5 * np.cos(t), -2 + 5 * np.sin(t)], axis=1) + rng.normal(0, 0.02, (400, 2))
    bad = rng.random(400) < 0.15
    pts[bad] += rng.normal(0, 1.5, (bad.sum(), 2))

    def fj(p):
        d = pts - p[:2]
        rho = np.hypot(d[:, 0], d[:, 1])
        J = np.stack([-d[:, 0] / rho, -d[:, 1] / rho, -np.ones(len(rho))], axis=1)
        return rho - p[2], J

    return fj


def test_same_minimum_and_hessian_as_scipy():
    for seed in range(5):
        fj = _circle_problem(seed)
        x0 = np.array([2.0, -1.0, 4.0])
        ours = soft_l1_least_squares(fj, x0, f_scale=0.05)
        ref = least_squares(lambda p: fj(p)[0], x0, jac=lambda p: fj(p)[1], loss="soft_l1", f_scale=0.05,
                            x_scale="jac", method="trf", xtol=1e-12, ftol=1e-12)
        np.testing.assert_allclose(ours.x, ref.x, atol=1e-8)
        assert abs(ours.cost - ref.cost) <= 1e-9 * ref.cost
        np.testing.assert_allclose(ours.fun, ref.fun, atol=1e-8)
        # the scaled Jacobian scipy returns: J^T J is the robust cost's Gauss-Newton Hessian
        np.testing.assert_allclose(ours.jac.T @ ours.jac, ref.jac.T @ ref.jac, rtol=1e-6)
        # robust: the outliers do not pull the circle (a plain least-squares fit moves it)
        np.testing.assert_allclose(ours.x, [3.0, -2.0, 5.0], atol=0.01)


def test_cost_is_scipys():
    r = np.array([-2.0, -0.1, 0.0, 0.3, 7.0])
    ref = least_squares(lambda p: r + 0 * p, np.zeros(1), loss="soft_l1", f_scale=0.5, max_nfev=1)
    assert abs(soft_l1_cost(r, 0.5) - ref.cost) < 1e-12


def test_a_start_at_the_minimum_stays_there():
    fj = _circle_problem(7)
    first = soft_l1_least_squares(fj, np.array([2.0, -1.0, 4.0]), f_scale=0.05)
    again = soft_l1_least_squares(fj, first.x, f_scale=0.05)
    np.testing.assert_allclose(again.x, first.x, atol=1e-10)
    assert again.iterations <= 3
