"""A station calibration from OpenCV files: cameras (OpenCV's calibration sample, or the station's
own export) and stereo pairs (OpenCV's stereo_calib / ``stereoCalibrate``), placed in the station
frame by what the user says (docs/calibration.md, "Import and export").

Every imported camera's intrinsics come from exactly one file, and its pose in the station frame
(``x_cam = R_cam_station x_station + t_cam_station``) from exactly one of:

* its own file's ``R`` (or ``rvec``) and ``T`` (the station's export writes them);
* a pose file (``poses``: an OpenCV file with ``R`` or ``rvec``, and ``T``);
* the current calibration (``anchors``: the camera has not moved since);
* a pair file's ``R, T`` (``x_b = R x_a + T``) from its partner's pose.

Cameras the files leave out are kept from the current calibration. An import has no
bundle-adjustment covariance, so a calibration that keeps some cameras keeps none (the file holds
all pairs' covariances or none).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration import calib_checks as checks
from calibration.calib_file import CameraCalibration, StationCalibration
from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError, CalibrationMismatch
from calibration.opencv_files import Keys

METHOD = "imported from OpenCV files"
PAIR_KEYS = ("M1", "D1", "M2", "D2")
POSE_HINT = ("place it in the station frame: --anchor CAM (its pose in the current calibration), --pose CAM=FILE "
             "(a file with R or rvec, and T, of x_cam = R x_station + T), or the camera's own file with R and T")


@dataclass
class Source:
    """Files read together as one camera or one pair. target: a camera id, a wheel, ``camA,camB``
    (a pair in its file's camera 1, camera 2 order), or None (the file names it: camera_id, wheel)."""

    target: str | None
    paths: list[Path]


@dataclass
class Layout:
    """The station the calibration is for: camera id -> configured (width, height) or None (take
    the file's), and wheel -> (precision, reference) camera ids."""

    sizes: dict[str, tuple[int, int] | None]
    pairs: dict[str, tuple[str, str]]


@dataclass
class Imported:
    calibration: StationCalibration
    intrinsics_from: dict[str, str]                        # camera -> the file (and key) of its K and dist
    pose_from: dict[str, str]                              # camera -> what placed it in the station frame
    kept: list[str] = field(default_factory=list)          # cameras kept from the current calibration
    covariance_dropped: bool = False


@dataclass
class _Intrinsics:
    cam: str
    where: str          # "FILE: KEY" of its camera matrix
    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int]


@dataclass
class _Link:
    """A pair file's relative pose: x_b = R x_a + t (metres)."""

    a: str
    b: str
    R: np.ndarray
    t: np.ndarray
    where: str


