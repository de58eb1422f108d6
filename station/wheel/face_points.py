"""3-D points of a wheel's face and tyre, seen by its stereo pair at one capture, and their
motion between captures (runout compensation, station/wheel/face_motion.py).

The face (spokes, windows, the hub, its bolts) and the tyre's lettering turn with the wheel as
one rigid body. Corners of the image inside ``FACE_REACH`` lip radii are matched between the
pair's two cameras along the epipolar geometry and within the wheel's volume (``stereo_points``)
and triangulated, each with its covariance from the pixel noise. Between two captures the
points are matched by their descriptors where the turn the face pattern measured puts them
(``matched``), and a rigid motion is fitted by consensus (``rigid_ransac``): the brake caliper,
the body and corners that are not one physical point (a spoke's edge over the disc behind it)
do not follow it.

Descriptors are computed in the wheel's own turning frame: each corner's orientation is the
direction, in that image, of the wheel's reference spoke direction at that capture, so a
corner keeps its descriptor while the wheel turns.

Shapes: uv (N,2) distorted pixels; X (N,3) station metres; cov (N,3,3) m^2; descriptors (N,128).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.rigid_motion import kabsch
from station.wheel.rim_pattern import FacePose, ring_basis

FACE_REACH = 1.6                # corners within this many lip radii of the wheel's centre (face and lettering)
FACE_DEPTH_M = (-0.25, 0.12)    # and this far along the outward axis from the lip plane
MAX_CORNERS = 600               # per image (the cost of the stereo matching grows with its square)
CORNER_QUALITY = 0.003          # Shi-Tomasi: of the strongest corner's response
CORNER_SPACING_PX = 4.0
DESCRIPTOR_SIZE_PX = 16.0
PIXEL_NOISE_PX = 0.1            # a refined corner's position noise, for the points' covariance
STEREO_GAP_PX = 1.5             # the two rays of a match pass within this (reprojected, px)
REPROJECTION_PX = 1.0           # a triangulated point reprojects within this in both views
RATIO = 0.85                    # a match's descriptor distance under this share of the runner-up's
GATE_M = 0.005                  # a point of one capture is looked for this near its predicted place in another
MAX_DESCRIPTOR_DISTANCE = 700.0  # summed over both cameras' SIFT descriptors (0..~1000 each)


@dataclass(frozen=True)
class FacePoints:
    """A wheel's face at one capture: 3-D points (N,3) and covariances (N,3,3); their pixels in
    the pair's first and second camera (N,2) each and descriptors (N,128) each."""

    X_station: np.ndarray
    cov: np.ndarray
    uv_a: np.ndarray
    uv_b: np.ndarray
    desc_a: np.ndarray
    desc_b: np.ndarray

    def __len__(self) -> int:
        return len(self.X_station)


def face_mask(camera: CameraModel, pose: FacePose, reach: float = FACE_REACH) -> np.ndarray:
    """(H,W) uint8: 255 inside the projection of the disc of ``reach`` lip radii in the lip plane."""
    e1, e2 = ring_basis(pose.axis_station)
    t = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    rim = pose.center_station + reach * pose.radius_m * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    cv2.fillPoly(mask, [np.round(camera.project(rim)).astype(np.int32)], 255)
    return mask


def _stretched(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H,W) uint8: the grey levels under the mask stretched from their 0.5th to 99.8th percentile."""
    grey = np.asarray(image, np.float32)
    lo, hi = np.percentile(grey[mask > 0], [0.5, 99.8])
    return np.clip((grey - lo) * (255.0 / max(hi - lo, 1e-6)), 0, 255).astype(np.uint8)


def spoke_angle_deg(camera: CameraModel, pose: FacePose, turn_rad: float) -> float:
    """The image direction (deg, clockwise from +u, OpenCV's keypoint convention) of the wheel's
    reference direction turned by ``turn_rad`` about its outward axis."""
    e1, e2 = ring_basis(pose.axis_station)
    d = np.cos(turn_rad) * e1 + np.sin(turn_rad) * e2
    a, b = camera.project(np.stack([pose.center_station, pose.center_station + 0.1 * pose.radius_m * d]))
    return float(np.degrees(np.arctan2(b[1] - a[1], b[0] - a[0])) % 360.0)


def corners(image: np.ndarray, mask: np.ndarray, angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel Shi-Tomasi corners under ``mask`` ((N,2) px) and their SIFT descriptors
    ((N,128) float32) at orientation ``angle_deg``."""
    grey = _stretched(image, mask)
    found = cv2.goodFeaturesToTrack(grey, maxCorners=MAX_CORNERS, qualityLevel=CORNER_QUALITY,
                                    minDistance=CORNER_SPACING_PX, mask=mask, blockSize=5)
    if found is None:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    found = cv2.cornerSubPix(grey.astype(np.float32), found.astype(np.float32), (4, 4), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3))
    keys = [cv2.KeyPoint(float(x), float(y), DESCRIPTOR_SIZE_PX, angle_deg) for x, y in found.reshape(-1, 2)]
    keys, desc = cv2.SIFT_create().compute(grey, keys)
    if desc is None:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    return np.array([k.pt for k in keys], float).reshape(-1, 2), desc


