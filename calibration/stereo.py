"""A calibrated stereo pair (paper section 2.4-2.5): extrinsics eqs 34-35, E eq. 29, F eq. 33,
epipolar lines, and triangulation to the station frame with the paper's eq. 24.

Conventions (docs/conventions.md "Stereo pair"): the left camera is the precision camera,
``P_l = R^T P_r + t`` (eq. 25) with ``R = R_r R_l^T`` and ``t = t_l - R^T t_r``; ``t`` is the
right camera's centre in the left frame, so the baseline is ``|t|``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.camera_model import CameraModel
from calibration.triangulation import homogeneous, triangulate_paper


def skew(v: np.ndarray) -> np.ndarray:
    """(3,) -> (3,3) with ``skew(v) @ x = v x x``."""
    x, y, z = np.asarray(v, float)
    return np.array([[0, -z, y], [z, 0, -x], [-y, x, 0.0]])


def pair_extrinsics(R_l, t_l, R_r, t_r) -> tuple[np.ndarray, np.ndarray]:
    """Eqs 34-35: ``R = R_r R_l^T``, ``t = t_l - R^T t_r`` from the cameras' ``R_cam_station, t``."""
    R = np.asarray(R_r, float) @ np.asarray(R_l, float).T
    t = np.asarray(t_l, float) - R.T @ np.asarray(t_r, float)
    return R, t


def essential_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Eq. 29: ``E = R T̂`` with ``T̂ = [t]x``, so that ``p_r^T E p_l = 0`` (eq. 28)."""
    return np.asarray(R, float) @ skew(t)


def fundamental_matrix(E: np.ndarray, K_l: np.ndarray, K_r: np.ndarray) -> np.ndarray:
    """Eq. 33: ``F = K_r^-T E K_l^-1`` (f = 1 in eqs 30-31), normalised to ``|F| = 1``."""
    F = np.linalg.inv(K_r).T @ E @ np.linalg.inv(K_l)
    return F / np.linalg.norm(F)


def epipolar_lines(F: np.ndarray, uv_left: np.ndarray) -> np.ndarray:
    """(N,2) left pixels (distortion removed) -> (N,3) lines ``a u + b v + c = 0`` in the right
    image, scaled so ``a^2 + b^2 = 1`` (then ``line @ (u, v, 1)`` is a distance in px)."""
    lines = homogeneous(uv_left) @ F.T
    return lines / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)


def epipolar_distance(F: np.ndarray, uv_left: np.ndarray, uv_right: np.ndarray) -> np.ndarray:
    """(N,) signed distance (px) of each right pixel from its left point's epipolar line."""
    return np.einsum("ij,ij->i", epipolar_lines(F, uv_left), homogeneous(uv_right))


@dataclass(frozen=True)
class StereoPair:
    """Two calibrated cameras of one wheel. left = precision, right = reference camera."""

    wheel: str
    left: CameraModel
    right: CameraModel

    @property
    def R(self) -> np.ndarray:
        return pair_extrinsics(self.left.R_cam_station, self.left.t_cam_station,
                               self.right.R_cam_station, self.right.t_cam_station)[0]

    @property
    def t(self) -> np.ndarray:
        return pair_extrinsics(self.left.R_cam_station, self.left.t_cam_station,
                               self.right.R_cam_station, self.right.t_cam_station)[1]

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.t))

    @property
    def E(self) -> np.ndarray:
        return essential_matrix(self.R, self.t)

    @property
    def F(self) -> np.ndarray:
        """For undistorted pixels (``K p`` of the normalised points)."""
        return fundamental_matrix(self.E, self.left.K, self.right.K)

    def epipolar_distance_px(self, uv_left: np.ndarray, uv_right: np.ndarray) -> np.ndarray:
        """(N,) distance (px) of matched raw pixels from the epipolar lines (distortion removed)."""
        ul = self.left.pixels_to_normalized(uv_left) @ self.left.K[:2, :2].T + self.left.K[:2, 2]
        ur = self.right.pixels_to_normalized(uv_right) @ self.right.K[:2, :2].T + self.right.K[:2, 2]
        return epipolar_distance(self.F, ul, ur)

    def triangulate_station(self, uv_left: np.ndarray, uv_right: np.ndarray) -> np.ndarray:
        """(N,2) matched raw pixels in both images -> (N,3) station points (eq. 24)."""
        p_l = homogeneous(self.left.pixels_to_normalized(uv_left))
        p_r = homogeneous(self.right.pixels_to_normalized(uv_right))
        P_l = triangulate_paper(p_l, p_r, self.R, self.t)
        return (P_l - self.left.t_cam_station) @ self.left.R_cam_station
