"""Load and validate the station configuration (config/station.yaml) once, at start-up.

Every problem becomes one :class:`ConfigError` naming the file, the key and what was expected.
The schema below is the single source of truth for the keys; docs/configuration.md explains
them. The loaded configuration is a tree of plain attributes (:class:`Section`).
"""

from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import yaml

from calibration.station_frame import WHEELS
from station.errors import ConfigError


if TYPE_CHECKING:
    from calibration.box_target import BoxTarget

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "config" / "station.yaml"
URI_SCHEMES = ("sim", "replay", "aravis", "v4l2")


# --- a small declarative schema -------------------------------------------------------------
@dataclass(frozen=True)
class Field:
    check: Callable[[Any, str], Any]  # (value, key) -> converted value, raises _Bad
    default: Any = ...  # ... = required
    doc: str = ""


class _Bad(Exception):
    pass


def _number(lo=-math.inf, hi=math.inf, integer=False):
    def check(v, key):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not isinstance(v, int)):
            raise _Bad(f"expected {'an integer' if integer else 'a number'}, got {v!r}"[:200])
        try:
            x = float(v)  # an integer of hundreds of digits is beyond any float
        except OverflowError:
            x = math.inf
        if not math.isfinite(x) or not lo <= v <= hi:
            raise _Bad(f"expected a value in [{lo}, {hi}], got {v if x == v else f'{x:g}'}")
        return int(v) if integer else x
    return check


def _string(choices=None, nullable=False):
    def check(v, key):
        if v is None and nullable:
            return None
        if not isinstance(v, str) or not v:
            raise _Bad(f"expected a non-empty string, got {v!r}")
        if choices and v not in choices:
            raise _Bad(f"expected one of {', '.join(choices)}, got {v!r}")
        return v
    return check


def _bool(v, key):
    if not isinstance(v, bool):
        raise _Bad(f"expected true or false, got {v!r}")
    return v


def _vector(n, positive=False, integer=False, lo=-math.inf, hi=math.inf):
    """A list of ``n`` numbers in [lo, hi]; ``positive``: each at least 1 (pixel counts)."""
    def check(v, key):
        if not isinstance(v, (list, tuple)) or len(v) != n:
            raise _Bad(f"expected a list of {n} numbers, got {v!r}"[:200])
        out = [_number(lo=1 if positive else lo, hi=hi, integer=integer)(x, key) for x in v]
        return tuple(out)
    return check


def _string_list(v, key):
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise _Bad(f"expected a list of strings, got {v!r}")
    return tuple(v)


def _exposure_steps(v, key):
    """Factors of the configured exposure, each in (0, 1), falling: [] turns the re-take off."""
    if not isinstance(v, (list, tuple)) or len(v) > 4:
        raise _Bad(f"expected a list of up to 4 exposure factors such as [0.5, 0.25], got {v!r}"[:200])
    out = tuple(_number(lo=0.01, hi=0.99)(x, key) for x in v)
    if any(b >= a for a, b in zip(out, out[1:])):
        raise _Bad(f"expected falling factors such as [0.5, 0.25], got {list(out)}")
    return out


def _history_url(v, key):
    """null, or a PostgreSQL URL with a host and a database (its password never repeated in errors)."""
    if v is None:
        return None
    from urllib.parse import urlsplit
    if not isinstance(v, str) or not v.startswith(("postgresql://", "postgres://")):
        raise _Bad("expected null (SQLite in data_dir) or postgresql://user:password@host:port/database")
    try:
        parts = urlsplit(v)
        parts.port  # noqa: B018 - raises ValueError for a port that is not a number
    except ValueError as e:
        raise _Bad(f"not a usable PostgreSQL URL ({e})") from None
    if not parts.hostname or not parts.path.strip("/"):
        raise _Bad("expected postgresql://user:password@host:port/database (a host and a database)")
    return v


def _password_hashes(v, key):
    """{user: hex SHA-256 of the password}: who may log in to the OPC UA server."""
    if not isinstance(v, dict):
        raise _Bad(f"expected a mapping of user: sha256 hex of the password, got {type(v).__name__}")
    for user, digest in v.items():
        if not isinstance(user, str) or not user or not isinstance(digest, str) \
                or len(digest) != 64 or any(ch not in "0123456789abcdef" for ch in digest.lower()):
            raise _Bad(f"user {user!r}: expected the password's SHA-256 as 64 hex digits "
                       "(python -c \"import hashlib;print(hashlib.sha256(b'PASSWORD').hexdigest())\")")
    return {u: d.lower() for u, d in v.items()}


