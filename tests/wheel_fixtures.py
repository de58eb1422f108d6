"""Stereo pairs and exact rims for the 3-D wheel tests (tests/test_wheel_circle_fit*.py)."""

import numpy as np

from calibration.camera_model import CameraModel, look_at


def pair_cameras(wheel_x, wheel_y):
    s = np.sign(wheel_x)
    target = np.array([wheel_x, wheel_y, 0.33])
    cams = []
    for name, pos, dist in (("L", [wheel_x + s * 1.3, wheel_y, 0.33], [-0.2, 0.08, 1e-4, -2e-4, 0.0]),
                            ("R", [wheel_x + s * 1.3, wheel_y - np.sign(wheel_y) * 0.6, 0.33], [-0.12, 0.03, 0, 0, 0])):
        R, t = look_at(np.array(pos), target)
        K = np.array([[1800.0, 0, 640], [0, 1795.0, 512], [0, 0, 1]])
        cams.append(CameraModel(name, 1280, 1024, K, np.array(dist), R, t))
    return cams


def rim_points(vehicle, wheel, n=1200):
    c, Rw = vehicle.wheel_frame_station(wheel)
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    X = c + vehicle.wheel.rim_radius_m * (np.cos(phi)[:, None] * Rw[:, 0] + np.sin(phi)[:, None] * Rw[:, 1])
    return c, Rw[:, 2], X


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))
