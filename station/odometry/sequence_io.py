"""Reading a stereo sequence from disk: our simulated format and the KITTI odometry layout.

Layouts (docs/odometry.md):

* ours: ``left/`` and ``right/`` image folders, ``stereo.json`` (the two cameras as
  ``CameraModel`` dicts in the rig frame = the left camera; the right camera's pose is
  ``x_right = R_right_left x_left + t_right_left``; distortion allowed), optional ``poses.txt``.
* KITTI: ``image_0/`` and ``image_1/`` (or ``left/`` ``right/``), ``calib.txt`` with rectified
  projection matrices ``P0:`` and ``P1:`` (12 numbers each), optional ``poses.txt`` (or
  ``poses/NN.txt`` beside the sequence, passed explicitly).

Truth poses (``poses.txt``): one line per image, the 3x4 ``[R|t]`` of the left camera at that
step in the left camera frame of step 0, row-major (KITTI's convention).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.triangulation import paper_from_opencv
from station.errors import OdometryError

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".pgm", ".tif", ".tiff")
BLANK_STD_GREY = 2.0   # an image whose grey levels vary less than this carries no texture


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTS)


def read_poses(path: Path) -> np.ndarray:
    """KITTI pose file -> (N,4,4) camera-to-step-0 transforms."""
    try:
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as e:
        raise OdometryError(f"{path}: cannot read the poses ({e})",
                            hint="one line per image with 12 numbers (a 3x4 [R|t], row-major)") from e
    if rows.shape[1] != 12:
        raise OdometryError(f"{path}: expected 12 numbers per line, found {rows.shape[1]}")
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :] = rows.reshape(-1, 3, 4)
    return T


def write_poses(path: Path, T: np.ndarray) -> None:
    """(N,4,4) transforms -> KITTI pose file (12 numbers per line)."""
    lines = [" ".join(f"{v:.9e}" for v in M[:3].ravel()) for M in np.asarray(T)]
    Path(path).write_text("\n".join(lines) + ("\n" if lines else ""))


def _kitti_calib(path: Path, size: tuple[int, int]) -> tuple[CameraModel, CameraModel]:
    mats = {}
    for line in path.read_text().splitlines():
        key, _, rest = line.partition(":")
        vals = rest.split()
        if key.strip() in ("P0", "P1") and len(vals) == 12:
            mats[key.strip()] = np.array(vals, float).reshape(3, 4)
    if "P0" not in mats or "P1" not in mats:
        raise OdometryError(f"{path}: needs the lines 'P0:' and 'P1:' with 12 numbers each",
                            hint="KITTI's calib.txt of the sequence (rectified projection matrices)")
    K0 = mats["P0"][:, :3]
    K1 = mats["P1"][:, :3]
    t0 = np.linalg.solve(K0, mats["P0"][:, 3])
    t1 = np.linalg.solve(K1, mats["P1"][:, 3])
    w, h = size
    left = CameraModel("left", w, h, K0)
    right = CameraModel("right", w, h, K1, np.zeros(5), np.eye(3), t1 - t0)
    return left, right


@dataclass
class StereoSequence:
    """A stereo sequence on disk. ``left``/``right``: cameras in the rig frame (left = identity).

    truth: (N,4,4) left camera i -> left camera 0, or None.
    """

    directory: Path
    layout: str
    left: CameraModel
    right: CameraModel
    left_files: list[Path]
    right_files: list[Path]
    truth: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.left_files)

    @property
    def paper_pair(self) -> tuple[np.ndarray, np.ndarray]:
        """The paper's (R, t) with P_l = R^T P_r + t (eq. 25)."""
        return paper_from_opencv(self.right.R_cam_station, self.right.t_cam_station)

    def load(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Images of image index ``i``: (left, right) grey uint8, checked (names the step)."""
        imgs = []
        for side, files, cam in (("left", self.left_files, self.left),
                                 ("right", self.right_files, self.right)):
            path = files[i]
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise OdometryError(f"image {i}: cannot read the {side} image {path}",
                                    hint="check the file is a complete image")
            if img.ndim == 3:
                img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
            if img.dtype != np.uint8:
                img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
            if (img.shape[1], img.shape[0]) != (cam.width, cam.height):
                raise OdometryError(
                    f"image {i}: the {side} image {path.name} is {img.shape[1]}x{img.shape[0]} but the "
                    f"calibration says {cam.width}x{cam.height}",
                    hint="left and right images must all have the calibrated size")
            if float(img.std()) < BLANK_STD_GREY:
                raise OdometryError(f"image {i}: the {side} image {path.name} is blank "
                                    f"(grey-level std {img.std():.2f})",
                                    hint="check the camera's exposure and lens cap")
            imgs.append(img)
        return imgs[0], imgs[1]


def open_sequence(directory: str | Path, poses: str | Path | None = None) -> StereoSequence:
    """Open a sequence folder (our layout or KITTI's); raises OdometryError saying what is missing."""
    d = Path(directory)
    if not d.is_dir():
        raise OdometryError(f"{d}: no such directory", hint="give the folder of a stereo sequence")
    for lname, rname in (("left", "right"), ("image_0", "image_1")):
        if (d / lname).is_dir() and (d / rname).is_dir():
            break
    else:
        raise OdometryError(f"{d}: no image folders 'left/' and 'right/' (or KITTI's 'image_0/' "
                            "and 'image_1/')")
    left_files, right_files = _images(d / lname), _images(d / rname)
    if not left_files:
        raise OdometryError(f"{d / lname}: no images")
    if [p.stem for p in left_files] != [p.stem for p in right_files]:
        only = sorted({p.stem for p in left_files} ^ {p.stem for p in right_files})
        raise OdometryError(f"{d}: left and right images do not pair up (unpaired: {', '.join(only[:5])})",
                            hint="every left image needs a right image of the same name")
    if (d / "stereo.json").is_file():
        try:
            spec = json.loads((d / "stereo.json").read_text())
            left, right = CameraModel.from_dict(spec["left"]), CameraModel.from_dict(spec["right"])
        except (ValueError, KeyError, TypeError) as e:
            raise OdometryError(f"{d / 'stereo.json'}: not a valid stereo calibration ({e})") from e
        if np.any(left.R_cam_station != np.eye(3)) or np.any(left.t_cam_station != 0):
            raise OdometryError(f"{d / 'stereo.json'}: the left camera must be the rig frame "
                                "(identity pose)")
        layout = "station"
    elif (d / "calib.txt").is_file():
        first = cv2.imread(str(left_files[0]), cv2.IMREAD_UNCHANGED)
        if first is None:
            raise OdometryError(f"image 0: cannot read the left image {left_files[0]}")
        left, right = _kitti_calib(d / "calib.txt", (first.shape[1], first.shape[0]))
        layout = "kitti"
    else:
        raise OdometryError(f"{d}: missing calibration: neither 'stereo.json' nor KITTI's 'calib.txt'",
                            hint="odometry needs the stereo pair's calibration (station calibrate)")
    truth = None
    pose_path = Path(poses) if poses else d / "poses.txt"
    if poses or pose_path.is_file():
        truth = read_poses(pose_path)
        if len(truth) < len(left_files):
            raise OdometryError(f"{pose_path}: {len(truth)} poses for {len(left_files)} images")
        truth = truth[:len(left_files)]
    return StereoSequence(d, layout, left, right, left_files, right_files, truth)
