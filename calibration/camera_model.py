"""Pinhole camera with OpenCV's lens distortion, vectorised over points.

The distortion vector is OpenCV's, of 5, 8 or 12 coefficients (docs/conventions.md, "Camera
model"): ``k1 k2 p1 p2 k3`` (what the station's own calibration estimates), + ``k4 k5 k6`` (the
rational model's denominator), + ``s1 s2 s3 s4`` (thin prism). OpenCV's 14 add the tilted sensor
``tauX tauY``, which this model does not have: such a camera is refused with that reason.

Frames and pixel conventions are in docs/conventions.md:
``x_cam = R_cam_station @ x_station + t_cam_station``; pixel origin at the centre of the
top-left pixel; normalised coordinates ``(X/Z, Y/Z)`` before distortion.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
DIST_LENGTHS = (5, 8, 12)  # k1 k2 p1 p2 k3 | + k4 k5 k6 (rational) | + s1 s2 s3 s4 (thin prism)
TILT_LENGTH = 14           # OpenCV's + tauX tauY (tilted sensor): not this model


def dist_length_problem(n: int) -> str | None:
    """Why a distortion vector of ``n`` coefficients is not one this model has (None if it is),
    to follow "dist has "."""
    if n in DIST_LENGTHS:
        return None
    if n == TILT_LENGTH:
        return ("14 coefficients: the last two are OpenCV's tilted-sensor terms tauX tauY (CALIB_TILTED_MODEL), "
                "which this camera model does not have; use a calibration with 5, 8 or 12 coefficients")
    return (f"{n} coefficients; this camera model takes 5 (k1 k2 p1 p2 k3), 8 (+ k4 k5 k6, the rational "
            "model) or 12 (+ s1 s2 s3 s4, thin prism), as OpenCV orders them")


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV's distortion to undistorted normalised points.

    xy: (N, 2) undistorted normalised coordinates. dist: (5,) k1 k2 p1 p2 k3, or (8,) / (12,)
    with the rational and thin-prism terms. Returns (N, 2) distorted normalised coordinates.
    """
    if len(dist) != 5:
        return _distort_rational(xy, dist)
    k1, k2, p1, p2, k3 = dist
    x = xy[:, 0]
    y = xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def _distortion_jacobian(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """d(distorted)/d(undistorted) for each point: (N, 2, 2)."""
    if len(dist) != 5:
        return _rational_jacobian(xy, dist)
    k1, k2, p1, p2, k3 = dist
    x = xy[:, 0]
    y = xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    J = np.empty((len(x), 2, 2))
    J[:, 0, 0] = radial + x * dradial_dr2 * 2 * x + 2 * p1 * y + p2 * 6 * x
    J[:, 0, 1] = x * dradial_dr2 * 2 * y + 2 * p1 * x + p2 * 2 * y
    J[:, 1, 0] = y * dradial_dr2 * 2 * x + p1 * 2 * x + 2 * p2 * y
    J[:, 1, 1] = radial + y * dradial_dr2 * 2 * y + p1 * 6 * y + 2 * p2 * x
    return J


# --- the rational and thin-prism terms (8 or 12 coefficients), as OpenCV's projectPoints ------
# radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
# xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2) + s1 r2 + s2 r2^2
# yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y + s3 r2 + s4 r2^2
# The 5-term functions above stay separate: they are the station's hot path, bit for bit as before.
def _rational_terms(dist: np.ndarray) -> tuple[float, ...]:
    """(k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4) of an (8,) or (12,) vector (thin prism 0 for 8)."""
    n = len(dist)
    if n not in (8, 12):
        raise ValueError(f"the distortion has {dist_length_problem(n) or f'{n} coefficients, not 8 or 12'}")
    return (*(float(v) for v in dist), *((0.0,) * (12 - n)))


def _distort_rational(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = _rational_terms(dist)
    x = xy[:, 0]
    y = xy[:, 1]
    r2 = x * x + y * y
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + r2 * (s1 + r2 * s2)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + r2 * (s3 + r2 * s4)
    return np.stack([xd, yd], axis=1)


def _rational_jacobian(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """:func:`_distortion_jacobian` of the 8- and 12-term model: (N, 2, 2)."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = _rational_terms(dist)
    x = xy[:, 0]
    y = xy[:, 1]
    r2 = x * x + y * y
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / den
    # d(num/den)/dr2 = (num' - radial den') / den
    dradial_dr2 = (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2) - radial * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2))) / den
    dprism_x = s1 + 2.0 * s2 * r2  # d(s1 r2 + s2 r2^2)/dr2
    dprism_y = s3 + 2.0 * s4 * r2
    J = np.empty((len(x), 2, 2))
    J[:, 0, 0] = radial + 2 * x * (x * dradial_dr2 + dprism_x) + 2 * p1 * y + 6 * p2 * x
    J[:, 0, 1] = 2 * y * (x * dradial_dr2 + dprism_x) + 2 * p1 * x + 2 * p2 * y
    J[:, 1, 0] = 2 * x * (y * dradial_dr2 + dprism_y) + 2 * p1 * x + 2 * p2 * y
    J[:, 1, 1] = radial + 2 * y * (y * dradial_dr2 + dprism_y) + 6 * p1 * y + 2 * p2 * x
    return J


def undistort_normalized(xy_d: np.ndarray, dist: np.ndarray, iterations: int = 30,
                         tol: float = 1e-15) -> np.ndarray:
    """Invert :func:`distort_normalized` exactly (Newton's method to machine precision).

    xy_d: (N, 2) distorted normalised coordinates; dist: (5,), (8,) or (12,) as
    :func:`distort_normalized`. Returns (N, 2) undistorted ones. Points where Newton does not
    converge (far outside a lens's valid field) come back NaN.
    """
    xy_d = np.asarray(xy_d, dtype=float)
    if not np.any(dist):
        return xy_d.copy()
    xy = xy_d.copy()
    for _ in range(iterations):
        residual = distort_normalized(xy, dist) - xy_d
        if np.max(np.abs(residual), initial=0.0) < tol:
            break
        # the 2x2 Newton step by its explicit inverse (a batched LAPACK solve of (N,2,2)
        # costs 3x more here, and undistortion runs on every edge point of every cycle)
        J = _distortion_jacobian(xy, dist)
        a, b, c, d = J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1]
        det = a * d - b * c
        rx, ry = residual[:, 0], residual[:, 1]
        xy = xy - np.stack([(d * rx - b * ry) / det, (a * ry - c * rx) / det], axis=1)
    residual = np.abs(distort_normalized(xy, dist) - xy_d).max(axis=1)
    xy[~(residual < 1e-9)] = np.nan
    return xy


def rodrigues_to_matrix(rvec: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) to matrix (3,3)."""
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec)
    if theta < 1e-15:
        return np.eye(3)
    k = rvec / theta
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * Kx + (1 - np.cos(theta)) * (Kx @ Kx)


def matrix_to_rodrigues(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3,3) to rotation vector (3,)."""
    cos_t = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos_t)
    if theta < 1e-12:
        return np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    if np.pi - theta < 1e-6:
        # Near 180 degrees: axis from the symmetric part.
        B = (R + np.eye(3)) / 2.0
        axis = np.sqrt(np.clip(np.diag(B), 0, None))
        i = int(np.argmax(axis))
        axis = B[:, i] / np.sqrt(B[i, i])
        return axis * theta
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return w * theta / (2.0 * np.sin(theta))


@dataclass(frozen=True)
class CameraModel:
    """One calibrated camera.

    K: (3,3) intrinsics, no skew. dist: (5,) k1 k2 p1 p2 k3, or OpenCV's (8,) / (12,) with
    k4 k5 k6 and s1 s2 s3 s4 (DIST_LENGTHS; 14, the tilted sensor, is refused).
    R_cam_station: (3,3), t_cam_station: (3,) metres, x_cam = R x_station + t.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R_cam_station: np.ndarray = field(default_factory=lambda: np.eye(3))
    t_cam_station: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        for name, shape in (("K", (3, 3)), ("dist", None), ("R_cam_station", (3, 3)),
                            ("t_cam_station", (3,))):
            arr = np.array(getattr(self, name), dtype=float)
            if shape is None:  # dist: one of DIST_LENGTHS
                problem = dist_length_problem(arr.size) if arr.ndim == 1 else f"shape {arr.shape}"
                if problem:
                    raise ValueError(f"camera {self.name}: dist has {problem}")
            elif arr.shape != shape:
                raise ValueError(f"camera {self.name}: {name} must have shape {shape}, got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"camera {self.name}: {name} contains NaN or infinity")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    # --- derived ---------------------------------------------------------------------------
    @property
    def center_station(self) -> np.ndarray:
        """Projection centre in the station frame, (3,) metres."""
        return -self.R_cam_station.T @ self.t_cam_station

    @property
    def optical_axis_station(self) -> np.ndarray:
        """Unit optical axis (camera +z) in the station frame, (3,)."""
        return self.R_cam_station[2].copy()

    def with_pose(self, R_cam_station: np.ndarray, t_cam_station: np.ndarray) -> "CameraModel":
        return replace(self, R_cam_station=R_cam_station, t_cam_station=t_cam_station)

    # --- projection ------------------------------------------------------------------------
    def station_to_cam(self, points_station: np.ndarray) -> np.ndarray:
        """(N,3) station -> (N,3) camera frame."""
        return np.asarray(points_station, float) @ self.R_cam_station.T + self.t_cam_station

    def apply_K(self, xy: np.ndarray) -> np.ndarray:
        """(N,2) coordinates on the z = 1 plane -> (N,2) pixels through K alone (no distortion:
        undistorted normalised coordinates give ideal pinhole pixels)."""
        K = self.K
        return np.stack([K[0, 0] * xy[:, 0] + K[0, 2], K[1, 1] * xy[:, 1] + K[1, 2]], axis=1)

    def unapply_K(self, uv: np.ndarray) -> np.ndarray:
        """(N,2) pixels -> (N,2) coordinates on the z = 1 plane through K alone (the inverse of apply_K)."""
        K = self.K
        return np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]], axis=1)

    def normalized_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(N,2) undistorted normalised -> (N,2) pixels (distortion applied)."""
        return self.apply_K(distort_normalized(np.asarray(xy, float), self.dist))

    def pixels_to_normalized(self, uv: np.ndarray) -> np.ndarray:
        """(N,2) pixels -> (N,2) undistorted normalised coordinates (exact inverse)."""
        return undistort_normalized(self.unapply_K(np.asarray(uv, float).reshape(-1, 2)), self.dist)

    def project_cam(self, points_cam: np.ndarray) -> np.ndarray:
        """(N,3) camera-frame points -> (N,2) pixels. Points behind the camera give NaN."""
        P = np.asarray(points_cam, float).reshape(-1, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(P[:, 2] > 0, P[:, 2], np.nan)
            xy = P[:, :2] / z[:, None]
        return self.normalized_to_pixels(xy)

    def project(self, points_station: np.ndarray) -> np.ndarray:
        """(N,3) station-frame points -> (N,2) pixels."""
        return self.project_cam(self.station_to_cam(points_station))

    def rays_cam(self, uv: np.ndarray) -> np.ndarray:
        """(N,2) pixels -> (N,3) unit ray directions in the camera frame."""
        xy = self.pixels_to_normalized(uv)
        d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def rays_station(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,2) pixels -> (origin (3,), unit directions (N,3)) in the station frame."""
        return self.center_station, self.rays_cam(uv) @ self.R_cam_station

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N,) bool: pixel inside the sensor (with a margin in px)."""
        uv = np.asarray(uv, float)
        return ((uv[:, 0] >= -0.5 + margin) & (uv[:, 0] <= self.width - 0.5 - margin)
                & (uv[:, 1] >= -0.5 + margin) & (uv[:, 1] <= self.height - 0.5 - margin))

    # --- OpenCV interop --------------------------------------------------------------------
    @property
    def rvec(self) -> np.ndarray:
        return matrix_to_rodrigues(self.R_cam_station)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "width": int(self.width),
            "height": int(self.height),
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "R_cam_station": self.R_cam_station.tolist(),
            "t_cam_station_m": self.t_cam_station.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "CameraModel":
        return cls(name=d["name"], width=int(d["width"]), height=int(d["height"]),
                   K=np.array(d["K"], float), dist=np.array(d["dist"], float),
                   R_cam_station=np.array(d["R_cam_station"], float),
                   t_cam_station=np.array(d["t_cam_station_m"], float))


def look_at(position_station: np.ndarray, target_station: np.ndarray,
            up_station: np.ndarray = np.array([0.0, 0.0, 1.0])) -> tuple[np.ndarray, np.ndarray]:
    """Pose of a camera at ``position`` looking at ``target`` with image-up near ``up``.

    Returns (R_cam_station (3,3), t_cam_station (3,)).
    """
    c = np.asarray(position_station, float)
    z = np.asarray(target_station, float) - c
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up_station, float))  # camera x = right
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: the viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # camera y = down
    R = np.stack([x, y, z])
    return R, -R @ c
