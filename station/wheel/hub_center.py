"""Where each wheel's hub is, from its lip centres over a roll.

A rim's lip is seldom centred on its hub (radial runout: a few tenths of a mm). The car frame
rests on the four wheel centres (docs/conventions.md), and a lip centre off its hub by 0.3 mm
tilts the frame's up by about 0.01 deg over a track, straight into camber. Rolled, the lip
centre turns about the hub with the wheel: at a capture where the wheel has turned by theta_k
since the reference (the last capture) and the car has travelled s_k along its direction t,

    c_k - c_ref = s_k t + (Rot(a, theta_k) - I) e,

with a the wheel's spin axis and e (across a) the lip centre's offset from the hub at the
reference. The car is rigid: every hub travels the same s_k. :func:`hub_centers` solves for
the s_k and every wheel's e together by linear least squares; the hub is c_ref - e. The
offsets' along-track share moves the lip centres up and down as the wheel turns, their
vertical share along the track against the other wheels: both are seen to a few hundredths of
a mm over a roll of 25 deg each way. An offset common to all four wheels is weakly seen, and
tilts nothing.

Shapes: centres (W,K,3) m, turns (W,K) rad (right-handed about each wheel's axis, the
reference's 0), axes (W,3) unit, forward (3,) unit; W wheels, K captures, the last the reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.wheel.runout import rotate


@dataclass(frozen=True)
class HubCenters:
    """Each wheel's hub centre (W,3) at the reference capture, its lip centre's offset from it
    (W,3) and that offset's covariance (W,3,3) m^2; the car's travel at each other capture
    (K-1,) m along ``forward``."""

    center_station: np.ndarray
    offset_station: np.ndarray
    cov_offset: np.ndarray
    travel_m: np.ndarray


def hub_centers(centers: np.ndarray, turns_rad: np.ndarray, axes: np.ndarray, forward: np.ndarray) -> HubCenters:
    """The hubs of W wheels rolled together through K captures (the last the reference)."""
    centers = np.asarray(centers, float)
    W, K, _ = centers.shape
    t = np.asarray(forward, float) / np.linalg.norm(forward)
    a = np.asarray(axes, float) / np.linalg.norm(axes, axis=1, keepdims=True)          # (W,3)
    p = t - a * (a @ t)[:, None]
    p /= np.linalg.norm(p, axis=1, keepdims=True)                                       # (W,3) across a, along the travel
    q = np.cross(a, p)                                                                  # (W,3)
    n_travel = K - 1
    A = np.zeros((W, n_travel, 3, n_travel + 2 * W))
    for w in range(W):
        theta = np.asarray(turns_rad, float)[w, :n_travel]
        A[w, np.arange(n_travel), :, np.arange(n_travel)] = t
        A[w, :, :, n_travel + 2 * w] = rotate(a[w], theta, p[w]) - p[w]
        A[w, :, :, n_travel + 2 * w + 1] = rotate(a[w], theta, q[w]) - q[w]
    A = A.reshape(-1, n_travel + 2 * W)
    b = (centers[:, :n_travel] - centers[:, -1:]).reshape(-1)
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    residual = b - A @ x
    dof = max(len(b) - len(x), 1)
    cov_x = np.linalg.pinv(A.T @ A) * float(residual @ residual) / dof
    coef = x[n_travel:].reshape(W, 2)
    offset = coef[:, :1] * p + coef[:, 1:] * q                                          # (W,3)
    basis = np.stack([p, q], axis=2)                                                    # (W,3,2)
    cov_coef = np.array([cov_x[n_travel + 2 * w:n_travel + 2 * w + 2, n_travel + 2 * w:n_travel + 2 * w + 2]
                         for w in range(W)])
    cov_offset = basis @ cov_coef @ basis.transpose(0, 2, 1)
    return HubCenters(centers[:, -1] - offset, offset, cov_offset, x[:n_travel])
