"""The checks every field of a calibration file passes when it is read: types, shapes, finite
numbers and values a camera of this model can have (docs/calibration-format.md, "Validation on
load").

Each reader takes the parsed JSON of one part of the file and returns it converted, or raises
:class:`FieldError` naming the field by its path in the file (``cameras.cam3.K``) and saying
what is wrong; ``StationCalibration.from_dict`` turns that into the CalibrationError a user sees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime

import numpy as np

from calibration.camera_model import CameraModel, dist_length_problem, distort_normalized, undistort_normalized
from calibration.stereo import StereoPair

SIZE_PX = (8, 32768)              # image width and height a camera can have
FOV_DEG = (0.5, 150.0)            # field of view per image axis of a camera this model describes
PIXEL_ASPECT = (0.5, 2.0)         # fy / fx
MAX_DISTORTION = 0.5              # no border pixel moves by more than this share of its distance from the centre
MAX_CAMERA_DISTANCE_M = 100.0     # a station camera stands within this of the station origin
MIN_BASELINE_M = 0.001            # a pair's cameras at one place cannot triangulate
ROTATION_TOL = 1e-6               # |R R^T - I| and |det R - 1|
DERIVED_TOL = 1e-6                # stored derived values against the ones computed from the cameras
COVARIANCE_SIZE = 30              # two cameras x [9 intrinsics, rotation vector, centre]
STD_SCALARS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
STD_VECTORS = ("position_m", "rotation_deg")

TOP_KEYS = {"format", "format_version", "calibration_id", "created_utc", "software_version", "station_name",
            "method", "camera_ids", "cameras", "pairs", "notes"}
TOP_TEXT = ("calibration_id", "created_utc", "software_version", "station_name", "method")
CAMERA_REQUIRED = ("width", "height", "K", "dist", "R_cam_station", "t_cam_station_m")
CAMERA_OPTIONAL = ("center_station_m", "reprojection_rms_px", "n_points", "std")
PAIR_REQUIRED = ("left", "right")
PAIR_DERIVED = {"R": (3, 3), "t_m": (3,), "E": (3, 3), "F": (3, 3)}
PAIR_OPTIONAL = (*PAIR_DERIVED, "baseline_m", "covariance")


class FieldError(Exception):
    """One field of the file is wrong: ``where`` is its path (``pairs.FL.R``), ``str(e)`` what."""

    def __init__(self, where: str, message: str):
        super().__init__(message)
        self.where = where


# --- plain values -----------------------------------------------------------------------------
def _kind(v) -> str:
    return "null" if v is None else {bool: "true/false", str: "text", list: "a list", dict: "an object"}.get(
        type(v), type(v).__name__)


def mapping(v, where: str) -> dict:
    if not isinstance(v, dict):
        raise FieldError(where, f"expected an object, got {_kind(v)}")
    return v


def keys(d: dict, where: str, required, optional=()) -> None:
    """Every ``required`` key present, no key beyond ``required`` and ``optional``."""
    for k in d:
        if k not in required and k not in optional:
            raise FieldError(f"{where}.{k}" if where else str(k), "unknown key (docs/calibration-format.md lists them)")
    for k in required:
        if k not in d:
            raise FieldError(f"{where}.{k}" if where else k, "missing")


def number(v, where: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise FieldError(where, f"expected a number, got {_kind(v)}")
    try:
        x = float(v)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise FieldError(where, "not a finite number (NaN, infinity or beyond 1.8e308)")
    if not lo <= x <= hi:
        raise FieldError(where, f"{x:g} is outside [{lo:g}, {hi:g}]")
    return x


def integer(v, where: str, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise FieldError(where, f"expected a whole number, got {_kind(v)} {_short(v)}")
    if not lo <= v <= hi:
        raise FieldError(where, f"{_short(v)} is outside [{lo}, {hi}]")
    return v


def _short(v) -> str:
    text = repr(v)
    return text if len(text) <= 24 else f"{text[:12]}...({len(text)} characters)"


def text(v, where: str) -> str:
    if not isinstance(v, str):
        raise FieldError(where, f"expected text, got {_kind(v)}")
    return v


def array(v, where: str, shape: tuple[int, ...]) -> np.ndarray:
    """A nested list of finite numbers of ``shape`` as a float array."""
    def check(x, depth, path):
        if depth == len(shape):
            number(x, path)
            return
        if not isinstance(x, list) or len(x) != shape[depth]:
            raise FieldError(where, f"expected {'x'.join(map(str, shape))} numbers, got {_kind(x)}"
                             + (f" of {len(x)}" if isinstance(x, list) else ""))
        for i, item in enumerate(x):
            check(item, depth + 1, f"{path}[{i}]")
    check(v, 0, where)
    return np.array(v, dtype=float)


# --- the document -------------------------------------------------------------------------------
@dataclass
class Document:
    """A calibration file's content, checked: per camera (model, RMS, corners used, std), per
    wheel (left, right), the pairs' covariances, the header's texts and the notes."""

    cameras: dict[str, tuple[CameraModel, float, int, dict]]
    pairs: dict[str, tuple[str, str]]
    covariance: dict[str, np.ndarray]
    header: dict[str, str]
    notes: dict


def read_document(d: dict) -> Document:
    """Every part of a parsed calibration file (its format and version already checked)."""
    keys(d, "", ("format", "format_version", "cameras", "pairs"), TOP_KEYS)
    header = {k: text(d.get(k, ""), k) for k in TOP_TEXT}
    if header["created_utc"]:
        try:
            datetime.fromisoformat(header["created_utc"])
        except ValueError:
            raise FieldError("created_utc", f"{_short(header['created_utc'])} is not an ISO 8601 time") from None
    if not mapping(d["cameras"], "cameras"):
        raise FieldError("cameras", "no cameras")
    cameras = {cam_id: read_camera(cam_id, c) for cam_id, c in d["cameras"].items()}
    if "camera_ids" in d:  # written for other tools: it must still list the cameras
        ids = d["camera_ids"]
        if not isinstance(ids, list) or sorted(map(str, ids)) != sorted(cameras) or len(set(map(str, ids))) != len(ids):
            raise FieldError("camera_ids", f"must list the cameras of the file ({', '.join(cameras)})")
    models = {cam_id: parts[0] for cam_id, parts in cameras.items()}
    pairs, covariance = {}, {}
    for wheel, p in mapping(d["pairs"], "pairs").items():
        left, right, cov = read_pair(wheel, p, models)
        pairs[wheel] = (left, right)
        if cov is not None:
            covariance[wheel] = cov
    if covariance and len(covariance) != len(pairs):  # one bundle adjustment writes all (imports, old files: none)
        lacking = sorted(set(pairs) - set(covariance))
        raise FieldError(f"pairs.{lacking[0]}.covariance", f"missing while pair(s) {', '.join(sorted(covariance))} "
                         "have theirs")
    return Document(cameras, pairs, covariance, header, mapping(d.get("notes", {}), "notes"))


# --- a camera ---------------------------------------------------------------------------------
def read_camera(cam_id: str, c) -> tuple[CameraModel, float, int, dict]:
    """``cameras.<cam_id>`` -> (model, reprojection RMS (px, NaN if unknown), corners used, std)."""
    where = f"cameras.{cam_id}"
    mapping(c, where)
    keys(c, where, CAMERA_REQUIRED, CAMERA_OPTIONAL)
    width = integer(c["width"], f"{where}.width", *SIZE_PX)
    height = integer(c["height"], f"{where}.height", *SIZE_PX)
    K = array(c["K"], f"{where}.K", (3, 3))
    dist = read_dist(c["dist"], f"{where}.dist")
    R = array(c["R_cam_station"], f"{where}.R_cam_station", (3, 3))
    t = array(c["t_cam_station_m"], f"{where}.t_cam_station_m", (3,))
    check_intrinsics(where, width, height, K)
    check_pose(where, R, t)
    model = CameraModel(cam_id, width, height, K, dist, R, t)
    problem = distortion_problem(model)
    if problem:
        raise FieldError(f"{where}.dist", problem)
    if "center_station_m" in c:  # derived, for reading only: it must still agree
        center = array(c["center_station_m"], f"{where}.center_station_m", (3,))
        if np.abs(center - model.center_station).max() > DERIVED_TOL:
            raise FieldError(f"{where}.center_station_m", "does not agree with R_cam_station and t_cam_station_m "
                             "(it is -R^T t; the file was edited or damaged)")
    rms = c.get("reprojection_rms_px")
    rms = math.nan if rms is None else number(rms, f"{where}.reprojection_rms_px", 0, max(width, height))
    n_points = integer(c.get("n_points", 0), f"{where}.n_points", 0, 10**9)
    return model, rms, n_points, read_std(c.get("std", {}), f"{where}.std", model)


def read_dist(v, where: str) -> np.ndarray:
    """OpenCV's distortion coefficients: a list of 5, 8 or 12 finite numbers (camera_model.DIST_LENGTHS)."""
    if not isinstance(v, list):
        raise FieldError(where, f"expected a list of 5, 8 or 12 numbers, got {_kind(v)}")
    problem = dist_length_problem(len(v))
    if problem:
        raise FieldError(where, f"has {problem}")
    return array(v, where, (len(v),))