def triangulated(cam_a: CameraModel, cam_b: CameraModel, uv_a: np.ndarray, uv_b: np.ndarray,
                 cov_a: np.ndarray | None = None, cov_b: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (N,3) from matched pixels (N,2) of two cameras (linear triangulation of the
    undistorted rays), their covariances (N,3,3) from each pixel's (N,2,2) covariance ``cov_a``,
    ``cov_b`` px^2 (``PIXEL_NOISE_PX`` on each coordinate unless given; numerical Jacobian) and
    the larger of the two reprojection errors (N,) px."""
    P_a = np.hstack([cam_a.R_cam_station, cam_a.t_cam_station[:, None]])
    P_b = np.hstack([cam_b.R_cam_station, cam_b.t_cam_station[:, None]])

    def points(ua, ub):
        xa, xb = cam_a.pixels_to_normalized(ua), cam_b.pixels_to_normalized(ub)
        X = cv2.triangulatePoints(P_a, P_b, xa.T.astype(float), xb.T.astype(float))
        return (X[:3] / X[3]).T

    X = points(uv_a, uv_b)
    h = 0.05
    J = np.stack([(points(uv_a + h * (q == 0) * np.array([1, 0]) + h * (q == 1) * np.array([0, 1]),
                          uv_b + h * (q == 2) * np.array([1, 0]) + h * (q == 3) * np.array([0, 1])) - X) / h
                  for q in range(4)], axis=2)                                       # (N,3,4)
    isotropic = PIXEL_NOISE_PX ** 2 * np.eye(2)
    cov_a = isotropic if cov_a is None else cov_a
    cov_b = isotropic if cov_b is None else cov_b
    cov = J[..., :2] @ cov_a @ J[..., :2].transpose(0, 2, 1) + J[..., 2:] @ cov_b @ J[..., 2:].transpose(0, 2, 1)
    err = np.maximum(np.linalg.norm(cam_a.project(X) - uv_a, axis=1), np.linalg.norm(cam_b.project(X) - uv_b, axis=1))
    return X, cov, err


def _mutual_best(D: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j) of a distance matrix (N,M) (inf: not a candidate) whose best is clear
    (under ``ratio`` of the runner-up) both ways."""
    if D.size == 0 or min(D.shape) < 1:
        return np.zeros(0, int), np.zeros(0, int)

    def best(D):
        order = np.argsort(D, axis=1)[:, :2]
        d = np.take_along_axis(D, order, 1)
        second = d[:, 1] if d.shape[1] > 1 else np.full(len(d), np.inf)
        clear = np.isfinite(d[:, 0]) & (~np.isfinite(second) | (d[:, 0] < ratio * second))
        return np.where(clear, order[:, 0], -1)

    forward, backward = best(D), best(D.T)
    i = np.nonzero(forward >= 0)[0]
    j = forward[i]
    keep = backward[j] == i
    return i[keep], j[keep]


def _descriptor_distances(d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """(N,M) Euclidean distances between descriptor rows."""
    sq = (d1.astype(float) ** 2).sum(1)[:, None] + (d2.astype(float) ** 2).sum(1)[None, :] - 2.0 * d1 @ d2.T
    return np.sqrt(np.maximum(sq, 0.0))


def stereo_points(images: tuple[np.ndarray, np.ndarray], cameras: tuple[CameraModel, CameraModel], pose: FacePose,
                  turn_rad: float) -> FacePoints:
    """The face's 3-D points at one capture: corners of both cameras' ``images`` inside the
    wheel (``pose``: its lip circle), matched along the epipolar geometry (rays within
    ``STEREO_GAP_PX``, the point in the wheel's volume) by mutually clear descriptors."""
    cam_a, cam_b = cameras
    uv, desc = [], []
    for image, cam in zip(images, cameras):
        u, d = corners(image, face_mask(cam, pose), spoke_angle_deg(cam, pose, turn_rad))
        uv.append(u)
        desc.append(d)
    if min(len(uv[0]), len(uv[1])) < 3:
        return _no_points()
    o_a, r_a = cam_a.rays_station(uv[0])
    o_b, r_b = cam_b.rays_station(uv[1])
    # closest points of every pair of rays (N,M)
    w0 = o_a - o_b
    b = r_a @ r_b.T
    d, e = (r_a @ w0)[:, None], (r_b @ w0)[None, :]
    den = np.maximum(1 - b ** 2, 1e-12)
    s, t = (b * e - d) / den, (e - b * d) / den
    P_a = o_a + s[..., None] * r_a[:, None, :]
    P_b = o_b + t[..., None] * r_b[None, :, :]
    gap_px = np.linalg.norm(P_a - P_b, axis=2) / np.maximum(s, 1e-6) * cam_a.K[0, 0]
    rel = 0.5 * (P_a + P_b) - pose.center_station
    along = rel @ pose.axis_station
    across = np.linalg.norm(rel - along[..., None] * pose.axis_station, axis=2)
    ok = ((gap_px < STEREO_GAP_PX) & (s > 0) & (t > 0) & (across < FACE_REACH * pose.radius_m)
          & (along > FACE_DEPTH_M[0]) & (along < FACE_DEPTH_M[1]))
    i, j = _mutual_best(np.where(ok, _descriptor_distances(desc[0], desc[1]), np.inf), RATIO)
    X, cov, err = triangulated(cam_a, cam_b, uv[0][i], uv[1][j])
    keep = err < REPROJECTION_PX
    return FacePoints(X[keep], cov[keep], uv[0][i][keep], uv[1][j][keep], desc[0][i][keep], desc[1][j][keep])


def _no_points() -> FacePoints:
    return FacePoints(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 2)), np.zeros((0, 2)),
                      np.zeros((0, 128), np.float32), np.zeros((0, 128), np.float32))