def _section(schema: dict[str, Field]):
    def check(v, key):
        return _validate(v, schema, key)
    return check


def _mapping_of(schema: dict[str, Field], keys: tuple[str, ...] | None = None):
    def check(v, key):
        if not isinstance(v, dict):
            raise _Bad(f"expected a mapping, got {type(v).__name__}")
        if keys is not None:
            missing = [k for k in keys if k not in v]
            extra = [k for k in v if k not in keys]
            if extra:
                raise _Bad(f"unknown entry {extra[0]!r}; expected exactly {', '.join(keys)}")
            if missing:
                raise _Bad(f"missing entry {missing[0]!r}; expected exactly {', '.join(keys)}")
        return {str(k): _validate(item, schema, f"{key}.{k}") for k, item in v.items()}
    return check


class Section:
    """A validated mapping with attribute access; ``_key`` is its dotted path."""

    def __init__(self, values: dict, key: str):
        self.__dict__.update(values)
        self._key = key

    def __repr__(self):
        items = {k: v for k, v in self.__dict__.items() if not k.startswith("_")}
        return f"Section({self._key or '<root>'}: {items})"

    def as_dict(self) -> dict:
        def plain(v):
            if isinstance(v, Section):
                return v.as_dict()
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            if isinstance(v, tuple):
                return list(v)
            return v
        return {k: plain(v) for k, v in self.__dict__.items() if not k.startswith("_")}