def check_intrinsics(where: str, width: int, height: int, K: np.ndarray) -> None:
    """K is ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` with a field of view, pixel aspect and
    principal point a camera of ``width`` x ``height`` pixels can have."""
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise FieldError(f"{where}.K", "expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (the camera model has no skew)")
    fx, fy, cx, cy = (float(x) for x in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    for name, f, size, axis in (("fx", fx, width, "horizontal"), ("fy", fy, height, "vertical")):
        if not f > 0:
            raise FieldError(f"{where}.K", f"{name} = {f:g} px; a focal length must be positive")
        fov = math.degrees(2 * math.atan(size / (2 * f)))
        if not FOV_DEG[0] <= fov <= FOV_DEG[1]:
            raise FieldError(f"{where}.K", f"{name} = {f:g} px gives a {axis} field of view of {fov:.3g} deg over "
                             f"{size} px; a camera of this model sees {FOV_DEG[0]:g}-{FOV_DEG[1]:g} deg")
    if not PIXEL_ASPECT[0] <= fy / fx <= PIXEL_ASPECT[1]:
        raise FieldError(f"{where}.K", f"fy / fx = {fy / fx:.3g}; pixels this far from square are not a real camera's")
    for name, p, size in (("cx", cx, width), ("cy", cy, height)):
        if not -0.5 <= p <= size - 0.5:
            raise FieldError(f"{where}.K", f"{name} = {p:g} px puts the principal point outside the "
                             f"{width}x{height} image")


def check_pose(where: str, R: np.ndarray, t: np.ndarray) -> None:
    if abs(np.linalg.det(R) - 1) > ROTATION_TOL or np.abs(R @ R.T - np.eye(3)).max() > ROTATION_TOL:
        raise FieldError(f"{where}.R_cam_station", "is not a rotation (R R^T must be I and det R = 1)")
    distance = float(np.linalg.norm(t))  # |centre| = |t| since R is a rotation
    if distance > MAX_CAMERA_DISTANCE_M:
        raise FieldError(f"{where}.t_cam_station_m", f"puts the camera {distance:.3g} m from the station origin; "
                         f"a station camera stands within {MAX_CAMERA_DISTANCE_M:g} m")


def distortion_problem(model: CameraModel, n: int = 48) -> str | None:
    """Why ``model.dist`` cannot be a lens's over the image (None if it can): the distortion
    must be undone at every border pixel, must not fold the image (the Jacobian's determinant
    stays positive from the centre to the border) and moves no border pixel by more than
    MAX_DISTORTION of its distance from the principal point."""
    w, h = model.width, model.height
    u, v = np.linspace(-0.5, w - 0.5, n), np.linspace(-0.5, h - 0.5, n)
    border = np.concatenate([np.c_[u, np.full(n, -0.5)], np.c_[u, np.full(n, h - 0.5)],
                             np.c_[np.full(n, -0.5), v], np.c_[np.full(n, w - 0.5), v]])
    xy_d = model.unapply_K(border)
    with np.errstate(all="ignore"):
        xy = undistort_normalized(xy_d, model.dist)
    if not np.all(np.isfinite(xy)):
        return "the distortion cannot be undone at the image border (coefficients beyond any lens)"
    r = np.linalg.norm(xy, axis=1)
    keep = r > 1e-9
    moved = np.linalg.norm(xy_d - xy, axis=1)
    if np.any(moved[keep] > MAX_DISTORTION * r[keep]):
        worst = float(np.max(moved[keep] / r[keep]))
        return (f"the distortion moves the image border by {worst:.0%} of its distance from the centre; "
                f"a lens this model describes stays within {MAX_DISTORTION:.0%}")
    field = (np.linspace(0.02, 1.0, 25)[:, None, None] * xy[None]).reshape(-1, 2)
    step = 1e-6
    with np.errstate(all="ignore"):
        dx, dy = ((distort_normalized(field + h, model.dist) - distort_normalized(field - h, model.dist)) / (2 * step)
                  for h in ([step, 0], [0, step]))
    det = dx[:, 0] * dy[:, 1] - dx[:, 1] * dy[:, 0]
    if not np.all(det > 0):
        return "the distortion folds the image (two directions would meet in one pixel)"
    return None


def read_std(v, where: str, model: CameraModel) -> dict:
    """{parameter: standard deviation}: fx..k3 one number each, position_m and rotation_deg three;
    each at most std_limits(model)'s."""
    mapping(v, where)
    keys(v, where, (), (*STD_SCALARS, *STD_VECTORS))
    limits = std_limits(model)
    out = {}
    for k, x in v.items():
        if k in STD_VECTORS:
            out[k] = [number(s, f"{where}.{k}[{i}]", 0, limits[k]) for i, s in enumerate(
                array(x, f"{where}.{k}", (3,)).tolist())]
        else:
            out[k] = number(x, f"{where}.{k}", 0, limits[k])
    return out


def std_limits(model: CameraModel) -> dict[str, float]:
    """The largest standard deviation each parameter can have: one whose 1-sigma change moves
    the image's corners by the image's size (px), the station's extent (m), half a turn (deg)."""
    size = float(max(model.width, model.height))
    f = float(max(model.K[0, 0], model.K[1, 1]))
    corners = np.array([[-0.5, -0.5], [model.width - 0.5, model.height - 0.5],
                        [-0.5, model.height - 0.5], [model.width - 0.5, -0.5]])
    r = float(np.linalg.norm(model.unapply_K(corners), axis=1).max())  # normalised radius of the farthest corner
    return {"fx": size, "fy": size, "cx": size, "cy": size,
            "k1": size / (f * r**3), "k2": size / (f * r**5), "k3": size / (f * r**7),
            "p1": size / (f * 3 * r**2), "p2": size / (f * 3 * r**2),
            "position_m": MAX_CAMERA_DISTANCE_M, "rotation_deg": 180.0}


# --- a pair -----------------------------------------------------------------------------------
def read_pair(wheel: str, p, models: dict[str, CameraModel]) -> tuple[str, str, np.ndarray | None]:
    """``pairs.<wheel>`` -> (left camera id, right camera id, (30,30) covariance or None). The
    derived values (R, t_m, baseline_m, E, F) are checked against the cameras'."""
    where = f"pairs.{wheel}"
    mapping(p, where)
    keys(p, where, PAIR_REQUIRED, PAIR_OPTIONAL)
    left, right = text(p["left"], f"{where}.left"), text(p["right"], f"{where}.right")
    for side, cam in (("left", left), ("right", right)):
        if cam not in models:
            raise FieldError(f"{where}.{side}", f"names camera {cam!r}, which is not in the file's cameras")
    if left == right:
        raise FieldError(where, f"left and right are both {left!r}; a pair has two cameras")
    pair = StereoPair(wheel, models[left], models[right])
    if pair.baseline_m < MIN_BASELINE_M:
        raise FieldError(where, f"the cameras {left} and {right} are {pair.baseline_m * 1000:.3g} mm apart; "
                         "a pair needs a baseline")
    computed = {"R": pair.R, "t_m": pair.t, "E": pair.E, "F": pair.F}
    for name, shape in PAIR_DERIVED.items():
        if name in p:
            stored = array(p[name], f"{where}.{name}", shape)
            _agree(stored, computed[name], f"{where}.{name}")
    if "baseline_m" in p:
        baseline = number(p["baseline_m"], f"{where}.baseline_m")
        _agree(np.array(baseline), np.array(pair.baseline_m), f"{where}.baseline_m")
    cov = None
    if "covariance" in p:
        cov = read_covariance(p["covariance"], f"{where}.covariance")
        check_covariance_scale(cov, (models[left], models[right]), f"{where}.covariance")
    return left, right, cov


def _agree(stored: np.ndarray, computed: np.ndarray, where: str) -> None:
    if np.abs(stored - computed).max() > DERIVED_TOL * max(1.0, float(np.abs(computed).max())):
        raise FieldError(where, "does not agree with the cameras it is derived from (the file was edited or damaged)")


COVARIANCE_PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "rotation", "rotation", "rotation",
                         "position_m", "position_m", "position_m")  # per camera, in the covariance's order