def matched(before: FacePoints, after: FacePoints, predicted: np.ndarray, gate_m: float = GATE_M,
            ratio: float = RATIO) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j): point i of ``before``, moved to ``predicted`` (N,3), is point j of
    ``after``: within ``gate_m`` of it, with a clear descriptor match (both cameras' summed)."""
    if not len(before) or not len(after):
        return np.zeros(0, int), np.zeros(0, int)
    near = np.linalg.norm(predicted[:, None, :] - after.X_station[None, :, :], axis=2) < gate_m
    D = _descriptor_distances(before.desc_a, after.desc_a) + _descriptor_distances(before.desc_b, after.desc_b)
    return _mutual_best(np.where(near & (D < MAX_DESCRIPTOR_DISTANCE), D, np.inf), ratio)


def rigid_ransac(A: np.ndarray, B: np.ndarray, threshold_m: float, iterations: int = 400,
                 seed: int = 0) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """The rigid motion (R, t) taking most of points A (N,3) to B (N,3) within ``threshold_m``
    (consensus of 3-point samples, then least squares on the consensus, refined twice), and
    its inliers (N,) bool; (None, None, no inliers) under 3 points."""
    n = len(A)
    best = np.zeros(n, bool)
    if n < 3:
        return None, None, best
    rng = np.random.default_rng(seed)
    samples = np.array([rng.choice(n, 3, replace=False) for _ in range(iterations)])     # (I,3)
    for s in samples:
        if np.linalg.norm(np.cross(A[s[1]] - A[s[0]], A[s[2]] - A[s[0]])) < 1e-4:
            continue
        R, t = kabsch(B[s], A[s])
        inliers = np.linalg.norm(A @ R.T + t - B, axis=1) < threshold_m
        if inliers.sum() > best.sum():
            best = inliers
    if best.sum() < 3:
        return None, None, best
    for _ in range(2):
        R, t = kabsch(B[best], A[best])
        best = np.linalg.norm(A @ R.T + t - B, axis=1) < threshold_m
        if best.sum() < 3:
            return None, None, best
    R, t = kabsch(B[best], A[best])
    return R, t, best
