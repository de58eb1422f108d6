"""The station calibration file (JSON, versioned; docs/calibration-format.md). OpenCV's files:
calibration/opencv_files.py (reading, writing, export) and calibration/opencv_import.py.

Saving is atomic (write a temporary file beside the target, fsync, rename): a crash or a failed
run never leaves a half-written file, and a good file is replaced only by a validated one.
Loading checks every field (calibration/calib_checks.py) and the cameras and pairs against the
station configuration, and raises :class:`CalibrationError` naming the file and the field. The
calibration id is a checksum of the content, so an edited file has another id.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

import numpy as np

from calibration import calib_checks as checks
from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError, CalibrationMismatch
from calibration.stereo import StereoPair

FORMAT = "wheel-alignment-station/calibration"
FORMAT_VERSION = 1


def software_version() -> str:
    try:
        return metadata.version("wheel-alignment-station")
    except metadata.PackageNotFoundError:
        return "unknown"


@dataclass
class CameraCalibration:
    """One camera: the model plus how well it is known.

    std: parameter standard deviations {"fx": px, ..., "k3": -, "position_m": [3],
    "rotation_deg": [3]}. reprojection_rms_px, n_points: from the refinement.
    """

    model: CameraModel
    reprojection_rms_px: float = float("nan")
    n_points: int = 0
    std: dict = field(default_factory=dict)


@dataclass
class StationCalibration:
    cameras: dict[str, CameraCalibration]
    pairs: dict[str, tuple[str, str]] = field(default_factory=dict)  # wheel -> (left, right)
    station_name: str = ""
    created_utc: str = field(default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec="seconds"))
    software_version: str = field(default_factory=software_version)
    method: str = "box: paper eqs 4-22 + bundle adjustment"
    notes: dict = field(default_factory=dict)
    # wheel -> (30,30) joint covariance of the pair's two cameras from the bundle adjustment,
    # per camera [fx fy cx cy k1 k2 p1 p2 k3, rvec (3, rad), centre (3, m)], left then right
    pair_covariance: dict = field(default_factory=dict)

    def model(self, cam_id: str) -> CameraModel:
        return self.cameras[cam_id].model

    def pair(self, wheel: str) -> StereoPair:
        left, right = self.pairs[wheel]
        return StereoPair(wheel, self.model(left), self.model(right))

    @property
    def calibration_id(self) -> str:
        """12 hex digits: the checksum of the document this calibration writes (content_id)."""
        return content_id(self._document())

    # --- JSON ---------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        doc = self._document()
        return {"format": FORMAT, "format_version": FORMAT_VERSION, "calibration_id": content_id(doc), **doc}

    def _document(self) -> dict:
        """The file's content without its calibration id."""
        cams = {}
        for cam_id, c in self.cameras.items():
            d = c.model.to_dict()
            d.pop("name")
            d["center_station_m"] = c.model.center_station.tolist()
            d["reprojection_rms_px"] = _num(c.reprojection_rms_px)
            d["n_points"] = int(c.n_points)
            d["std"] = {k: (list(map(float, v)) if isinstance(v, (list, tuple, np.ndarray)) else float(v))
                        for k, v in c.std.items()}
            cams[cam_id] = d
        pairs = {}
        for wheel, (left, right) in self.pairs.items():
            missing = [c for c in (left, right) if c not in self.cameras]
            if missing:
                raise CalibrationError(f"pair {wheel} names camera {missing[0]}, which has no calibration")
            p = self.pair(wheel)
            pairs[wheel] = {"left": left, "right": right, "R": p.R.tolist(), "t_m": p.t.tolist(),
                            "baseline_m": p.baseline_m, "E": p.E.tolist(), "F": p.F.tolist()}
            if wheel in self.pair_covariance:
                pairs[wheel]["covariance"] = np.asarray(self.pair_covariance[wheel], float).tolist()
        return {"format": FORMAT, "format_version": FORMAT_VERSION,
                "created_utc": self.created_utc, "software_version": self.software_version,
                "station_name": self.station_name, "method": self.method,
                "camera_ids": list(self.cameras), "cameras": cams, "pairs": pairs, "notes": self.notes}

    @classmethod
    def from_dict(cls, d: dict, source: str = "calibration") -> "StationCalibration":
        """The calibration in the parsed JSON ``d``, every field checked (calibration/calib_checks.py);
        CalibrationError naming ``source`` and the field otherwise."""
        def bad(msg):
            return CalibrationError(f"{source}: {msg}", hint="recalibrate with `station calibrate` or fix the file")
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise bad(f"not a station calibration file (format must be {FORMAT!r})")
        version = d.get("format_version")
        if type(version) is not int or version != FORMAT_VERSION:  # true and 1.0 equal 1 in Python
            raise bad(f"format_version {version!r} is not supported (this software reads {FORMAT_VERSION})")
        try:
            return cls._read(d)
        except checks.FieldError as e:
            raise bad(f"{e.where}: {e}") from None

    @classmethod
    def _read(cls, d: dict) -> "StationCalibration":
        doc = checks.read_document(d)
        cams = {cam_id: CameraCalibration(*parts) for cam_id, parts in doc.cameras.items()}
        return cls(cams, doc.pairs, station_name=doc.header["station_name"], created_utc=doc.header["created_utc"],
                   software_version=doc.header["software_version"], method=doc.header["method"], notes=doc.notes,
                   pair_covariance=doc.covariance)

    def check_against_config(self, config, source: str = "calibration") -> None:
        """The file must describe exactly the configured cameras (at their resolution) and pairs."""
        want = set(config.cameras)
        have = set(self.cameras)
        if want - have:
            raise CalibrationMismatch(f"{source}: no calibration for camera(s) {', '.join(sorted(want - have))}",
                                      hint="run `station calibrate` for this station")
        if have - want:
            raise CalibrationMismatch(f"{source}: calibrates camera(s) {', '.join(sorted(have - want))} that the "
                                      "station configuration does not have", hint="use the calibration made for this station")
        for cam_id, cam in config.cameras.items():
            m = self.model(cam_id)
            if (m.width, m.height) != (cam.width, cam.height):
                raise CalibrationMismatch(f"{source}: camera {cam_id} was calibrated at {m.width}x{m.height} but is "
                                          f"configured for {cam.width}x{cam.height}")
        unknown = sorted(set(self.pairs) - set(config.pairs))
        if unknown:
            raise CalibrationMismatch(f"{source}: pairs: {', '.join(map(repr, unknown))} is not a configured pair "
                                      f"({', '.join(config.pairs)})", hint="use the calibration made for this station")
        for wheel, pc in config.pairs.items():
            if wheel not in self.pairs:
                raise CalibrationMismatch(f"{source}: pairs: no pair {wheel} ({pc.precision}, {pc.reference}); the "
                                          "stereo calibration of every configured pair is needed",
                                          hint="run `station calibrate` for this station")
            if self.pairs[wheel] != (pc.precision, pc.reference):
                raise CalibrationMismatch(f"{source}: pair {wheel} is {self.pairs[wheel]} in the file but "
                                          f"({pc.precision}, {pc.reference}) in the configuration")


