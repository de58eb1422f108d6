"""The calibration's share of a wheel's uncertainty (docs/measurement.md).

The pair's joint (30,30) camera-parameter covariance from the calibration's bundle adjustment
(stored per pair in the calibration file) is mapped to small perturbations of the two cameras
(:func:`pair_perturbation_covariance`) and propagated to the 3-D circle of
``station.wheel.circle_fit.refine_circle`` by the implicit-function theorem (:func:`calibration_covariance`).
"""

from __future__ import annotations

import numpy as np

from calibration.camera_model import CameraModel
from station.errors import MeasurementError
from station.wheel.conics import circle_conic, sampson_px
from station.wheel.fit import WheelFit
from station.wheel.uncertainty import normal_from

CAMERA_PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "rx", "ry", "rz", "tx", "ty", "tz")


def perturb_camera(cam: CameraModel, delta: np.ndarray) -> CameraModel:
    """A camera with its 15 parameters (CAMERA_PARAMS order) moved by ``delta`` (15,); any
    distortion terms beyond k1 k2 p1 p2 k3 (an OpenCV import's) stay as they are.

    The rotation moves by the small rotation vector delta[9:12] applied in the camera frame
    (R' = exp([d]x) R), the translation by delta[12:15] (m).
    """
    from calibration.camera_model import rodrigues_to_matrix

    K = cam.K.copy()
    K[0, 0] += delta[0]
    K[1, 1] += delta[1]
    K[0, 2] += delta[2]
    K[1, 2] += delta[3]
    dist = cam.dist.copy()
    dist[:5] += delta[4:9]  # the bundle adjustment's five; an imported camera's k4.. s4 are held
    return CameraModel(cam.name, cam.width, cam.height, K, dist,
                       rodrigues_to_matrix(delta[9:12]) @ cam.R_cam_station, cam.t_cam_station + delta[12:15])


def bundle_to_perturbation(cam: CameraModel) -> np.ndarray:
    """(15,15) Jacobian from the bundle adjustment's camera parameters (calibration/refine.py:
    9 intrinsics, rotation vector of R_cam_station, camera centre C in the station frame) to
    :func:`perturb_camera`'s (9 intrinsics, small rotation applied in the camera frame,
    translation t_cam_station), at ``cam``: t = -R C, so dt = d x t - R dC."""
    from calibration.camera_model import matrix_to_rodrigues, rodrigues_to_matrix

    R, t = cam.R_cam_station, cam.t_cam_station
    rvec = matrix_to_rodrigues(R)
    D = np.zeros((3, 3))
    h = 1e-7
    for k in range(3):  # d(rotation in the camera frame) / d(rvec), numerically
        dR = rodrigues_to_matrix(rvec + h * np.eye(3)[k]) @ R.T
        D[:, k] = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / (2 * h)
    J = np.zeros((15, 15))
    J[:9, :9] = np.eye(9)
    J[9:12, 9:12] = D
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    J[12:15, 9:12] = -tx @ D
    J[12:15, 12:15] = -R
    return J


def pair_perturbation_covariance(cam_l: CameraModel, cam_r: CameraModel, cov_bundle: np.ndarray) -> np.ndarray:
    """(30,30) covariance of both cameras' :func:`perturb_camera` parameters from the pair's
    bundle-adjustment covariance (30,30) (StationCalibration.pair_covariance)."""
    J = np.zeros((30, 30))
    J[:15, :15] = bundle_to_perturbation(cam_l)
    J[15:, 15:] = bundle_to_perturbation(cam_r)
    return J @ cov_bundle @ J.T


def calibration_covariance(points_l_px: np.ndarray, points_r_px: np.ndarray, cam_l: CameraModel,
                           cam_r: CameraModel, fit: WheelFit, cov_params_l: np.ndarray | None = None,
                           cov_params_r: np.ndarray | None = None, cov_pair: np.ndarray | None = None,
                           max_points: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """How the calibration's uncertainty moves a fitted circle: (cov_center (3,3), cov_axis (3,3)).

    First order, by the implicit-function theorem at the solution x* of the circle fit:
    dx/dp = -(J_x^T J_x)^-1 J_x^T J_p, with J_p the residuals' derivative with respect to the
    30 camera parameters (numerical). The parameters' covariance is either each camera's
    (15,15) ``cov_params_*`` (independent cameras) or the pair's joint (30,30) ``cov_pair``
    (both in :func:`perturb_camera`'s parameters). Sensitivities need not every edge point:
    each view is thinned to ``max_points`` evenly spread ones. Raises MeasurementError when the
    points do not determine the circle (J_x^T J_x singular: a candidate pair that is no rim).
    """
    views_pts = tuple(p[:: max(1, len(p) // max_points)] for p in (points_l_px, points_r_px))
    n = fit.axis_station
    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)

    xy0 = [cam.pixels_to_normalized(pts) for cam, pts in zip((cam_l, cam_r), views_pts)]

    def residuals(x, cams, xys=xy0):
        c = x[2:5]
        nn = normal_from(x[:2], n, e1, e2)
        out = []
        for cam, xy in zip(cams, xys):
            C = circle_conic(cam.R_cam_station @ c + cam.t_cam_station, cam.R_cam_station @ nn, x[5])
            out.append(sampson_px(C, xy, 0.5 * (cam.K[0, 0] + cam.K[1, 1])))
        return np.concatenate(out)

    x0 = np.concatenate([[0.0, 0.0], fit.center_station, [fit.radius_m]])
    cams = (cam_l, cam_r)
    r0 = residuals(x0, cams)
    steps_x = np.array([1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6])
    Jx = np.stack([(residuals(x0 + np.eye(6)[k] * steps_x[k], cams) - r0) / steps_x[k] for k in range(6)], axis=1)
    steps_p = np.array([0.05, 0.05, 0.05, 0.05, 1e-5, 1e-5, 1e-6, 1e-6, 1e-5, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6])
    if cov_pair is not None:
        cov_p = np.asarray(cov_pair, float)
    else:
        cov_p = np.zeros((30, 30))
        cov_p[:15, :15] = cov_params_l
        cov_p[15:, 15:] = cov_params_r
    cols = []
    for which in range(2):
        for k in range(15):
            delta = np.zeros(15)
            delta[k] = steps_p[k]
            moved = list(cams)
            moved[which] = perturb_camera(cams[which], delta)
            xys = list(xy0)
            if k < 9:  # an intrinsic moves the normalised points; a pose does not
                xys[which] = moved[which].pixels_to_normalized(views_pts[which])
            cols.append((residuals(x0, moved, xys) - r0) / steps_p[k])
    Jp = np.stack(cols, axis=1)
    JtJ = Jx.T @ Jx
    if not np.isfinite(JtJ).all() or np.linalg.cond(JtJ) > 1e14:
        raise MeasurementError("the two views' rim points do not determine one circle (they fit a degenerate one)",
                               hint="check that both cameras of the pair see the same rim")
    dx_dp = -np.linalg.solve(JtJ, Jx.T @ Jp)
    cov_x = dx_dp @ cov_p @ dx_dp.T
    B = np.stack([e1, e2], axis=1)
    return cov_x[2:5, 2:5], B @ cov_x[:2, :2] @ B.T
