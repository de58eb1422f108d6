"""A trajectory's errors against the ground truth: position (eq. 49) and drift, orientation,
and KITTI's error over segments of the path.

Poses are (N,4,4) camera-to-world transforms, world = the left camera at image 0 (both the
estimate and the truth). Only the images both have are compared (a method that stopped early
is compared up to where it stopped).

- **rotation error** of image i: the angle of ``R_true_i^T R_est_i`` (degrees). The paper's
  composed 3x3 block is not exactly a rotation (docs/odometry.md); its nearest rotation is used.
- **segments** (KITTI's odometry benchmark, ``evaluate_odometry.cpp``): for every start image
  and every segment length L, the end image is the first one more than L further along the true
  path; the error is the relative pose of the two images, estimated against true,
  ``E = (T_est_a^-1 T_est_b)^-1 (T_true_a^-1 T_true_b)``: translation ``|t_E| / L`` (%) and
  rotation ``angle(R_E) / L`` (deg/m), averaged over all segments. KITTI's lengths are 100,
  200 ... 800 m, from every 10th image; a path shorter than 100 m uses 10 %, 20 % ... 80 % of
  its length instead, from every image (``SegmentErrors.kitti_lengths`` says which).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.odometry.trajectory import ErrorSummary, distance_travelled, summarize

KITTI_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
KITTI_START_STEP = 10                 # KITTI's start images: every 10th (1 s at 10 Hz)
SHORT_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> the nearest rotations (SVD, no reflection)."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (...) their angles in degrees (accurate for small angles too)."""
    axis = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                     R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    cos = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.degrees(np.arctan2(0.5 * np.linalg.norm(axis, axis=-1), cos))


def rotation_errors_deg(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """(n,) the angle of ``R_true_i^T R_est_i`` per image, degrees (n: the images both have)."""
    n = min(len(T_est), len(T_true))
    R_est = nearest_rotation(np.asarray(T_est)[:n, :3, :3])
    R_true = np.asarray(T_true)[:n, :3, :3]
    return rotation_angle_deg(np.swapaxes(R_true, -1, -2) @ R_est)


@dataclass(frozen=True)
class SegmentErrors:
    """KITTI-style errors over segments: ``t_pct`` the mean translation error in % of the
    segment length, ``r_deg_per_m`` the mean rotation error per metre; NaN without segments."""

    lengths_m: tuple[float, ...]
    kitti_lengths: bool
    n_segments: int
    t_pct: float
    r_deg_per_m: float


def segment_errors(T_est: np.ndarray, T_true: np.ndarray) -> SegmentErrors:
    """KITTI's segment errors (module docstring) over the images both trajectories have."""
    n = min(len(T_est), len(T_true))
    T_est, T_true = np.asarray(T_est, float)[:n], np.asarray(T_true, float)[:n]
    dist = distance_travelled(T_true[:, :3, 3])
    kitti = dist[-1] >= KITTI_LENGTHS_M[0]
    lengths = np.array(KITTI_LENGTHS_M if kitti else [f * dist[-1] for f in SHORT_FRACTIONS])
    first = np.arange(0, n, KITTI_START_STEP if kitti else 1)
    last = np.searchsorted(dist, dist[first][:, None] + lengths[None, :], side="right")
    ok = (last < n) & (lengths[None, :] > 0)
    a = np.broadcast_to(first[:, None], last.shape)[ok]
    b, L = last[ok], np.broadcast_to(lengths[None, :], last.shape)[ok]
    if not len(L):
        return SegmentErrors(tuple(lengths.tolist()), bool(kitti), 0, float("nan"), float("nan"))
    d_true = np.linalg.solve(T_true[a], T_true[b])
    d_est = np.linalg.solve(T_est[a], T_est[b])
    E = np.linalg.solve(d_est, d_true)
    t_err = np.linalg.norm(E[:, :3, 3], axis=1) / L
    r_err = rotation_angle_deg(nearest_rotation(E[:, :3, :3])) / L
    return SegmentErrors(tuple(lengths.tolist()), bool(kitti), len(L),
                         float(100 * t_err.mean()), float(r_err.mean()))


@dataclass(frozen=True)
class TruthErrors:
    """Everything the command prints against the truth for one method."""

    translation: ErrorSummary          # eq. 49 mean/std/max/final, drift, over steps 1..n
    rot_mean_deg: float                # rotation error, mean over steps 1..n
    rot_final_deg: float               # rotation error at the last step
    segments: SegmentErrors


def compare(T_est: np.ndarray, T_true: np.ndarray) -> TruthErrors:
    """Errors of the estimated poses (n,4,4) against the true ones (m,4,4), over the images both
    have; NaN where there is no step."""
    T_est, T_true = np.asarray(T_est, float), np.asarray(T_true, float)
    translation = summarize(T_est[:, :3, 3], T_true[:, :3, 3])
    rot = rotation_errors_deg(T_est, T_true)[1:]
    return TruthErrors(translation,
                       float(rot.mean()) if len(rot) else float("nan"),
                       float(rot[-1]) if len(rot) else float("nan"),
                       segment_errors(T_est, T_true))
