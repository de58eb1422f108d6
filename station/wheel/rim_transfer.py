"""A rim found in one camera of a pair, carried over to the other as a prior for its search.

When one camera of a pair ended on another contour (a ring inside the barrel, a dark flange's
shaded inner edge) and none of its runner-up candidates is the rim, the other camera's rim and
the rim's size (its axle partner's, :mod:`station.wheel.rim_size`) fix where the rim must appear in
this camera: the rays of the first camera's rim ellipse form a cone from its centre, and a
plane of the wheel's orientation cuts that cone in a circle whose size grows with the plane's
distance from the camera. The plane at which the circle has the partner's radius holds the
rim; projected into the other camera, that circle is the prior its rim search refines from.
The wheel's orientation comes from the pair's circle as measured: a concentric contour gives
the right axis even where its centre and size are wrong.
"""
from __future__ import annotations

import numpy as np

from calibration.camera_model import CameraModel
from station.rim import Ellipse
from station.rim.ellipse_fit import fit_direct

PRIOR_POINTS = 180  # points round the carried circle


def carried_rim(ellipse_ideal: Ellipse, cam_from: CameraModel, axis_station: np.ndarray,
                radius_m: float) -> np.ndarray | None:
    """(PRIOR_POINTS,3) station points of the circle of ``radius_m`` in a plane of normal
    ``axis_station`` (3,) cut from the cone of ``ellipse_ideal`` (the rim in ``cam_from``'s
    ideal pixels); None where the plane does not cut the cone in front of the camera."""
    n = np.asarray(axis_station, float)
    if not (np.all(np.isfinite(n)) and np.linalg.norm(n) > 0 and radius_m > 0):
        return None
    n = n / np.linalg.norm(n)
    xy = cam_from.unapply_K(ellipse_ideal.points(PRIOR_POINTS))  # ideal pixels -> normalised
    d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ cam_from.R_cam_station   # (N,3) rays, station
    o = cam_from.center_station
    nd = d @ n
    if not (np.all(nd > 0) or np.all(nd < 0)):
        return None
    X = o + d / np.abs(nd)[:, None]             # the cut by a plane 1 m from the camera along n
    # in-plane circle fit (Kasa): its radius scales with the plane's distance from the camera
    e1 = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    u, v = (X - o) @ e1, (X - o) @ e2
    A = np.stack([u, v, np.ones_like(u)], axis=1)
    (a, b, c), *_ = np.linalg.lstsq(A, u * u + v * v, rcond=None)
    rho2 = c + 0.25 * (a * a + b * b)
    if not rho2 > 0:
        return None
    return o + (X - o) * (radius_m / np.sqrt(rho2))


def carried_prior(ellipse_ideal: Ellipse, cam_from: CameraModel, cam_to: CameraModel, axis_station: np.ndarray,
                  radius_m: float) -> Ellipse | None:
    """The rim's ellipse expected in ``cam_to`` (ideal pixels, the frame of a detection's
    candidates) from the rim ``ellipse_ideal`` found in ``cam_from``, the wheel's axis and the
    rim's radius (m); None when it cannot be carried (the plane behind a camera)."""
    X = carried_rim(ellipse_ideal, cam_from, axis_station, radius_m)
    if X is None:
        return None
    P = cam_to.station_to_cam(X)
    if not np.all(P[:, 2] > 0):
        return None
    try:
        prior = fit_direct(cam_to.apply_K(P[:, :2] / P[:, 2:]))
    except (ValueError, np.linalg.LinAlgError):
        return None
    # a prior the search can start from: finite and no larger than a few images
    size = max(cam_to.width, cam_to.height)
    if not (np.all(np.isfinite(prior.center_px)) and np.all(np.isfinite(prior.axes_px))
            and 0 < max(prior.axes_px) < 4 * size):
        return None
    return prior