def content_id(document: dict) -> str:
    """The calibration id of a calibration document: the first 12 hex digits of the SHA-256 of
    the document without its ``calibration_id``, as JSON with sorted keys and no spaces."""
    content = {k: v for k, v in document.items() if k != "calibration_id"}
    text = json.dumps(content, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _num(x: float):
    return None if x is None or not math.isfinite(x) else float(x)


def save_calibration(calib: StationCalibration, path: str | os.PathLike) -> Path:
    """Validate, then write atomically (temp file + fsync + rename). Returns the path."""
    path = Path(path)
    d = calib.to_dict()
    StationCalibration.from_dict(json.loads(json.dumps(d)), str(path))  # validates what we write
    text = json.dumps(d, indent=2, allow_nan=False)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(text + "\n")
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as e:
        raise CalibrationError(f"{path}: cannot write the calibration ({e.strerror or e})") from None
    return path


def load_calibration(path: str | os.PathLike, config=None) -> StationCalibration:
    """Read and validate a calibration file (and check it against ``config`` if given)."""
    path = Path(path)
    hint = "recalibrate with `station calibrate` or restore the file"
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise CalibrationError(f"{path}: calibration file not found", hint="run `station calibrate`") from None
    except OSError as e:
        raise CalibrationError(f"{path}: cannot read the calibration ({e.strerror or e})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise CalibrationError(f"{path}: not a calibration file: byte {e.start} is not UTF-8 text "
                               "(a binary or damaged file)", hint=hint) from None
    if not text.strip():
        raise CalibrationError(f"{path}: the calibration file is empty", hint=hint)
    try:
        d = json.loads(text, parse_constant=lambda c: float("nan"))
    except json.JSONDecodeError as e:
        raise CalibrationError(f"{path}: not valid JSON at line {e.lineno}, column {e.colno}: {e.msg} "
                               "(a truncated or damaged file)", hint=hint) from None
    except (ValueError, RecursionError) as e:  # a number of thousands of digits, nesting beyond any file's
        raise CalibrationError(f"{path}: not a calibration file ({type(e).__name__}: {str(e)[:80]})",
                               hint=hint) from None
    calib = StationCalibration.from_dict(d, str(path))
    if config is not None:
        calib.check_against_config(config, str(path))
    return calib
