"""OpenCV FileStorage files (YAML, XML, JSON, as ``cv2.FileStorage`` reads them): every key of
a file read with a message naming the file and the key when it is missing or wrong, OpenCV's
distortion vectors taken into the camera model's, and the station's cameras and pairs written
for OpenCV (docs/calibration.md, "Import and export"; the key layouts are listed there).

Units: a file's ``T`` is in whatever unit its maker used (the board's square size for OpenCV's
samples); the reader scales it to metres by the factor it is given.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.calib_file import StationCalibration
from calibration.camera_model import CameraModel, dist_length_problem
from calibration.errors import CalibrationError

# OpenCV's distortion lengths: 4 (k3 = 0), 5, 8, 12, 14 (the last two the tilted sensor's tauX tauY)
OPENCV_DIST_LENGTHS = (4, 5, 8, 12, 14)
HINT = "see docs/calibration.md, \"Import and export\", for the keys each kind of file needs"


def _read_node(node):
    """One FileNode as a float array (a matrix or a list of numbers), a float, a str, or None
    (a nested map, a list of text, ...: nothing the import reads)."""
    if node.isInt() or node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    if node.isMap():  # an !!opencv-matrix (rows, cols, dt, data), or some other map
        try:
            m = node.mat()
        except Exception:  # noqa: BLE001 - cv2.error for a map that is no matrix
            return None
        return None if m is None else np.asarray(m, dtype=float)
    if node.isSeq():  # a plain list of numbers, or a list of such lists
        rows = [node.at(i) for i in range(node.size())]
        if all(r.isInt() or r.isReal() for r in rows):
            return np.array([r.real() for r in rows], dtype=float)
        if rows and all(r.isSeq() for r in rows):
            values = [[r.at(j).real() if r.at(j).isInt() or r.at(j).isReal() else np.nan for j in range(r.size())]
                      for r in rows]
            if len({len(v) for v in values}) == 1:
                return np.array(values, dtype=float)
    return None


def read_storage(path: str | os.PathLike) -> dict[str, object]:
    """Every top-level key of an OpenCV FileStorage file -> its value (see :func:`_read_node`).
    CalibrationError naming the file when it is missing, unreadable or not a FileStorage file."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    try:
        with open(path, "rb") as f:
            head = f.read(1)
    except OSError as e:
        raise CalibrationError(f"{path}: cannot read it ({e.strerror or e})") from None
    if not head:
        raise CalibrationError(f"{path}: the file is empty", hint=HINT)
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except Exception as e:  # noqa: BLE001 - cv2.error, or SystemError wrapping it, on a parse failure
        raise CalibrationError(f"{path}: not an OpenCV FileStorage file (YAML, XML or JSON as cv2.FileStorage "
                               f"writes): {_parse_error(e, path)}", hint=HINT) from None
    try:
        if not fs.isOpened():
            raise CalibrationError(f"{path}: OpenCV cannot open it as a FileStorage file", hint=HINT)
        root = fs.root()
        if not root.isMap():
            raise CalibrationError(f"{path}: not an OpenCV FileStorage file of named keys", hint=HINT)
        return {key: _read_node(root.getNode(key)) for key in root.keys()}
    finally:
        fs.release()


def _parse_error(e: Exception, path: Path) -> str:
    """OpenCV's parser message without its source location: ``line 3: Missing , between the elements``."""
    text = str(e.__cause__ or e).strip().splitlines()[-1]
    m = re.search(r"in function '(.*?)'?$", text)
    text = m.group(1) if m else text
    m = re.match(rf"{re.escape(str(path))}\((\d+)\): (.*)", text)
    return (f"line {m.group(1)}: {m.group(2)}" if m else text)[:200]


