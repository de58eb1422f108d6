"""Robust (soft-L1) least squares by Levenberg-Marquardt, for the small fits of every cycle.

The 3-D circle fit (station/wheel/circle_fit.py) minimises, over P = 6 parameters and N ~ 2000 rim
points, the soft-L1 cost

    F(x) = 1/2 sum_i C^2 rho(z_i),   rho(z) = 2 (sqrt(1 + z) - 1),   z_i = (r_i(x) / C)^2,

which ``scipy.optimize.least_squares(loss="soft_l1", f_scale=C)`` solves by its trust-region
method. Here the same cost is minimised the way that method linearises it (Triggs' correction:
the residuals and the Jacobian scaled so that ``J_s^T J_s`` is the Gauss-Newton Hessian of F
and ``J_s^T f_s`` its gradient), with Levenberg-Marquardt steps instead of trust-region SVDs and
ONE call of the model per iteration, which returns residuals and Jacobian together. Both
methods stop where the gradient ``J^T rho'(z) r`` vanishes: the same minimum. On the circle
fit scipy's bookkeeping took more time than the model (docs/speed.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

EPS = np.finfo(float).eps
DAMPING_START, DAMPING_DOWN, DAMPING_UP = 1e-2, 0.1, 10.0  # Marquardt's, relative to diag(J^T J)


@dataclass
class RobustSolution:
    """x: (P,) the solution; fun: (N,) residuals there; jac: (N,P) the Jacobian there, scaled
    for the loss as scipy's ``least_squares`` returns it (``jac.T @ jac`` is the Gauss-Newton
    Hessian of the robust cost); cost: F(x); iterations: model evaluations made."""

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    cost: float
    iterations: int


def soft_l1_cost(r: np.ndarray, f_scale: float) -> float:
    """F for residuals r (N,): 1/2 sum C^2 rho((r/C)^2)."""
    z = (r / f_scale) ** 2
    return float(f_scale * f_scale * np.sum(np.sqrt(1.0 + z) - 1.0))


def _scaled(r: np.ndarray, J: np.ndarray, f_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(f_s (N,), J_s (N,P)): rho'(z) = (1+z)^-1/2, and the Jacobian's scale
    sqrt(rho' + 2 rho'' r^2) = (1+z)^-3/4 (rho'' = -(1+z)^-3/2 / (2 C^2))."""
    z = (r / f_scale) ** 2
    scale = np.maximum((1.0 + z) ** -1.5, EPS) ** 0.5
    return r * (1.0 + z) ** -0.5 / scale, J * scale[:, None]


def soft_l1_least_squares(residuals_and_jacobian: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                          x0: np.ndarray, f_scale: float, max_evaluations: int = 60,
                          xtol: float = 1e-10, ftol: float = 1e-10) -> RobustSolution:
    """Minimise the soft-L1 cost of ``residuals_and_jacobian(x) -> (r (N,), J (N,P))`` from x0 (P,).

    Stops when a step changes the cost by less than ``ftol`` of it (either way: a rise of that
    size is round-off at the minimum) or an accepted step moves x by less than ``xtol``
    (relative), or after ``max_evaluations`` model calls (a step that raises the cost more is
    retried with ten times the damping)."""
    x = np.asarray(x0, float).copy()
    r, J = residuals_and_jacobian(x)
    cost = soft_l1_cost(r, f_scale)
    lam = DAMPING_START
    evaluations = 1
    while evaluations < max_evaluations:
        fs, Js = _scaled(r, J, f_scale)
        A = Js.T @ Js
        g = Js.T @ fs
        diag = np.maximum(np.diag(A), 1e-12 * max(float(np.max(np.diag(A))), 1e-300))
        try:
            dx = -np.linalg.solve(A + lam * np.diag(diag), g)
        except np.linalg.LinAlgError:
            lam *= DAMPING_UP
            evaluations += 1
            continue
        if not np.all(np.isfinite(dx)):
            break
        x_new = x + dx
        r_new, J_new = residuals_and_jacobian(x_new)
        evaluations += 1
        cost_new = soft_l1_cost(r_new, f_scale) if np.all(np.isfinite(r_new)) else np.inf
        if cost_new <= cost:
            small_step = np.linalg.norm(dx) <= xtol * (xtol + np.linalg.norm(x))
            small_gain = cost - cost_new <= ftol * cost
            x, r, J, cost = x_new, r_new, J_new, cost_new
            lam = max(lam * DAMPING_DOWN, 1e-12)
            if small_step or small_gain:
                break
        else:  # rejected: at the minimum already when the cost moved by round-off only
            if cost_new - cost <= ftol * cost:
                break
            lam *= DAMPING_UP
            if lam > 1e12:
                break
    fs, Js = _scaled(r, J, f_scale)
    return RobustSolution(x=x, fun=r, jac=Js, cost=cost, iterations=evaluations)
