"""Every field of a calibration file is checked on load (calibration/calib_checks.py): a damaged,
edited or impossible file is refused with the field's name, never an internal error, and the
calibration id is a checksum of the content, so an edited file has another id."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from calibration.calib_file import load_calibration, save_calibration
from calibration.errors import CalibrationError, CalibrationMismatch
from station.cli import main
from station.config import load_config
from tests.station_fixtures import nominal_calibration, small_station_config, truth_calibration


@pytest.fixture(scope="module")
def config():
    return load_config()


@pytest.fixture
def doc(config, tmp_path):
    """(path, the saved document) of a plausible calibration with every pair's covariance."""
    calib = nominal_calibration(config)
    rng = np.random.default_rng(5)
    for wheel in calib.pairs:
        A = rng.normal(size=(30, 30)) * 1e-4
        calib.pair_covariance[wheel] = A @ A.T
    path = save_calibration(calib, tmp_path / "c.json")
    return path, json.loads(path.read_text())


def _set(d, dotted: str, value):
    *parents, last = dotted.split(".")
    for k in parents:
        d = d[int(k)] if isinstance(d, list) else d[k]
    if value is KeyError:
        del d[last]
    elif isinstance(d, list):
        d[int(last)] = value
    else:
        d[last] = value


NAN = float("nan")
CORRUPTIONS = [  # (field, new value or KeyError to delete it, what the message says)
    ("cameras.cam1.std", None, "cameras.cam1.std: expected an object, got null"),
    ("cameras.cam1.std.fx", -1, "cameras.cam1.std.fx: -1 is outside"),
    ("cameras.cam1.std.bogus", 1, "cameras.cam1.std.bogus: unknown key"),
    ("cameras.cam1.std.k2", 1e308, "cameras.cam1.std.k2: 1e+308 is outside [0, "),
    ("cameras.cam1.std.fx", 5000, "cameras.cam1.std.fx: 5000 is outside [0, 1280]"),
    ("cameras.cam1.std.position_m", [0, 0, 1e3], "cameras.cam1.std.position_m[2]: 1000 is outside [0, 100]"),
    ("cameras.cam2.K.0.0", 1e308, "cameras.cam2.K: fx = 1e+308 px gives a horizontal field of view"),
    ("cameras.cam2.K.1.1", 1.0, "cameras.cam2.K: fy = 1 px gives a vertical field of view of 180 deg"),
    ("cameras.cam2.K.0.0", -1800.0, "cameras.cam2.K: fx = -1800 px; a focal length must be positive"),
    ("cameras.cam2.K.0.1", 3.0, "cameras.cam2.K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"),
    ("cameras.cam2.K.0.2", 5000.0, "cameras.cam2.K: cx = 5000 px puts the principal point outside"),
    ("cameras.cam2.K.1", [0, 5400, 512], "cameras.cam2.K: fy / fx = 3"),
    ("cameras.cam2.K.2", [0, 0], "cameras.cam2.K: expected 3x3 numbers"),
    ("cameras.cam2.K.2.2", "1", "cameras.cam2.K[2][2]: expected a number, got text"),
    ("cameras.cam3.dist.0", 50.0, "cameras.cam3.dist: the distortion"),
    ("cameras.cam3.dist.0", -5.0, "cameras.cam3.dist: the distortion"),
    ("cameras.cam3.dist.4", NAN, "cameras.cam3.dist[4]: not a finite number"),
    ("cameras.cam3.dist", [0.0] * 14, "cameras.cam3.dist: has 14 coefficients: the last two are OpenCV's tilted-sensor"),
    ("cameras.cam3.dist", [0.0] * 6, "cameras.cam3.dist: has 6 coefficients; this camera model takes 5"),
    ("cameras.cam3.dist", {"k1": 0}, "cameras.cam3.dist: expected a list of 5, 8 or 12 numbers, got an object"),
    ("cameras.cam3.dist", [-0.2, 0.1, 0, 0, 0, 8.0, 0, 0], "cameras.cam3.dist: the distortion cannot be undone"),
    ("cameras.cam3.dist", [-0.2, 0.1, 0, 0, 0, 0, 0, 0, 3.0, 0, 0, 0], "cameras.cam3.dist: the distortion cannot be"),
    ("cameras.cam3.R_cam_station.0.0", 2.0, "cameras.cam3.R_cam_station: is not a rotation"),
    ("cameras.cam3.t_cam_station_m", [1000.0, 0, 0], "cameras.cam3.t_cam_station_m: puts the camera 1e+03 m"),
    ("cameras.cam3.center_station_m.0", 9.0, "cameras.cam3.center_station_m: does not agree"),
    ("cameras.cam4.width", 640.5, "cameras.cam4.width: expected a whole number"),
    ("cameras.cam4.width", "1280", "cameras.cam4.width: expected a whole number"),
    ("cameras.cam4.height", 0, "cameras.cam4.height: 0 is outside"),
    ("cameras.cam4.n_points", -3, "cameras.cam4.n_points: -3 is outside"),
    ("cameras.cam4.reprojection_rms_px", [], "cameras.cam4.reprojection_rms_px: expected a number, got a list"),
    ("cameras.cam4.reprojection_rms_px", 1e300, "cameras.cam4.reprojection_rms_px: 1e+300 is outside"),
    ("cameras.cam4.K", KeyError, "cameras.cam4.K: missing"),
    ("cameras.cam4.Kx", [], "cameras.cam4.Kx: unknown key"),
    ("cameras.cam5", "cam", "cameras.cam5: expected an object, got text"),
    ("cameras", {}, "cameras: no cameras"),
    ("pairs", KeyError, "pairs: missing"),
    ("pairs", [], "pairs: expected an object, got a list"),
    ("pairs.FL.R.0.0", NAN, "pairs.FL.R[0][0]: not a finite number"),
    ("pairs.FL.R.0.0", 0.5, "pairs.FL.R: does not agree with the cameras"),
    ("pairs.FL.F.2.2", 1.0, "pairs.FL.F: does not agree with the cameras"),
    ("pairs.FL.baseline_m", 2.0, "pairs.FL.baseline_m: does not agree"),
    ("pairs.FL.right", "cam3", "pairs.FL: left and right are both 'cam3'"),
    ("pairs.FL.right", "cam99", "pairs.FL.right: names camera 'cam99'"),
    ("pairs.FL.left", 1, "pairs.FL.left: expected text"),
    ("pairs.FL.covariance", KeyError, "pairs.FL.covariance: missing while pair(s) FR, RL, RR have theirs"),
    ("pairs.FL.covariance.0.0", -1.0, "pairs.FL.covariance: is not positive semi-definite"),
    ("pairs.FL.covariance.0.1", 1.0, "pairs.FL.covariance: must be a symmetric 30x30"),
    ("pairs.FL.covariance.20.20", 1e308, "pairs.FL.covariance: row 20 (cam4 k2) gives a standard deviation of 1e+154"),
    ("camera_ids", ["cam1"], "camera_ids: must list the cameras"),
    ("created_utc", "yesterday", "created_utc: 'yesterday' is not an ISO 8601 time"),
    ("station_name", 7, "station_name: expected text, got int"),
    ("notes", None, "notes: expected an object, got null"),
    ("extra", 1, "extra: unknown key"),
    ("format_version", True, "format_version True is not supported"),
    ("format_version", 1.0, "format_version 1.0 is not supported"),
]