def import_calibration(sources: list[Source], layout: Layout, *, poses: dict[str, Path] | None = None,
                       anchors=(), current: StationCalibration | None = None, unit_m: float = 1.0,
                       station_name: str = "") -> Imported:
    """The station calibration the files describe (module docstring); CalibrationError naming the
    file and key of whatever is missing or wrong, and what to do."""
    intrinsics: dict[str, _Intrinsics] = {}
    placed: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}  # camera -> (R, t_m, what placed it)
    links: list[_Link] = []

    def place(cam, R, t, what):
        if cam in placed:
            raise CalibrationError(f"{what} places camera {cam} in the station frame, and so does {placed[cam][2]}",
                                   hint="give each camera's pose once")
        placed[cam] = (R, t, what)

    for src in sources:
        keys = Keys.read(src.paths)
        if "camera_matrix" in keys and any(k in keys for k in PAIR_KEYS):
            raise CalibrationError(f"{keys.source}: has both camera_matrix (one camera's) and M1 D1 M2 D2 (a pair's)",
                                   hint="give a camera's file and a pair's file separately")
        if "camera_matrix" in keys:
            intr, pose = _read_camera(keys, src.target, layout, unit_m)
            _add(intrinsics, intr)
            if pose is not None:
                place(intr.cam, *pose)
        elif any(k in keys for k in PAIR_KEYS):
            a, b, link = _read_pair(keys, src.target, layout, unit_m)
            _add(intrinsics, a)
            _add(intrinsics, b)
            links.append(link)
        else:
            raise CalibrationError(f"{keys.source}: neither camera_matrix (a camera's file, as OpenCV's calibration "
                                   "sample writes) nor M1 D1 M2 D2 (a stereo pair's, as OpenCV's stereo_calib writes)",
                                   hint="with OpenCV's stereo_calib, give intrinsics.yml and extrinsics.yml together: "
                                   "FL=intrinsics.yml FL=extrinsics.yml")
    for cam, path in (poses or {}).items():
        _known(cam, layout, f"--pose {cam}={path}")
        keys = Keys.read([path])
        todo = "a pose file holds R (3x3) or rvec (3x1), and T (3x1): x_cam = R x_station + T"
        R = keys.rotation(f"camera {cam}'s rotation in the station frame", todo)
        t = keys.matrix("T", (3, 1), f"camera {cam}'s translation in the station frame", todo).ravel() * unit_m
        place(cam, *_pose(R, t, keys, cam), f"{path} (--pose)")
    for cam in anchors:
        _known(cam, layout, f"--anchor {cam}")
        if current is None or cam not in current.cameras:
            raise CalibrationError(f"--anchor {cam}: there is no current calibration of camera {cam} to take its "
                                   "pose from",
                                   hint="run `station calibrate`, or give its pose with --pose CAM=FILE")
        m = current.model(cam)
        place(cam, m.R_cam_station, m.t_cam_station, "the current calibration (--anchor)")
    given = [*((c, f"--pose {c}={p}") for c, p in (poses or {}).items()), *((c, f"--anchor {c}") for c in anchors)]
    for cam, what in given:
        if cam not in intrinsics:
            raise CalibrationError(f"{what}: no file gives camera {cam}'s intrinsics, so nothing of it is imported",
                                   hint=f"give {cam}'s file (or its pair's), or leave out {what.split('=')[0]}")
    _follow_links(links, placed)

    cameras, kept = {}, []
    for cam in layout.sizes:
        if cam in intrinsics:
            cameras[cam] = CameraCalibration(_model(intrinsics[cam], placed))
        elif current is not None and cam in current.cameras:
            cameras[cam] = current.cameras[cam]
            kept.append(cam)
    missing = [c for c in layout.sizes if c not in cameras]
    if missing:
        raise CalibrationError(f"camera(s) {', '.join(missing)}: in none of the files"
                               + ("" if current is None else " and not in the current calibration"),
                               hint="import every camera, or import into a station that has a calibration")
    for link in links:
        baseline = float(np.linalg.norm(cameras[link.a].model.center_station - cameras[link.b].model.center_station))
        if baseline < checks.MIN_BASELINE_M:
            raise CalibrationError(f"{link.where}: puts cameras {link.a} and {link.b} {baseline * 1000:.3g} mm apart; "
                                   "a pair needs a baseline")
    notes = {"imported": {c: i.where for c, i in intrinsics.items()},
             "poses": {c: p[2] for c, p in placed.items() if c in intrinsics}}
    if kept:
        notes["kept_from_calibration_id"] = current.calibration_id
    calib = StationCalibration(cameras, {w: p for w, p in layout.pairs.items()}, station_name=station_name,
                               method=METHOD, notes=notes)
    dropped = bool(kept and current.pair_covariance)
    return Imported(calib, {c: i.where for c, i in intrinsics.items()},
                    {c: placed[c][2] for c in intrinsics}, kept, dropped)


def import_opencv(paths: dict[str, str | Path], pairs: dict | None = None, station_name: str = "",
                  unit_m: float = 1.0) -> StationCalibration:
    """Per-camera files {cam_id: path} that each hold the camera's pose (R or rvec, and T, as
    :func:`calibration.opencv_files.export_opencv` writes) -> a calibration of those cameras."""
    layout = Layout({cam: None for cam in paths}, dict(pairs or {}))
    return import_calibration([Source(cam, [Path(p)]) for cam, p in paths.items()], layout, unit_m=unit_m,
                              station_name=station_name).calibration


# --- one file (or files read as one) ----------------------------------------------------------
def _read_camera(keys: Keys, target, layout: Layout, unit_m: float):
    """(intrinsics, pose or None) of a camera file."""
    if "fisheye_model" in keys and keys.number("fisheye_model", "1 for OpenCV's fisheye model") != 0:
        raise CalibrationError(f"{keys.where('fisheye_model')}: the file holds OpenCV's fisheye model, which is not "
                               "this station's camera model", hint="calibrate the camera with the pinhole model")
    named = keys.text("camera_id")
    cam = target or named
    if cam is None:
        raise CalibrationError(f"{keys.source}: which camera the file describes is not known (no camera_id key)",
                               hint=f"name the camera before the file: cam3={keys.files[0]}")
    if cam in layout.pairs:
        raise CalibrationError(f"{keys.source}: {cam} names a pair, but the file holds one camera (camera_matrix)",
                               hint=f"name the camera: {'/'.join(layout.pairs[cam])}=FILE")
    _known(cam, layout, keys.source)
    if target and named and named != target:
        raise CalibrationError(f"{keys.where('camera_id')}: the file is camera {named}'s, given as {target}'s",
                               hint="check which file belongs to which camera")
    intr = _intrinsics(keys, cam, "camera_matrix", "distortion_coefficients", layout)
    if not any(k in keys for k in ("R", "rvec", "T")):
        return intr, None
    todo = "R (or rvec) and T are the camera's pose in the station frame: x_cam = R x_station + T; give both"
    R = keys.rotation(f"camera {cam}'s rotation in the station frame", todo)
    t = keys.matrix("T", (3, 1), f"camera {cam}'s translation in the station frame", todo).ravel() * unit_m
    return intr, (*_pose(R, t, keys, cam), f"{keys.source} (R, T)")