@dataclass
class Keys:
    """The keys of one or more files read as one (OpenCV's stereo_calib writes a pair's M1 D1 M2
    D2 into intrinsics.yml and R T into extrinsics.yml). Each key remembers its file, for messages."""

    files: list[Path]
    values: dict[str, tuple[Path, object]]

    @classmethod
    def read(cls, paths) -> "Keys":
        files = [Path(p) for p in paths]
        values: dict[str, tuple[Path, object]] = {}
        for path in files:
            for key, value in read_storage(path).items():
                if key in values and not _same(values[key][1], value):
                    raise CalibrationError(f"{path}: {key} differs from the {key} in {values[key][0]}; files read "
                                           "together describe one camera or pair", hint="give one of the files")
                values.setdefault(key, (path, value))
        return cls(files, values)

    @property
    def source(self) -> str:
        return " + ".join(map(str, self.files))

    def __contains__(self, key: str) -> bool:
        return key in self.values

    def where(self, key: str) -> str:
        return f"{self.values[key][0] if key in self.values else self.source}: {key}"

    def missing(self, key: str, what: str, todo: str) -> CalibrationError:
        return CalibrationError(f"{self.source}: no key {key} ({what})", hint=todo)

    def matrix(self, key: str, shape: tuple[int, int], what: str, todo: str = HINT) -> np.ndarray:
        """The key's matrix of ``shape`` (a vector: (3, 1) also takes (1, 3) and (3,)), finite."""
        if key not in self.values:
            raise self.missing(key, what, todo)
        value = self.values[key][1]
        if not isinstance(value, np.ndarray):
            raise CalibrationError(f"{self.where(key)}: expected a {shape[0]}x{shape[1]} matrix ({what}), got "
                                   f"{_kind(value)}", hint=HINT)
        if 1 in shape and value.size == max(shape):
            value = value.reshape(shape)
        if value.shape != shape:
            raise CalibrationError(f"{self.where(key)}: expected a {shape[0]}x{shape[1]} matrix ({what}), got "
                                   f"{'x'.join(map(str, value.shape))}", hint=HINT)
        if not np.all(np.isfinite(value)):
            raise CalibrationError(f"{self.where(key)}: contains NaN or infinity", hint=HINT)
        return value

    def distortion(self, key: str, todo: str = HINT) -> np.ndarray:
        """OpenCV's distortion vector as the camera model's (5,), (8,) or (12,): 4 coefficients
        get k3 = 0, 14 with tauX = tauY = 0 are the 12-term model, a tilted sensor is refused."""
        if key not in self.values:
            raise self.missing(key, "the distortion coefficients", todo)
        value = self.values[key][1]
        if not isinstance(value, np.ndarray) or (value.ndim == 2 and 1 not in value.shape) or value.ndim > 2:
            raise CalibrationError(f"{self.where(key)}: expected a row or column of distortion coefficients, got "
                                   f"{_kind(value)}", hint=HINT)
        d = value.ravel()
        if not np.all(np.isfinite(d)):
            raise CalibrationError(f"{self.where(key)}: contains NaN or infinity", hint=HINT)
        if d.size not in OPENCV_DIST_LENGTHS:
            raise CalibrationError(f"{self.where(key)}: {d.size} coefficients; OpenCV writes 4, 5, 8, 12 or 14",
                                   hint=HINT)
        if d.size == 4:
            return np.r_[d, 0.0]
        if d.size == 14:
            if np.any(d[12:] != 0):
                raise CalibrationError(f"{self.where(key)}: {dist_length_problem(14)} (tauX = {d[12]:g}, "
                                       f"tauY = {d[13]:g})",
                                       hint="recalibrate without CALIB_TILTED_MODEL (5, 8 or 12 coefficients)")
            return d[:12].copy()
        return d.copy()

    def number(self, key: str, what: str, todo: str = HINT) -> float:
        if key not in self.values:
            raise self.missing(key, what, todo)
        value = self.values[key][1]
        if isinstance(value, np.ndarray) and value.size == 1:
            value = float(value.ravel()[0])
        if not isinstance(value, float) or not np.isfinite(value):
            raise CalibrationError(f"{self.where(key)}: expected a number ({what}), got {_kind(value)}", hint=HINT)
        return value

    def text(self, key: str) -> str | None:
        """The key's text, None when absent; CalibrationError when it is not text."""
        if key not in self.values:
            return None
        value = self.values[key][1]
        if not isinstance(value, str):
            raise CalibrationError(f"{self.where(key)}: expected text, got {_kind(value)}", hint=HINT)
        return value

    def size(self) -> tuple[int, int] | None:
        """(image_width, image_height) when the file has them (both), else None."""
        if "image_width" not in self and "image_height" not in self:
            return None
        w, h = (self.number(k, "the image size in px") for k in ("image_width", "image_height"))
        if w != int(w) or h != int(h) or w < 1 or h < 1:
            raise CalibrationError(f"{self.source}: image_width x image_height = {w:g} x {h:g} is not an image size",
                                   hint=HINT)
        return int(w), int(h)

    def rotation(self, what: str, todo: str) -> np.ndarray:
        """R (3x3), or rvec (3, Rodrigues) when there is no R."""
        if "R" not in self and "rvec" in self:
            return cv2.Rodrigues(self.matrix("rvec", (3, 1), what))[0]
        return self.matrix("R", (3, 3), what, todo)


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape and np.array_equal(a, b)
    return a == b


