"""Box detection: ChArUco corners per face, sub-pixel accuracy, partly hidden faces, vertices.

Images come from a small exact renderer here (perspective warps of the face textures,
4x4 supersampled, no lens distortion) so these tests do not depend on the simulator.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.box_detect import BoxDetector
from calibration.camera_model import rodrigues_to_matrix
from station.config import load_box

BOX_YAML = Path(__file__).resolve().parent.parent / "config" / "box.yaml"
K = np.array([[1800.0, 0, 639.5], [0, 1800.0, 511.5], [0, 0, 1]])


def render_box(box, K, R_cam_box, t_cam_box, size=(1280, 1024), noise=0.0, rng=None, ss=4,
               occluder=None):
    """(H,W) uint8 image of the box (pinhole, no distortion), grey background.

    occluder: optional (x0, y0, x1, y1) pixel rectangle painted mid-grey (a hand)."""
    W, H = size
    S = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1.0]])
    canvas = np.full((H * ss, W * ss), 110.0, np.float32)
    faces = []
    for f, tex in zip(box.faces, box.textures):
        n_cam = R_cam_box @ f.normal
        centre = R_cam_box @ f.corners_box.mean(axis=0) + t_cam_box
        if n_cam @ centre < 0:
            faces.append((np.linalg.norm(centre), f, tex))
    for _, f, tex in sorted(faces, key=lambda x: -x[0]):
        tx = box.texel_m
        A = np.array([[tx, 0, 0.5 * tx], [0, tx, 0.5 * tx], [0, 0, 1.0]])
        H0 = S @ K @ np.c_[R_cam_box @ f.u, R_cam_box @ f.v, R_cam_box @ f.origin_box + t_cam_box]
        Hm = H0 @ A
        shade = 0.6 + 0.4 * abs((R_cam_box @ f.normal)[2])
        warped = cv2.warpPerspective(tex.astype(np.float32) * shade, Hm, (W * ss, H * ss),
                                     flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1)
        mask = cv2.warpPerspective(np.ones_like(tex, np.float32), Hm, (W * ss, H * ss),
                                   flags=cv2.INTER_NEAREST, borderValue=0) > 0.5
        canvas[mask] = warped[mask]
    img = cv2.resize(canvas, (W, H), interpolation=cv2.INTER_AREA)
    if occluder is not None:
        x0, y0, x1, y1 = occluder
        img[y0:y1, x0:x1] = 128
    if noise:
        img = img + (rng or np.random.default_rng(0)).normal(0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def box_pose(yaw_deg=35.0, tilt=(0.0, 0.0, 0.0), t=(0.0, 0.25, 1.3)):
    """Box in the camera frame: box z up = camera -y, yawed, then a small tilt."""
    a = np.radians(yaw_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    up = np.array([[0, 1.0, 0], [0, 0, -1], [-1, 0, 0]])  # box z (up) -> camera -y (image up)
    R = rodrigues_to_matrix(np.asarray(tilt, float)) @ up @ Rz
    return R, np.asarray(t, float)


@pytest.fixture(scope="module")
def box():
    return load_box(BOX_YAML)


@pytest.fixture(scope="module")
def detector(box):
    return BoxDetector(box)


def _truth(box, R, t, ids):
    P = box.points_for_ids(ids) @ R.T + t
    return (P[:, :2] / P[:, 2:]) @ K[:2, :2].T + K[:2, 2]


def test_two_faces_found_with_subpixel_corners(box, detector):
    R, t = box_pose()
    img = render_box(box, K, R, t, noise=2.0, rng=np.random.default_rng(3))
    det = detector.detect(img)
    assert set(det.faces) == {"px", "ny"} or len(det.faces) == 2, det.faces
    assert det.n_points > 200
    err = np.linalg.norm(det.pixels - _truth(box, R, t, det.ids), axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.12, np.sqrt(np.mean(err ** 2))
    assert err.max() < 0.4
    # six vertices on the two visible faces, placed within a pixel
    vis = det.vertex_mask
    assert vis.sum() == 6
    P = box.vertices[vis] @ R.T + t
    v_true = (P[:, :2] / P[:, 2:]) @ K[:2, :2].T + K[:2, 2]
    assert np.abs(det.vertex_pixels[vis] - v_true).max() < 1.0


def test_partly_hidden_face_still_gives_its_visible_corners(box, detector):
    R, t = box_pose()
    full = detector.detect(render_box(box, K, R, t))
    hidden = detector.detect(render_box(box, K, R, t, occluder=(400, 250, 640, 600)))
    assert 0.3 * full.n_points < hidden.n_points < full.n_points
    err = np.linalg.norm(hidden.pixels - _truth(box, R, t, hidden.ids), axis=1)
    assert err.max() < 0.3
    assert len(hidden.faces) == 2


def test_no_box_gives_an_empty_detection(detector):
    img = np.random.default_rng(0).integers(0, 255, (1024, 1280), dtype=np.uint8)
    det = detector.detect(img)
    assert det.n_points == 0 and not det.vertex_mask.any()