def _read_pair(keys: Keys, target, layout: Layout, unit_m: float):
    """(camera 1's intrinsics, camera 2's, their link) of a stereo pair's file(s)."""
    a, b = _pair_cameras(keys, target, layout)
    one = _intrinsics(keys, a, "M1", "D1", layout)
    two = _intrinsics(keys, b, "M2", "D2", layout)
    todo = ("OpenCV's stereo_calib writes R and T into extrinsics.yml: give it with the intrinsics, "
            f"{target or 'FL'}=intrinsics.yml {target or 'FL'}=extrinsics.yml")
    R = keys.matrix("R", (3, 3), f"camera 2 ({b}) relative to camera 1 ({a}): x_2 = R x_1 + T", todo)
    t = keys.matrix("T", (3, 1), f"camera 2 ({b}) relative to camera 1 ({a}), in the file's length unit", todo)
    if abs(np.linalg.det(R) - 1) > checks.ROTATION_TOL or np.abs(R @ R.T - np.eye(3)).max() > checks.ROTATION_TOL:
        raise CalibrationError(f"{keys.where('R')}: is not a rotation (R R^T must be I and det R = 1)")
    t = t.ravel() * unit_m
    if np.linalg.norm(t) > checks.MAX_CAMERA_DISTANCE_M:
        raise CalibrationError(f"{keys.where('T')}: puts {b} {np.linalg.norm(t):.3g} m from {a}",
                               hint=_unit_hint(np.linalg.norm(t) / unit_m))
    return one, two, _Link(a, b, R, t, f"{keys.source} (R, T)")


def _pair_cameras(keys: Keys, target, layout: Layout) -> tuple[str, str]:
    """(camera 1, camera 2) of a pair's file: a wheel (its precision camera first), ``camA,camB``,
    or the file's own wheel / camera_1, camera_2 keys."""
    named = (keys.text("camera_1"), keys.text("camera_2"))
    name = target or keys.text("wheel")
    if name is None and None not in named:
        name = ",".join(named)
    if name is None:
        raise CalibrationError(f"{keys.source}: which pair the file describes is not known (no wheel key)",
                               hint=f"name the pair before the file: FL={keys.files[0]} (camera 1 = its precision "
                               "camera), or its cameras in the file's order: cam3,cam4=FILE")
    if name in layout.pairs:
        cams = layout.pairs[name]
    else:
        cams = tuple(name.split(","))
        if len(cams) != 2 or not any(set(cams) == set(p) for p in layout.pairs.values()):
            known = ", ".join(f"{w} ({l},{r})" for w, (l, r) in layout.pairs.items()) or "none"
            raise CalibrationError(f"{keys.source}: {name!r} is not one of the station's pairs: {known}",
                                   hint="name a pair, or its two cameras in the file's order: cam3,cam4=FILE")
    if None not in named and tuple(named) != tuple(cams):
        raise CalibrationError(f"{keys.source}: camera_1, camera_2 are {named[0]}, {named[1]}, but the file is given "
                               f"as {cams[0]}, {cams[1]}", hint="check which cameras the pair's file is for")
    return cams[0], cams[1]