@pytest.mark.parametrize("field,value,message", CORRUPTIONS, ids=[c[0] + "=" + repr(c[1])[:20] for c in CORRUPTIONS])
def test_a_wrong_field_is_refused_by_name(doc, field, value, message):
    path, d = doc
    _set(d, field, value)
    path.write_text(json.dumps(d))
    with pytest.raises(CalibrationError) as e:
        load_calibration(path)
    assert message in str(e.value) and str(path) in str(e.value)
    assert e.value.hint


@pytest.mark.parametrize("content,message", [
    (b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe", "byte 0 is not UTF-8 text"),
    (b"", "the calibration file is empty"),
    (b"[" * 100_000, "not a calibration file (RecursionError"),
    (b'{"format": ' + b"9" * 5000 + b"}", "not a calibration file (ValueError"),
    (b"[1, 2]", "not a station calibration file"),
])
def test_a_file_that_is_not_a_calibration_is_refused(tmp_path, content, message):
    path = tmp_path / "c.json"
    path.write_bytes(content)
    with pytest.raises(CalibrationError, match=message.replace("(", r"\(")):
        load_calibration(path)


def test_a_truncated_file_is_refused_at_every_length(doc):
    path, _ = doc
    text = path.read_bytes()
    for n in range(0, len(text) - 2, max(1, len(text) // 97)):
        path.write_bytes(text[:n])
        with pytest.raises(CalibrationError):
            load_calibration(path)


def test_a_configured_pair_missing_from_the_file_is_refused(config, doc):
    path, d = doc
    del d["pairs"]["RL"]
    path.write_text(json.dumps(d))
    with pytest.raises(CalibrationMismatch, match="pairs: no pair RL"):
        load_calibration(path, config)


def test_the_id_is_a_checksum_of_the_content_and_an_edit_changes_it(doc):
    path, d = doc
    content = {k: v for k, v in d.items() if k != "calibration_id"}
    checksum = hashlib.sha256(json.dumps(content, sort_keys=True, separators=(",", ":")).encode()).hexdigest()
    assert d["calibration_id"] == checksum[:12] == load_calibration(path).calibration_id
    d["cameras"]["cam1"]["dist"][0] += 1e-6  # a plausible edit the derived values do not show
    path.write_text(json.dumps(d, indent=1))
    edited = load_calibration(path)
    assert edited.calibration_id != d["calibration_id"]
    d["calibration_id"] = "0123456789ab"  # the stored id is not believed either
    path.write_text(json.dumps(d))
    assert load_calibration(path).calibration_id == edited.calibration_id
    saved = save_calibration(edited, path.with_name("again.json"))
    assert json.loads(saved.read_text())["calibration_id"] == edited.calibration_id


@pytest.mark.parametrize("dist", [[-0.2, 0.1, 3e-4, -2e-4, 0.01, 0.03, -0.02, 0.01],
                                  [-0.2, 0.1, 3e-4, -2e-4, 0.01, 0.03, -0.02, 0.01, 1e-3, -5e-4, -1e-3, 4e-4]])
def test_a_camera_with_opencvs_longer_distortion_loads_exactly(doc, dist):
    path, d = doc
    d["cameras"]["cam3"]["dist"] = dist
    for p in d["pairs"].values():  # an imported camera has no covariance, and then no pair has one
        p.pop("covariance", None)
    path.write_text(json.dumps(d))
    back = load_calibration(path)
    assert back.model("cam3").dist.tolist() == dist and back.model("cam4").dist.shape == (5,)
    assert back.calibration_id != d["calibration_id"]  # the content changed, so did its id


def test_the_truth_calibration_of_the_tests_loads_with_its_written_id(tmp_path):
    cfg = small_station_config(tmp_path)
    calib = truth_calibration(cfg)
    back = load_calibration(cfg.calibration_file, cfg)
    assert back.calibration_id == calib.calibration_id == json.loads(cfg.calibration_file.read_text())["calibration_id"]


def test_measure_refuses_an_impossible_focal_length_at_once_naming_the_field(tmp_path, capsys):
    cfg = small_station_config(tmp_path)
    truth_calibration(cfg)
    d = json.loads(cfg.calibration_file.read_text())
    d["cameras"]["cam5"]["K"][0][0] = 1e308
    cfg.calibration_file.write_text(json.dumps(d))
    assert main(["--config", str(cfg.path), "measure", "--seed", "1", "--no-record"]) == 2
    err = capsys.readouterr().err
    assert "cameras.cam5.K: fx = 1e+308 px" in err and "station calibrate" in err
    assert "Traceback" not in err and "internal error" not in err