def _kind(value) -> str:
    if isinstance(value, np.ndarray):
        return f"a {'x'.join(map(str, value.shape))} matrix"
    return {float: "a number", str: "text", type(None): "a map or list that is no matrix"}.get(type(value), "?")


# --- writing ------------------------------------------------------------------------------------
def write_storage(path: Path, items: dict[str, object]) -> Path:
    """One FileStorage file (YAML, XML or JSON by the name's ending) of ``items``; CalibrationError
    naming the file when it cannot be written."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    except (OSError, cv2.error, SystemError) as e:
        raise CalibrationError(f"{path}: cannot write it ({getattr(e, 'strerror', None) or e})") from None
    if not fs.isOpened():
        raise CalibrationError(f"{path}: cannot write it")
    try:
        for key, value in items.items():
            fs.write(key, value)
    finally:
        fs.release()
    return path


def camera_items(cam_id: str, m: CameraModel) -> dict[str, object]:
    """A camera as the station writes it: OpenCV's calibration-sample keys plus its station pose."""
    return {"camera_id": cam_id, "image_width": int(m.width), "image_height": int(m.height),
            "camera_matrix": np.asarray(m.K, float), "distortion_coefficients": m.dist.reshape(1, -1).astype(float),
            "R": np.asarray(m.R_cam_station, float), "T": m.t_cam_station.reshape(3, 1).astype(float),
            "rvec": m.rvec.reshape(3, 1)}


def pair_items(wheel: str, id_a: str, id_b: str, a: CameraModel, b: CameraModel) -> dict[str, object]:
    """A pair as OpenCV's stereo_calib writes it (M1 D1 M2 D2 R T: x_b = R x_a + T, metres),
    with the wheel, the two cameras' ids and, when both cameras have one size, the image size."""
    R_ba = b.R_cam_station @ a.R_cam_station.T
    t_ba = b.t_cam_station - R_ba @ a.t_cam_station
    size = {"image_width": int(a.width), "image_height": int(a.height)} if (a.width, a.height) == (b.width, b.height) \
        else {}
    return {"wheel": wheel, "camera_1": id_a, "camera_2": id_b, **size,
            "M1": np.asarray(a.K, float), "D1": a.dist.reshape(1, -1).astype(float),
            "M2": np.asarray(b.K, float), "D2": b.dist.reshape(1, -1).astype(float),
            "R": R_ba, "T": t_ba.reshape(3, 1)}


def export_opencv(calib: StationCalibration, directory: str | os.PathLike) -> list[Path]:
    """``DIR/<cam_id>.yaml`` per camera (:func:`camera_items`) and ``DIR/pairs/<wheel>.yaml`` per
    pair (:func:`pair_items`, its precision camera as camera 1). Returns the paths written."""
    directory = Path(directory)
    out = [write_storage(directory / f"{cam_id}.yaml", camera_items(cam_id, c.model))
           for cam_id, c in calib.cameras.items()]
    for wheel, (left, right) in calib.pairs.items():
        out.append(write_storage(directory / "pairs" / f"{wheel}.yaml",
                                 pair_items(wheel, left, right, calib.model(left), calib.model(right))))
    return out
