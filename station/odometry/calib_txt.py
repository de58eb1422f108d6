"""A stereo pair from KITTI-style ``calib.txt`` projection matrices.

Two forms are read (docs/odometry.md):

* labelled, KITTI's: ``P0: ...`` ``P1: ...`` ``P2: ...`` ``P3: ...`` (12 numbers each; KITTI
  raw's ``P_rect_00:`` ... ``P_rect_03:`` are the same matrices); other labelled lines (``Tr:``,
  ``R0_rect:``, ``calib_time:``) are ignored. The image folders say which two are the pair
  (``image_0/ image_1/``: P0, P1; ``image_2/ image_3/``: P2, P3).
* unlabelled: one 3x4 matrix per line, 12 numbers; the first two are the left and right cameras.

A projection matrix is ``P = K [R | t]`` (rectified KITTI matrices have ``R = I``); the pair is
returned in the rig frame = the left camera (``x_right = R_right_left x_left + t_right_left``),
without distortion (KITTI's images are rectified).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.camera_model import CameraModel
from station.errors import OdometryError

CALIB_HINT = ("calib.txt: either KITTI's labelled lines 'P0: <12 numbers>' 'P1: ...', or the left "
              "and right 3x4 projection matrices on the first two lines, 12 numbers each, row-major")
_LABEL = re.compile(r"^\s*([A-Za-z][\w]*)\s*:(.*)$")
_PROJECTION = re.compile(r"^P(?:_rect_0)?([0-3])$")     # P0..P3, P_rect_00..P_rect_03 -> "P0".."P3"


@dataclass(frozen=True)
class Projection:
    """One 3x4 matrix of calib.txt: ``label`` ("P0".."P3", or "" unlabelled), its line."""

    label: str
    line: int
    P: np.ndarray            # (3,4)

    @property
    def name(self) -> str:
        return self.label or f"line {self.line}"


@dataclass(frozen=True)
class StereoCalib:
    """The pair read from calib.txt. ``T_truth_left`` (4,4) maps the left camera's coordinates
    into P0's when the left camera is another one of KITTI's (whose poses describe P0), else None."""

    left: CameraModel
    right: CameraModel
    source: str              # e.g. "calib.txt P2/P3", "calib.txt lines 1-2 (unlabelled)"
    T_truth_left: np.ndarray | None = None


def read_projections(path: Path) -> list[Projection]:
    """Every projection matrix of ``path``, labelled or not, in file order; OdometryError for a
    projection line that is not 12 numbers."""
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise OdometryError(f"{path}: not a text file", hint=CALIB_HINT) from None
    except OSError as e:
        raise OdometryError(f"{path}: cannot read ({e.strerror or e})", hint=CALIB_HINT) from e
    out = []
    for no, line in enumerate(text.splitlines(), 1):
        m = _LABEL.match(line)
        if m:
            p = _PROJECTION.match(m.group(1))
            if not p:
                continue                                  # Tr:, R0_rect:, calib_time: ...
            label, words = f"P{p.group(1)}", m.group(2).split()
            what = f"{path} line {no} ({m.group(1)})"
        else:
            label, words = "", line.split()
            if not words or words[0].startswith("#"):
                continue
            what = f"{path} line {no}"
        if len(words) != 12:
            raise OdometryError(f"{what}: {len(words)} numbers, expected 12 (a 3x4 projection "
                                "matrix, row-major)", hint=CALIB_HINT)
        try:
            P = np.array([float(w) for w in words]).reshape(3, 4)
        except ValueError:
            raise OdometryError(f"{what}: not 12 numbers ({' '.join(words[:3])} ...)",
                                hint=CALIB_HINT) from None
        if not np.isfinite(P).all():
            raise OdometryError(f"{what}: not finite numbers", hint=CALIB_HINT)
        out.append(Projection(label, no, P))
    return out


def pick_pair(projections: list[Projection], labels: tuple[str, str], path: Path,
              folders: str) -> tuple[Projection, Projection]:
    """The (left, right) matrices: by ``labels`` in a labelled file, else the first two lines."""
    labelled = {p.label: p for p in projections if p.label}
    if labelled:
        missing = [lb for lb in labels if lb not in labelled]
        if missing:
            raise OdometryError(f"{path}: has {', '.join(sorted(labelled))} but no {' or '.join(missing)}: "
                                f"{folders} need {labels[0]} (left) and {labels[1]} (right)",
                                hint=CALIB_HINT)
        return labelled[labels[0]], labelled[labels[1]]
    if len(projections) < 2:
        raise OdometryError(f"{path}: {len(projections)} projection matrix line(s), need two "
                            "(left, then right)", hint=CALIB_HINT)
    return projections[0], projections[1]


def decompose(P: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``P = s K [R | t]`` -> K (3,3, K[2,2] = 1, positive focal lengths), R (3,3), t (3,) by an
    RQ decomposition of P's left 3x3 block."""
    M = P[:, :3]
    if not np.linalg.cond(M) < 1e12:
        raise OdometryError(f"{what}: not a projection matrix (its left 3x3 block is singular)",
                            hint=CALIB_HINT)
    if np.linalg.det(M) < 0:
        P, M = -P, -M
    flip = np.eye(3)[::-1]
    Q_, R_ = np.linalg.qr((flip @ M).T)           # RQ of M through QR of the flipped transpose
    K = flip @ R_.T @ flip
    R = flip @ Q_.T
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R                           # positive diagonal; det R stays +1
    t = np.linalg.solve(K, P[:, 3])
    return K / K[2, 2], R, t


def stereo_from_projections(left: Projection, right: Projection, size: tuple[int, int],
                            path: Path, p0: Projection | None = None) -> StereoCalib:
    """The pair in the rig frame (= left camera) for images of ``size`` (w, h). ``p0``: KITTI's
    P0, when the left camera is not P0 (the truth poses describe P0's camera)."""
    K_l, R_l, t_l = decompose(left.P, f"{path} {left.name}")
    K_r, R_r, t_r = decompose(right.P, f"{path} {right.name}")
    R_rl = R_r @ R_l.T
    t_rl = t_r - R_rl @ t_l
    if np.linalg.norm(t_rl) < 1e-6:
        raise OdometryError(f"{path}: {left.name} and {right.name} are the same camera (no baseline)",
                            hint=CALIB_HINT)
    w, h = size
    cam_l = CameraModel("left", w, h, K_l)
    cam_r = CameraModel("right", w, h, K_r, np.zeros(5), R_rl, t_rl)
    if left.label:
        source = f"{path.name} {left.label}/{right.label}"
    else:
        source = f"{path.name} lines {left.line} and {right.line} (unlabelled)"
    T_truth_left = None
    if p0 is not None and p0 is not left:
        _, R_0, t_0 = decompose(p0.P, f"{path} P0")
        T_truth_left = np.eye(4)                  # x_P0 = R_0 R_l^T (x_left - t_l) + t_0
        T_truth_left[:3, :3] = R_0 @ R_l.T
        T_truth_left[:3, 3] = t_0 - R_0 @ R_l.T @ t_l
    return StereoCalib(cam_l, cam_r, source, T_truth_left)


def read_stereo_calib(path: Path, labels: tuple[str, str], folders: str,
                      size: tuple[int, int]) -> StereoCalib:
    """calib.txt -> the stereo pair of the image folders ``folders`` (named in messages)."""
    projections = read_projections(path)
    left, right = pick_pair(projections, labels, path, folders)
    p0 = next((p for p in projections if p.label == "P0"), None)
    return stereo_from_projections(left, right, size, path, p0)
