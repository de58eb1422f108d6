"""SIFT keypoints common to the four images of two consecutive stereo steps (paper Fig. 12).

Per stereo frame: SIFT in both images, left-right matches by Lowe's ratio test (mutual best),
optionally checked against the calibrated epipolar geometry and for positive depth. Between
steps: the left descriptors are matched (ratio test, mutual), and optionally the circle of
Fig. 12 is closed by requiring the right descriptors to match the same pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.triangulation import (essential_matrix, homogeneous, paper_from_opencv,
                                       triangulate_paper_full)


@dataclass(frozen=True)
class MatchSettings:
    """ratio: Lowe's ratio test. epipolar_px: max distance (px) of a right keypoint from the
    epipolar line of its left match (None: no check, as in the paper). circular: require the
    right images to agree with the left ones between steps. max_features: SIFT cap per image."""

    ratio: float = 0.8
    epipolar_px: float | None = 1.5
    circular: bool = True
    max_features: int = 4000


PAPER_MATCHING = MatchSettings(epipolar_px=None, circular=False)


@dataclass
class StereoFrame:
    """Stereo-matched keypoints of one step. uv_l, uv_r: (M,2) px; p_l, p_r: (M,3) normalised
    homogeneous; desc_l, desc_r: (M,128) float32; n_left/n_right: SIFT keypoints found."""

    uv_l: np.ndarray
    uv_r: np.ndarray
    p_l: np.ndarray
    p_r: np.ndarray
    desc_l: np.ndarray
    desc_r: np.ndarray
    n_left: int
    n_right: int


def detect(image: np.ndarray, max_features: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints of a grey image: positions (N,2) px and descriptors (N,128) float32."""
    sift = cv2.SIFT_create(nfeatures=max_features)
    kps, desc = sift.detectAndCompute(image, None)
    if desc is None:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    return np.array([k.pt for k in kps], float).reshape(-1, 2), desc


def ratio_matches(d1: np.ndarray, d2: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Mutual best matches passing Lowe's ratio test both ways. Returns index arrays (K,), (K,)."""
    if len(d1) < 2 or len(d2) < 2:
        return np.zeros(0, int), np.zeros(0, int)
    bf = cv2.BFMatcher(cv2.NORM_L2)

    def one_way(a, b):
        best = np.full(len(a), -1)
        for m in bf.knnMatch(a, b, k=2):
            if len(m) == 2 and m[0].distance < ratio * m[1].distance:
                best[m[0].queryIdx] = m[0].trainIdx
        return best

    fwd = one_way(d1, d2)
    bwd = one_way(d2, d1)
    i = np.flatnonzero(fwd >= 0)
    j = fwd[i]
    keep = bwd[j] == i
    return i[keep], j[keep]


def epipolar_distance_px(p_l: np.ndarray, p_r: np.ndarray, E: np.ndarray, f_px: float) -> np.ndarray:
    """(N,) distance (px) of each right point from the epipolar line of its left point."""
    lines = p_l @ E.T                                   # E p_l, (N,3)
    num = np.abs(np.einsum("ij,ij->i", lines, p_r))
    return f_px * num / np.maximum(np.linalg.norm(lines[:, :2], axis=1), 1e-15)


def stereo_frame(left_img: np.ndarray, right_img: np.ndarray, left: CameraModel,
                 right: CameraModel, settings: MatchSettings = MatchSettings()) -> StereoFrame:
    """Detect and stereo-match one frame. ``right`` is posed in the left camera frame."""
    return stereo_match(detect(left_img, settings.max_features),
                        detect(right_img, settings.max_features), left, right, settings)


def stereo_match(det_l: tuple[np.ndarray, np.ndarray], det_r: tuple[np.ndarray, np.ndarray],
                 left: CameraModel, right: CameraModel,
                 settings: MatchSettings = MatchSettings(),
                 pairs: tuple[np.ndarray, np.ndarray] | None = None) -> StereoFrame:
    """Stereo-match detections ``(uv, desc)`` of the left and right images of one frame.

    pairs: the result of ``ratio_matches`` on these descriptors if already computed.
    """
    (uv_l, d_l), (uv_r, d_r) = det_l, det_r
    i, j = ratio_matches(d_l, d_r, settings.ratio) if pairs is None else pairs
    p_l = homogeneous(left.pixels_to_normalized(uv_l[i])) if len(i) else np.zeros((0, 3))
    p_r = homogeneous(right.pixels_to_normalized(uv_r[j])) if len(j) else np.zeros((0, 3))
    keep = np.all(np.isfinite(p_l), axis=1) & np.all(np.isfinite(p_r), axis=1)
    if settings.epipolar_px is not None and len(i):
        R, t = paper_from_opencv(right.R_cam_station, right.t_cam_station)
        f = 0.5 * (right.K[0, 0] + right.K[1, 1])
        keep &= epipolar_distance_px(p_l, p_r, essential_matrix(R, t), f) <= settings.epipolar_px
        tri = triangulate_paper_full(p_l, p_r, R, t)
        keep &= (tri.z_l > 0) & (tri.z_r > 0)
    i, j = i[keep], j[keep]
    return StereoFrame(uv_l[i], uv_r[j], p_l[keep], p_r[keep], d_l[i], d_r[j], len(uv_l), len(uv_r))


def common_keypoints(prev: StereoFrame, cur: StereoFrame,
                     settings: MatchSettings = MatchSettings()) -> tuple[np.ndarray, np.ndarray]:
    """Indices (K,), (K,) into ``prev`` and ``cur`` of keypoints seen in all four images."""
    a, b = ratio_matches(prev.desc_l, cur.desc_l, settings.ratio)
    if settings.circular and len(a):
        # Fig. 12's circle: the right descriptors of the pair must be each other's nearest.
        bf = cv2.BFMatcher(cv2.NORM_L2)
        nn = np.array([m.trainIdx for m in bf.match(prev.desc_r[a], cur.desc_r)])
        keep = nn == b
        a, b = a[keep], b[keep]
    return a, b
