"""Calibration file: JSON round trip, OpenCV import/export, validation, atomic save, stereo."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calibration.calib_file import CameraCalibration, load_calibration, save_calibration
from calibration.errors import CalibrationError, CalibrationMismatch
from calibration.opencv_files import export_opencv
from calibration.opencv_import import import_opencv
from calibration.stereo import StereoPair, epipolar_distance, pair_extrinsics
from station.config import load_config
from tests.station_fixtures import nominal_calibration


@pytest.fixture(scope="module")
def config():
    return load_config()


def test_json_round_trip_is_exact(config, tmp_path):
    calib = nominal_calibration(config)
    path = save_calibration(calib, tmp_path / "c.json")
    back = load_calibration(path, config)
    assert back.calibration_id == calib.calibration_id and back.software_version == calib.software_version
    for cam_id in config.cameras:
        a, b = calib.model(cam_id), back.model(cam_id)
        for key in ("K", "dist", "R_cam_station", "t_cam_station"):
            assert np.array_equal(getattr(a, key), getattr(b, key)), (cam_id, key)
    d = json.loads(path.read_text())
    assert d["format_version"] == 1 and set(d["camera_ids"]) == set(config.cameras)
    assert abs(d["pairs"]["FR"]["baseline_m"] - 0.6) < 0.01


def test_opencv_export_import_round_trip(config, tmp_path):
    calib = nominal_calibration(config)
    files = [f for f in export_opencv(calib, tmp_path / "ocv") if f.parent == tmp_path / "ocv"]
    assert len(files) == 8
    back = import_opencv({f.stem: f for f in files}, calib.pairs)
    for cam_id in config.cameras:
        a, b = calib.model(cam_id), back.model(cam_id)
        assert np.allclose(a.K, b.K, rtol=1e-12) and np.allclose(a.dist, b.dist, rtol=1e-12, atol=1e-15)
        assert np.allclose(a.R_cam_station, b.R_cam_station, atol=1e-12)
        assert np.allclose(a.t_cam_station, b.t_cam_station, atol=1e-12)
    back.check_against_config(config)


def test_nan_in_file_is_refused_and_named(config, tmp_path):
    path = save_calibration(nominal_calibration(config), tmp_path / "c.json")
    d = json.loads(path.read_text())
    d["cameras"]["cam3"]["K"][0][0] = float("nan")
    path.write_text(json.dumps(d))
    with pytest.raises(CalibrationError, match="cam3.*NaN"):
        load_calibration(path)


def test_failed_save_keeps_the_good_file(config, tmp_path):
    good = nominal_calibration(config)
    path = save_calibration(good, tmp_path / "c.json")
    before = path.read_bytes()
    bad = nominal_calibration(config)
    bad.pairs["FR"] = ("cam1", "cam99")
    with pytest.raises(CalibrationError):
        save_calibration(bad, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["c.json"]   # no temporary left behind


def test_camera_ids_must_match_the_configuration(config, tmp_path):
    calib = nominal_calibration(config)
    calib.cameras["cam9"] = CameraCalibration(calib.model("cam1"))
    path = save_calibration(calib, tmp_path / "c.json")
    with pytest.raises(CalibrationMismatch, match="cam9"):
        load_calibration(path, config)
    del calib.cameras["cam9"], calib.cameras["cam4"]
    calib.pairs.pop("FL")
    path = save_calibration(calib, tmp_path / "d.json")
    with pytest.raises(CalibrationMismatch, match="cam4"):
        load_calibration(path, config)


def test_stereo_eqs_34_35_29_33(config):
    calib = nominal_calibration(config)
    pair: StereoPair = calib.pair("FR")
    L, R_ = pair.left, pair.right
    R, t = pair_extrinsics(L.R_cam_station, L.t_cam_station, R_.R_cam_station, R_.t_cam_station)
    X = np.random.default_rng(0).uniform([0.6, 1.0, 0.1], [1.0, 1.7, 0.6], (50, 3))
    P_l, P_r = L.station_to_cam(X), R_.station_to_cam(X)
    assert np.allclose(P_l, P_r @ R + t, atol=1e-12)              # eq. 25: P_l = R^T P_r + t
    assert abs(pair.baseline_m - np.linalg.norm(L.center_station - R_.center_station)) < 1e-12
    p_l, p_r = P_l / P_l[:, 2:], P_r / P_r[:, 2:]
    assert np.abs(np.einsum("ni,ij,nj->n", p_r, pair.E, p_l)).max() < 1e-12     # eq. 28
    uv_l, uv_r = L.project(X), R_.project(X)
    assert np.abs(pair.epipolar_distance_px(uv_l, uv_r)).max() < 1e-6          # eq. 32 via F
    assert np.abs(pair.triangulate_station(uv_l, uv_r) - X).max() < 1e-9       # eq. 24
    shifted = uv_r + [0, 3.0]
    assert np.abs(pair.epipolar_distance_px(uv_l, shifted)).min() > 1.0


def test_pair_covariance_round_trips_and_a_malformed_one_is_refused(config, tmp_path):
    calib = nominal_calibration(config)
    rng = np.random.default_rng(3)
    covs = {}
    for wheel in calib.pairs:
        A = rng.normal(size=(30, 30))
        covs[wheel] = A @ A.T * 1e-8
    calib.pair_covariance = covs
    path = save_calibration(calib, tmp_path / "c.json")
    back = load_calibration(path, config)
    assert set(back.pair_covariance) == set(calib.pairs)
    np.testing.assert_array_equal(back.pair_covariance["FR"], calib.pair_covariance["FR"])
    d = json.loads(path.read_text())
    d["pairs"]["FR"]["covariance"] = d["pairs"]["FR"]["covariance"][:29]
    path.write_text(json.dumps(d))
    with pytest.raises(CalibrationError, match="pairs.FR.covariance: must be a symmetric 30x30"):
        load_calibration(path)
    del d["pairs"]["FR"]["covariance"]  # one pair without: the file is damaged
    path.write_text(json.dumps(d))
    with pytest.raises(CalibrationError, match="pairs.FR.covariance: missing while"):
        load_calibration(path)
    for p in d["pairs"].values():  # files written before it (or imported): none, still valid
        p.pop("covariance", None)
    path.write_text(json.dumps(d))
    assert load_calibration(path, config).pair_covariance == {}