def _intrinsics(keys: Keys, cam: str, k_key: str, d_key: str, layout: Layout) -> _Intrinsics:
    K = keys.matrix(k_key, (3, 3), f"camera {cam}'s camera matrix")
    dist = keys.distortion(d_key)
    size, configured = keys.size(), layout.sizes.get(cam)
    if size and configured and size != configured:
        raise CalibrationMismatch(f"{keys.source}: image_width x image_height = {size[0]}x{size[1]}, but camera {cam} "
                                  f"is configured for {configured[0]}x{configured[1]}",
                                  hint="a calibration holds for the resolution it was made at")
    size = configured or size
    if size is None:
        raise CalibrationError(f"{keys.source}: no image_width and image_height, and camera {cam} has no configured "
                               "size", hint="add image_width and image_height to the file")
    where = f"{keys.where(k_key)} ({cam})"
    try:
        checks.check_intrinsics(where, *size, K)
        problem = checks.distortion_problem(CameraModel(cam, *size, K, dist))
    except checks.FieldError as e:
        raise CalibrationError(f"{where}: {e}", hint="check the file's camera matrix") from None
    if problem:
        raise CalibrationError(f"{keys.where(d_key)} ({cam}): {problem}", hint="check the file's distortion")
    return _Intrinsics(cam, keys.where(k_key), K, dist, size)


def _pose(R: np.ndarray, t: np.ndarray, keys: Keys, cam: str) -> tuple[np.ndarray, np.ndarray]:
    where = keys.where("R" if "R" in keys else "rvec")
    if abs(np.linalg.det(R) - 1) > checks.ROTATION_TOL or np.abs(R @ R.T - np.eye(3)).max() > checks.ROTATION_TOL:
        raise CalibrationError(f"{where} ({cam}): is not a rotation (R R^T must be I and det R = 1)")
    distance = float(np.linalg.norm(t))
    if distance > checks.MAX_CAMERA_DISTANCE_M:
        raise CalibrationError(f"{keys.where('T')} ({cam}): puts the camera {distance:.3g} m from the station origin; "
                               f"a station camera stands within {checks.MAX_CAMERA_DISTANCE_M:g} m",
                               hint=_unit_hint(distance))
    return R, t


def _unit_hint(length_m: float) -> str:
    mm = 1e-3 * length_m
    return (f"if T is in millimetres, give --unit mm ({mm:.3g} m)" if mm < checks.MAX_CAMERA_DISTANCE_M
            else "give T in metres, or name its unit with --unit")


def _known(cam: str, layout: Layout, where: str) -> None:
    if cam not in layout.sizes:
        raise CalibrationError(f"{where}: {cam!r} is not one of the station's cameras ({', '.join(layout.sizes)})",
                               hint="name a configured camera (station cameras lists them)")


def _add(intrinsics: dict[str, _Intrinsics], intr: _Intrinsics) -> None:
    if intr.cam in intrinsics:
        raise CalibrationError(f"camera {intr.cam} is in {intrinsics[intr.cam].where} and in {intr.where}",
                               hint="give each camera's intrinsics once")
    intrinsics[intr.cam] = intr


# --- the station frame --------------------------------------------------------------------------
def _follow_links(links: list[_Link], placed: dict) -> None:
    """Place the cameras the pair files tie to a placed partner, until nothing changes; a pair
    whose cameras are both placed otherwise is refused (two poses for one camera)."""
    todo = list(links)
    while todo:
        progress = False
        for link in list(todo):
            a, b = link.a in placed, link.b in placed
            if a and b:
                raise CalibrationError(f"{link.where}: places {link.b} relative to {link.a}, but both are already "
                                       f"placed: {link.a} by {placed[link.a][2]}, {link.b} by {placed[link.b][2]}",
                                       hint=f"place only one of {link.a}, {link.b}; the pair's R and T place the other")
            if a:
                R_a, t_a, _ = placed[link.a]
                placed[link.b] = (link.R @ R_a, link.R @ t_a + link.t, f"{link.where} from {link.a}")
            elif b:
                R_b, t_b, _ = placed[link.b]
                placed[link.a] = (link.R.T @ R_b, link.R.T @ (t_b - link.t), f"{link.where} from {link.b}")
            else:
                continue
            todo.remove(link)
            progress = True
        if not progress:
            link = todo[0]
            raise CalibrationError(f"{link.where}: R and T place {link.b} relative to {link.a}, but nothing places "
                                   "either in the station frame",
                                   hint=f"for {link.a}: {POSE_HINT.replace('CAM', link.a)}")


def _model(intr: _Intrinsics, placed: dict) -> CameraModel:
    if intr.cam not in placed:
        raise CalibrationError(f"{intr.where}: camera {intr.cam} has no pose in the station frame (no R and T in its "
                               "file)", hint=POSE_HINT.replace("CAM", intr.cam))
    R, t, _ = placed[intr.cam]
    try:
        return CameraModel(intr.cam, *intr.size, intr.K, intr.dist, R, t)
    except ValueError as e:  # the checks above make this unreachable for a file's values
        raise CalibrationError(f"{intr.where}: {e}") from None

