"""Opening a stereo sequence on disk: its image folders, its calibration, its truth.

Layouts (docs/odometry.md; the folders in :mod:`station.odometry.image_folders`):

* ours: ``left/`` and ``right/`` image folders, ``stereo.json`` (the two cameras as
  ``CameraModel`` dicts in the rig frame = the left camera; the right camera's pose is
  ``x_right = R_right_left x_left + t_right_left``; distortion allowed), optional ``poses.txt``.
* KITTI's and its common variants: ``image_0/ image_1/``, ``image_l/ image_r/``, ``left/
  right/``, ``image_2/ image_3/`` or ``image_02/ image_03/`` with ``calib.txt``, labelled (``P0:``
  ... ``P3:``) or two unlabelled 3x4 matrices (:mod:`station.odometry.calib_txt`); optional
  ``times.txt`` and ``poses.txt`` (or a poses file anywhere, passed explicitly).

Truth poses (:mod:`station.odometry.poses_io`): one line per image, the 3x4 ``[R|t]`` of the
left camera at that image, re-expressed from the first image's pose.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.triangulation import paper_from_opencv
from station.errors import OdometryError
from station.odometry.calib_txt import read_stereo_calib
from station.odometry.image_folders import ImageFolders, find_images
from station.odometry.poses_io import read_truth, rebase

BLANK_STD_GREY = 2.0   # an image whose grey levels vary less than this carries no texture


@dataclass
class StereoSequence:
    """A stereo sequence on disk. ``left``/``right``: cameras in the rig frame (left = identity).

    layout: "station" (stereo.json) or "kitti" (calib.txt); source: the folders and the
    calibration read, as a user sees them. truth: (N,4,4) left camera i -> left camera 0, or
    None; truth_file: where it came from. times_s: (N,) KITTI's times.txt, or None. notes:
    sentences about what was read and left aside (printed by the command).
    """

    directory: Path
    layout: str
    left: CameraModel
    right: CameraModel
    left_files: list[Path]
    right_files: list[Path]
    truth: np.ndarray | None = None
    source: str = ""
    truth_file: Path | None = None
    times_s: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

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
            img = read_grey(path, f"image {i}: the {side} image")
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


def read_grey(path: Path, what: str) -> np.ndarray:
    """An image file as grey uint8 (colour converted, 16-bit scaled); OdometryError naming
    ``what`` and the file when it cannot be read."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        try:
            size = path.stat().st_size
        except OSError as e:
            size = None
            why = e.strerror or str(e)
        else:
            why = "an empty file" if size == 0 else "not a readable image (truncated, or another format)"
        raise OdometryError(f"{what} {path} cannot be read: {why}",
                            hint="replace or remove the file (with its partner from the other camera)")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
    return img


def _stereo_json(path: Path) -> tuple[CameraModel, CameraModel]:
    try:
        spec = json.loads(path.read_text())
        left, right = CameraModel.from_dict(spec["left"]), CameraModel.from_dict(spec["right"])
    except (ValueError, KeyError, TypeError) as e:
        raise OdometryError(f"{path}: not a valid stereo calibration ({e})") from e
    if np.any(left.R_cam_station != np.eye(3)) or np.any(left.t_cam_station != 0):
        raise OdometryError(f"{path}: the left camera must be the rig frame (identity pose)")
    return left, right


def _times(path: Path, n: int, notes: list[str]) -> np.ndarray | None:
    """KITTI's times.txt (one time in seconds per image), or None with a note when unusable."""
    try:
        t = np.array([float(w) for w in path.read_text().split()])
    except (OSError, UnicodeDecodeError, ValueError):
        notes.append(f"{path.name} left aside: not one number per line")
        return None
    if len(t) != n:
        notes.append(f"{path.name} left aside: {len(t)} times for {n} images")
        return None
    return t


def _truth(path: Path, n_images: int, T_truth_left: np.ndarray | None,
           notes: list[str]) -> np.ndarray:
    """The truth for the images, re-expressed from the first one (and moved to the left camera
    when the poses describe another one); OdometryError when there are fewer poses than images."""
    T = read_truth(path)
    if len(T) < n_images:
        raise OdometryError(f"{path}: {len(T)} poses for {n_images} images: the truth needs one "
                            "line per image", hint="give the poses file of this sequence (KITTI: poses/NN.txt)")
    if len(T) > n_images:
        notes.append(f"{path.name}: {len(T)} poses for {n_images} images; the first {n_images} are used")
    if T_truth_left is not None:
        notes.append(f"{path.name}: the poses (of P0's camera) moved to the left camera, "
                     f"{np.linalg.norm(T_truth_left[:3, 3]):.3f} m from it")
    return rebase(T[:n_images], T_truth_left)


def open_sequence(directory: str | Path, poses: str | Path | None = None) -> StereoSequence:
    """Open a sequence folder (our layout or KITTI's and its variants); raises OdometryError
    saying what was found and what is missing. ``poses``: the truth file, else DIR/poses.txt
    if there is one."""
    d = Path(directory)
    if not d.is_dir():
        raise OdometryError(f"{d}: no such directory", hint="give the folder of a stereo sequence")
    images: ImageFolders = find_images(d)
    notes: list[str] = []
    T_truth_left = None
    if (d / "stereo.json").is_file():
        left, right = _stereo_json(d / "stereo.json")
        layout, calib_source = "station", "stereo.json"
    elif (d / "calib.txt").is_file():
        first = read_grey(images.left_files[0], "image 0: the left image")
        calib = read_stereo_calib(d / "calib.txt", images.calib_labels, images.names,
                                  (first.shape[1], first.shape[0]))
        left, right, T_truth_left = calib.left, calib.right, calib.T_truth_left
        layout, calib_source = "kitti", calib.source
    else:
        raise OdometryError(f"{d}: missing calibration: neither 'stereo.json' nor KITTI's 'calib.txt'",
                            hint="odometry needs the stereo pair's calibration (station calibrate), "
                                 "or calib.txt with the left and right 3x4 projection matrices")
    n = len(images.left_files)
    pose_path = Path(poses) if poses else d / "poses.txt"
    truth = None
    if poses or pose_path.is_file():
        truth = _truth(pose_path, n, T_truth_left, notes)
    times = _times(d / "times.txt", n, notes) if (d / "times.txt").is_file() else None
    return StereoSequence(d, layout, left, right, images.left_files, images.right_files, truth,
                          source=f"{images.names} + {calib_source}",
                          truth_file=pose_path if truth is not None else None,
                          times_s=times, notes=notes)