def check_covariance_scale(cov: np.ndarray, models: tuple[CameraModel, CameraModel], where: str) -> None:
    """Every parameter's standard deviation (the root of its variance) within std_limits of its
    camera; the rotation vector's within half a turn (rad)."""
    std = np.sqrt(np.diag(cov))
    for c, model in enumerate(models):
        limits = std_limits(model) | {"rotation": math.pi}
        for i, name in enumerate(COVARIANCE_PARAMETERS):
            k = c * len(COVARIANCE_PARAMETERS) + i
            if std[k] > limits[name]:
                raise FieldError(where, f"row {k} ({model.name} {name}) gives a standard deviation of {std[k]:.3g}, "
                                 f"beyond {limits[name]:.3g}")


def read_covariance(v, where: str) -> np.ndarray:
    """A symmetric positive semi-definite (30,30) matrix of finite numbers."""
    n = COVARIANCE_SIZE
    if not (isinstance(v, list) and len(v) == n and all(isinstance(row, list) and len(row) == n for row in v)):
        raise FieldError(where, f"must be a symmetric {n}x{n} matrix of finite numbers")
    cov = array(v, where, (n, n))
    scale = float(np.abs(cov).max())
    if np.abs(cov - cov.T).max() > 1e-9 * max(scale, 1e-300):
        raise FieldError(where, f"must be a symmetric {n}x{n} matrix of finite numbers")
    if np.linalg.eigvalsh(cov).min() < -1e-9 * scale:
        raise FieldError(where, "is not positive semi-definite (a variance cannot be negative)")
    return cov