def _validate(values, schema: dict[str, Field], key: str) -> Section:
    if values is None:
        values = {}
    if not isinstance(values, dict):
        where = "" if key else f"the file's top level must be a mapping of keys ({', '.join(list(schema)[:3])}, ...); "
        raise _BadAt(key, f"{where}expected a mapping, got {type(values).__name__}")
    out = {}
    for k in values:
        if k not in schema:
            close = difflib.get_close_matches(str(k), schema.keys(), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else f"; known keys: {', '.join(schema)}"
            raise _BadAt(_join(key, k), f"unknown key{hint}")
    for k, field in schema.items():
        sub = _join(key, k)
        if k in values:
            try:
                out[k] = field.check(values[k], sub)
            except _Bad as e:
                raise _BadAt(sub, str(e)) from None
        elif field.default is ...:
            raise _BadAt(sub, f"missing required key ({field.doc or 'see docs/configuration.md'})")
        else:
            out[k] = field.check(field.default, sub) if field.default is not None else None
    return Section(out, key)


class _BadAt(Exception):
    def __init__(self, key, message):
        super().__init__(message)
        self.key = key


def _at(e: _BadAt) -> str:
    """A validation error's message, after its key where it has one (not at the file's top level)."""
    return f"{e.key}: {e}" if e.key else str(e)


def _join(a, b):
    return f"{a}.{b}" if a else str(b)


# --- the schema -----------------------------------------------------------------------------
STATION_EXTENT_M = 100.0  # every position in the station frame lies within this of its origin
_POSITION = _vector(3, lo=-STATION_EXTENT_M, hi=STATION_EXTENT_M)
NOMINAL = {
    "position_m": Field(_POSITION, doc="camera position in the station frame (m)"),
    "look_at_m": Field(_POSITION, doc="point the optical axis aims at (m)"),
    "focal_px": Field(_number(100, 1e5), doc="nominal focal length (px)"),
}
CAMERA = {
    "wheel": Field(_string(WHEELS)),
    "role": Field(_string(("precision", "reference"))),
    "uri": Field(_string()),
    "resolution": Field(_vector(2, positive=True, integer=True), default=None),
    "pixel_format": Field(_string(("Mono8", "Mono16", "BayerRG8", "BayerGR8", "BayerBG8", "BayerGB8", "RGB8")), default=None),
    "exposure_us": Field(_number(1, 1e7), default=None),
    "gain_db": Field(_number(0, 48), default=None),
    "trigger": Field(_string(("free-run", "software", "hardware")), default=None),
    "response_gamma": Field(_number(0.2, 5), default=None),
    "nominal": Field(_section(NOMINAL)),
}
CAMERA_DEFAULTS = {
    "resolution": Field(_vector(2, positive=True, integer=True), default=[1280, 1024]),
    "pixel_format": Field(CAMERA["pixel_format"].check, default="Mono8"),
    "exposure_us": Field(_number(1, 1e7), default=8000),
    "gain_db": Field(_number(0, 48), default=0.0),
    "trigger": Field(CAMERA["trigger"].check, default="software"),
    "response_gamma": Field(CAMERA["response_gamma"].check, default=1.0),
}
FIXTURE = {
    "position_m": Field(_POSITION),
    "yaw_deg": Field(_number(-180, 180)),
}
SCHEMA = {
    "version": Field(_number(1, 1, integer=True), doc="format version, 1"),
    "name": Field(_string(), default="station"),
    "data_dir": Field(_string(), default="../var"),
    "vehicle_specs": Field(_string(), default="vehicles.yaml"),
    "cameras": Field(_mapping_of(CAMERA)),
    "camera_defaults": Field(_section(CAMERA_DEFAULTS), default={}),
    "nominal_vehicle": Field(_section({
        "wheelbase_m": Field(_number(1.5, 5.0)),
        "track_m": Field(_number(0.8, 2.5)),
    })),
    "calibration": Field(_section({
        "box": Field(_string(), default="box.yaml"),
        "file": Field(_string(), default="calibration/station.calib.json"),
        "intrinsic_poses": Field(_number(3, 100, integer=True), default=10),
        "fixture": Field(_mapping_of(FIXTURE, keys=WHEELS)),
        "limits": Field(_section({
            "reprojection_rms_px": Field(_number(0.01, 10), default=0.5),
            "focal_std_px": Field(_number(0.001, 100), default=2.0),
            "position_std_m": Field(_number(1e-6, 1), default=0.002),
        }), default={}),
    })),
    "measurement": Field(_section({
        "epipolar_limit_px": Field(_number(0.01, 100), default=0.6),
        "uncertainty_limit_deg": Field(_number(0.001, 10), default=0.06),
        "uncertainty_floor_deg": Field(_number(0, 1), default=0.015),
        "uncertainty_toe_scale": Field(_number(0, 10), default=1.0),
        "uncertainty_light_gain": Field(_number(0, 100), default=0.0),
        "uncertainty_blur_gain": Field(_number(0, 100), default=0.0),
        "view_edge_bias_px": Field(_number(0, 10), default=0.05),
        "edge_blur_limit_px": Field(_number(0.3, 10), default=1.3),
        "min_rim_axis_px": Field(_number(0, 10000), default=180.0),
        "white_edge_limit": Field(_number(0, 1), default=0.25),
        "mismatch_limit_px": Field(_number(0.1, 1000), default=5.0),
        "max_wheel_offset_m": Field(_number(0.01, 5), default=0.5),
        "min_rim_radius_m": Field(_number(0.05, 1), default=0.15),
        "max_rim_radius_m": Field(_number(0.05, 1), default=0.34),
        "min_rim_points": Field(_number(10, 100000, integer=True), default=200),
        "runout_limit_deg": Field(_number(0.01, 10), default=0.4),
    }), default={}),
    "simulation": Field(_section({
        "station_seed": Field(_number(0, 2**31, integer=True), default=7),
        "noise_sigma": Field(_number(0, 50), default=2.0),
        "runout_max_deg": Field(_number(0, 5), default=0.3),
    }), default={}),
    "capture": Field(_section({
        "timeout_s": Field(_number(0.01, 600), default=3.0),
        "keep_captures": Field(_bool, default=True),
        "frames_averaged": Field(_number(1, 64, integer=True), default=1),
        "exposure_steps": Field(_exposure_steps, default=(0.5, 0.25)),  # station/capture/exposure_bracket.py
    }), default={}),
    "trigger_board": Field(_section({
        "port": Field(_string(nullable=True), default=None),
        "baudrate": Field(_number(300, 4_000_000, integer=True), default=115200),
    }), default={}),
    "plc": Field(_section({
        "transport": Field(_string(("tcp", "rtu")), default="tcp"),
        "host": Field(_string(), default="127.0.0.1"),
        "port": Field(_number(1, 65535, integer=True), default=5020),
        "serial_port": Field(_string(nullable=True), default=None),
        "baudrate": Field(_number(300, 1_000_000, integer=True), default=19200),
        "parity": Field(_string(("N", "E", "O")), default="E"),
        "device_id": Field(_number(1, 247, integer=True), default=1),
        "allowed_clients": Field(_string_list, default=[]),  # "ADDRESS[/PREFIX] [read|write]" (station/plc/clients.py)
        "max_connections": Field(_number(1, 1000, integer=True), default=8),
        "idle_timeout_s": Field(_number(0, 86400), default=60.0),  # 0: never close an idle connection
        "roll_timeout_s": Field(_number(1, 3600), default=120.0),  # a roll the PLC does not confirm: fault 415
        "steer_timeout_s": Field(_number(1, 3600), default=120.0),  # a steer target not reached: fault 424
    }), default={}),
    "history": Field(_section({
        "url": Field(_history_url, default=None),  # null: <data_dir>/history.sqlite; postgresql://...: shared
        "connect_timeout_s": Field(_number(0.5, 60), default=3.0),
        "retry_s": Field(_number(0.5, 3600), default=10.0),  # station serve: resend the outbox this often
    }), default={}),
    "opcua": Field(_section({
        "host": Field(_string(), default="127.0.0.1"),
        "port": Field(_number(1, 65535, integer=True), default=4840),
        "users": Field(_password_hashes, default={}),  # {user: sha256 hex of the password}
    }), default={}),
    "ui": Field(_section({  # the technician's screen, `station ui` (docs/ui.md)
        "host": Field(_string(), default="127.0.0.1"),
        "port": Field(_number(1, 65535, integer=True), default=8080),
        "password_hash": Field(_string(nullable=True), default=None),  # station/ui/auth.py; `station ui --hash-password`
        "angle_format": Field(_string(choices=("decimal", "dms")), default="decimal"),  # the pages' default; each browser may switch
    }), default={}),
    "recording": Field(_section({
        "enabled": Field(_bool, default=True),
        "jpeg_quality": Field(_number(10, 100, integer=True), default=90),
    }), default={}),
}


# --- loading --------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraConfig:
    id: str
    wheel: str
    role: str
    uri: str
    width: int
    height: int
    pixel_format: str
    exposure_us: float
    gain_db: float
    trigger: str
    nominal: Section
    response_gamma: float = 1.0  # the camera's grey = light^gamma; undone before detection


@dataclass(frozen=True)
class PairConfig:
    wheel: str
    precision: str  # camera id (the paper's left camera)
    reference: str  # camera id (the paper's right camera)


class StationConfig:
    """The validated station. ``cameras`` in config order; ``pairs`` keyed by wheel."""

    def __init__(self, path: Path, tree: Section):
        self.path = path
        self.tree = tree
        self.name = tree.name
        base = path.parent
        env = os.environ.get("STATION_DATA_DIR")
        self.data_dir = Path(env) if env else (base / tree.data_dir).resolve()
        self.vehicle_specs_path = (base / tree.vehicle_specs).resolve()
        self.box_path = (base / tree.calibration.box).resolve()
        d = tree.camera_defaults
        self.cameras: dict[str, CameraConfig] = {}
        for cam_id, c in tree.cameras.items():
            res = c.resolution or d.resolution
            self.cameras[cam_id] = CameraConfig(
                id=cam_id, wheel=c.wheel, role=c.role, uri=c.uri, width=res[0], height=res[1],
                pixel_format=c.pixel_format or d.pixel_format,
                exposure_us=c.exposure_us or d.exposure_us, gain_db=c.gain_db if c.gain_db is not None else d.gain_db,
                trigger=c.trigger or d.trigger, nominal=c.nominal,
                response_gamma=float(c.response_gamma if c.response_gamma is not None else d.response_gamma))
        self.pairs: dict[str, PairConfig] = {}
        for wheel in WHEELS:
            members = {c.role: c.id for c in self.cameras.values() if c.wheel == wheel}
            self.pairs[wheel] = PairConfig(wheel, members["precision"], members["reference"])

    # Sections as attributes: config.calibration.limits.reprojection_rms_px, config.plc.port, ...
    def __getattr__(self, item):
        if item.startswith("_") or item == "tree":
            raise AttributeError(item)
        return getattr(self.tree, item)

    @property
    def calibration_file(self) -> Path:
        return self.data_dir / self.tree.calibration.file

    def data_path(self, *parts: str) -> Path:
        return self.data_dir.joinpath(*parts)


def read_yaml(path: Path, what: str, hint: str) -> Any:
    """The parsed YAML file ``path``, ``what`` it holds naming it in a ConfigError when it is
    missing (with ``hint``), unreadable or not YAML (with the line and column)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found", hint=hint) from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the {what} ({e.strerror or e})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: the {what} is not text: byte {e.start} is not UTF-8 (a binary or damaged file)",
                          hint="restore the file from a copy; docs/configuration.md describes it") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ConfigError(f"{path}: not valid YAML{where}: {getattr(e, 'problem', None) or e}") from None
    except RecursionError:  # nesting no configuration has
        raise ConfigError(f"{path}: not valid YAML: nested too deeply") from None


def load_config(path: str | os.PathLike | None = None) -> StationConfig:
    """Read, parse and validate the station configuration. Raises ConfigError."""
    path = Path(path) if path else Path(os.environ.get("STATION_CONFIG", DEFAULT_CONFIG))
    raw = read_yaml(path, "configuration file", "pass --config PATH or set STATION_CONFIG")
    try:
        tree = _validate(raw, SCHEMA, "")
    except _BadAt as e:
        raise ConfigError(f"{path}: {_at(e)}", hint="fix that key; docs/configuration.md lists every key") from None
    _check_station(path, tree)
    return StationConfig(path.resolve(), tree)


def _check_station(path: Path, tree: Section) -> None:
    cams = tree.cameras
    if len(cams) != 8:
        raise ConfigError(f"{path}: cameras: the station has four stereo pairs, so exactly 8 cameras; "
                          f"this file names {len(cams)} ({', '.join(cams)})")
    for wheel in WHEELS:
        roles = sorted(c.role for c in cams.values() if c.wheel == wheel)
        if roles != ["precision", "reference"]:
            raise ConfigError(f"{path}: cameras: wheel {wheel} needs one precision and one reference "
                              f"camera, found {roles or 'none'}")
    seen: dict[str, str] = {}
    for cam_id, c in cams.items():
        axis = [b - a for a, b in zip(c.nominal.position_m, c.nominal.look_at_m)]
        if math.hypot(axis[0], axis[1]) < 1e-3 * max(1.0, abs(axis[2])):
            raise ConfigError(f"{path}: cameras.{cam_id}.nominal: look_at_m is "
                              + ("position_m itself" if not any(axis) else "straight above or below position_m")
                              + "; a station camera looks across the runway at a wheel")
        scheme = c.uri.split("://", 1)[0] if "://" in c.uri else ""
        if scheme not in URI_SCHEMES:
            raise ConfigError(f"{path}: cameras.{cam_id}.uri: unknown scheme in {c.uri!r}; expected "
                              + ", ".join(f"{s}://..." for s in URI_SCHEMES))
        if c.uri in seen:
            raise ConfigError(f"{path}: cameras.{cam_id}.uri: {c.uri!r} is already used by {seen[c.uri]}; "
                              "two cameras cannot share an address")
        seen[c.uri] = cam_id


# --- the calibration box's description (config/box.yaml) -------------------------------------
BOX_FACE = {
    "squares": Field(_vector(2, integer=True, lo=2, hi=1000), doc="chessboard squares (columns, rows)"),
    "first_id": Field(_number(0, 100_000, integer=True), doc="the face's first ArUco marker id"),
}
BOX_SCHEMA = {
    "version": Field(_number(1, 1, integer=True), default=1, doc="format version, 1"),
    "size_m": Field(_vector(3, lo=0.01, hi=10), doc="the box's length, width and height (m)"),
    "dictionary": Field(_string(), doc="a cv2.aruco predefined dictionary, e.g. DICT_5X5_1000"),
    "square_m": Field(_number(1e-4, 1), doc="chessboard square side (m)"),
    "marker_m": Field(_number(1e-4, 1), doc="ArUco marker side (m)"),
    "texel_m": Field(_number(1e-5, 0.01), default=0.0005, doc="texture resolution (m)"),
    "faces": Field(_mapping_of(BOX_FACE), doc="face name -> squares and first_id"),
}


def load_box(path: str | os.PathLike) -> BoxTarget:
    """Read config/box.yaml. Raises ConfigError naming the file, the key and the problem."""
    from calibration.box_target import BoxTarget  # OpenCV, loaded only when a box is read

    path = Path(path)
    raw = read_yaml(path, "box description", "calibration.box in station.yaml must name the box file")
    hint = "fix the box file; config/box.yaml describes every key"
    try:
        box = _validate(raw, BOX_SCHEMA, "")
    except _BadAt as e:
        raise ConfigError(f"{path}: {_at(e)}", hint=hint) from None
    faces = {name: {"squares": f.squares, "first_id": f.first_id} for name, f in box.faces.items()}
    try:
        return BoxTarget(box.size_m, box.dictionary, box.square_m, box.marker_m, faces, box.texel_m, source=str(path))
    except (ValueError, TypeError, KeyError) as e:
        raise ConfigError(f"{path}: {e}", hint=hint) from None
