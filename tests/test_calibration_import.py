"""`station calibration import|export`: OpenCV's files in and out (docs/calibration.md, "Import and
export"). Every test has its own STATION_DATA_DIR (tests/conftest.py) and writes its OpenCV
files into its own tmp_path."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.calib_file import CameraCalibration, load_calibration, save_calibration
from station.cli import main
from station.config import load_config
from tests.station_fixtures import nominal_calibration

ROOT = Path(__file__).resolve().parent.parent
RATIONAL = np.array([-0.21, 0.09, 3e-4, -2e-4, -0.01, 0.03, -0.02, 0.01])   # k1 k2 p1 p2 k3 k4 k5 k6
PRISM = np.r_[RATIONAL, 1.5e-3, -8e-4, -1.2e-3, 6e-4]                        # + s1 s2 s3 s4
TILTED = np.r_[PRISM, 2e-3, -1e-3]                                           # + tauX tauY


def _station(dists: dict | None = None, covariance: bool = False):
    """(config, the saved current calibration) of this test's data dir; ``dists``: camera -> dist."""
    config = load_config()
    calib = nominal_calibration(config)
    for cam, d in (dists or {}).items():
        c = calib.cameras[cam]
        calib.cameras[cam] = CameraCalibration(replace(c.model, dist=np.asarray(d, float)), c.reprojection_rms_px,
                                               c.n_points, c.std)
    if covariance:
        rng = np.random.default_rng(5)
        for wheel in calib.pairs:
            A = rng.normal(size=(30, 30)) * 1e-4
            calib.pair_covariance[wheel] = A @ A.T
    save_calibration(calib, config.calibration_file)
    return config, load_calibration(config.calibration_file, config)


def _points_near(model, n=400, seed=3):
    """(n,3) station points 0.5-1.5 m in front of the camera, inside its image."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([20, 20], [model.width - 20, model.height - 20], (n, 2))
    origin, dirs = model.rays_station(uv)
    return origin + dirs * rng.uniform(0.5, 1.5, (n, 1))


def _opencv_pixels(pts, R, t, K, dist):
    uv, _ = cv2.projectPoints(pts, cv2.Rodrigues(R)[0], t, K, dist)
    return uv[:, 0, :]


def _write(path: Path, **items) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for k, v in items.items():
        fs.write(k, v)
    fs.release()
    return path


def _stereo_files(tmp_path: Path, current, n: int, unit: float = 1.0, ext: str = "yml"):
    """OpenCV's stereo_calib output for a known synthetic FL pair (cam3, cam4) with ``n`` distortion
    coefficients: intrinsics.<ext> (M1 D1 M2 D2) and extrinsics.<ext> (R T R1 R2 P1 P2 Q), T in
    metres / ``unit``; and the truth: camera -> (K, dist, R_cam_station, t_cam_station)."""
    a, b = current.model("cam3"), current.model("cam4")
    K1 = np.array([[1791.5, 0, 650.25], [0, 1789.0, 515.5], [0, 0, 1]])
    K2 = np.array([[1806.0, 0, 633.75], [0, 1804.5, 508.0], [0, 0, 1]])
    D1 = {8: RATIONAL, 12: PRISM, 14: TILTED, 5: RATIONAL[:5]}[n]
    D2 = D1 * 0.8
    # camera 4 moved a little since the current calibration: its pose comes from the pair's R, T
    R_b = cv2.Rodrigues(np.array([0.002, -0.003, 0.001]))[0] @ b.R_cam_station
    t_b = b.t_cam_station + np.array([0.0012, -0.0007, 0.0004])
    R = R_b @ a.R_cam_station.T
    T = t_b - R @ a.t_cam_station
    _write(tmp_path / f"intrinsics.{ext}", M1=K1, D1=D1.reshape(1, -1), M2=K2, D2=D2.reshape(1, -1))
    R1, R2, P1, P2, Q, *_ = cv2.stereoRectify(K1, D1, K2, D2, (a.width, a.height), R, (T / unit).reshape(3, 1))
    _write(tmp_path / f"extrinsics.{ext}", R=R, T=(T / unit).reshape(3, 1), R1=R1, R2=R2, P1=P1, P2=P2, Q=Q)
    truth = {"cam3": (K1, D1, a.R_cam_station, a.t_cam_station), "cam4": (K2, D2, R_b, t_b)}
    return tmp_path / f"intrinsics.{ext}", tmp_path / f"extrinsics.{ext}", truth


def _run(capsys, *argv) -> tuple[int, str, str]:
    rc = main(["calibration", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


# --- round trip ---------------------------------------------------------------------------------
def test_export_then_import_gives_identical_projections(tmp_path, capsys):
    config, current = _station({"cam3": RATIONAL, "cam6": PRISM})
    rc, out, _ = _run(capsys, "export", tmp_path / "ocv")
    assert rc == 0 and out.count("wrote ") == 12
    config.calibration_file.unlink()  # the import alone must give back every camera
    rc, out, err = _run(capsys, "import", *sorted((tmp_path / "ocv").glob("*.yaml")))
    assert rc == 0, err
    back = load_calibration(config.calibration_file, config)
    assert back.method == "imported from OpenCV files" and back.pairs == current.pairs
    worst = 0.0
    for cam in config.cameras:
        a, b = current.model(cam), back.model(cam)
        assert b.dist.size == {"cam3": 8, "cam6": 12}.get(cam, 5)
        pts = _points_near(a)
        worst = max(worst, float(np.abs(a.project(pts) - b.project(pts)).max()))
    assert worst < 1e-9, worst
    print(f"round trip: {worst:.2e} px")


def test_exported_files_are_what_opencv_reads(tmp_path, capsys):
    config, current = _station({"cam4": PRISM})
    assert _run(capsys, "export", tmp_path)[0] == 0
    fs = cv2.FileStorage(str(tmp_path / "pairs" / "FL.yaml"), cv2.FILE_STORAGE_READ)
    M2, D2, R, T = (fs.getNode(k).mat() for k in ("M2", "D2", "R", "T"))
    assert fs.getNode("camera_1").string() == "cam3" and fs.getNode("camera_2").string() == "cam4"
    fs.release()
    a, b = current.model("cam3"), current.model("cam4")
    pts = _points_near(b)
    # a point in cam3's frame, projected into cam4 with OpenCV and the pair's R, T
    in_a = a.station_to_cam(pts)
    uv = _opencv_pixels(in_a, R, T.ravel(), M2, D2)
    assert np.abs(uv - b.project(pts)).max() < 1e-9


# --- stereoCalibrate's files ----------------------------------------------------------------------
@pytest.mark.parametrize("n, how", [(8, "pose"), (12, "pose"), (8, "anchor"), (12, "anchor"), (8, "pose of camera 2")])
def test_a_stereo_calib_pair_reprojects_as_opencv(tmp_path, capsys, n, how):
    config, current = _station(covariance=True)
    intr, extr, truth = _stereo_files(tmp_path, current, n, unit=1e-3)  # T in millimetres
    cam = "cam4" if how == "pose of camera 2" else "cam3"
    R, t = truth[cam][2:]
    if how.startswith("pose"):
        pose = _write(tmp_path / "pose.xml", R=R, T=t.reshape(3, 1) * 1000)  # --unit mm: every T in mm
        place = ["--pose", f"{cam}={pose}"]
    else:
        place = ["--anchor", "cam3"]
    rc, out, err = _run(capsys, "import", f"FL={intr}", f"FL={extr}", "--unit", "mm", *place)
    assert rc == 0, err
    assert "kept from the current calibration" in out and "covariances are not kept" in out
    back = load_calibration(config.calibration_file, config)
    worst = 0.0
    for cam, (K, D, R, t) in truth.items():
        m = back.model(cam)
        assert m.dist.size == n
        pts = _points_near(m)
        worst = max(worst, float(np.abs(m.project(pts) - _opencv_pixels(pts, R, t, K, D)).max()))
    assert worst < 1e-6, worst
    for cam in ("cam1", "cam2", "cam5", "cam6", "cam7", "cam8"):  # the others as they were
        assert np.array_equal(back.model(cam).K, current.model(cam).K)
        assert np.array_equal(back.model(cam).t_cam_station, current.model(cam).t_cam_station)
    assert back.pair_covariance == {}
    print(f"{n} coefficients ({how}): {worst:.2e} px")


def test_a_fourteen_term_vector_with_a_tilted_sensor_is_refused(tmp_path, capsys):
    config, _current = _station()
    before = config.calibration_file.read_bytes()
    intr, extr, _ = _stereo_files(tmp_path, _current, 14)
    rc, _, err = _run(capsys, "import", f"FL={intr}", f"FL={extr}", "--anchor", "cam3")
    assert rc == 2
    assert f"{intr}: D1: 14 coefficients: the last two are OpenCV's tilted-sensor terms tauX tauY" in err
    assert "CALIB_TILTED_MODEL" in err and "Traceback" not in err
    assert config.calibration_file.read_bytes() == before


def test_fourteen_coefficients_without_tilt_are_the_twelve_term_model(tmp_path, capsys):
    config, current = _station()
    intr, extr, truth = _stereo_files(tmp_path, current, 12)
    fs = cv2.FileStorage(str(intr), cv2.FILE_STORAGE_READ)
    K1, D1, K2, D2 = (fs.getNode(k).mat() for k in ("M1", "D1", "M2", "D2"))
    fs.release()
    _write(intr, M1=K1, D1=np.c_[D1, 0.0, 0.0], M2=K2, D2=np.c_[D2, 0.0, 0.0])
    assert _run(capsys, "import", f"FL={intr}", f"FL={extr}", "--anchor", "cam3")[0] == 0
    assert np.array_equal(load_calibration(config.calibration_file).model("cam3").dist, truth["cam3"][1])


def test_a_single_camera_file_of_opencvs_calibration_sample_keeps_the_anchored_pose(tmp_path, capsys):
    config, current = _station()
    K = np.array([[1795.0, 0, 641.0], [0, 1795.0, 509.0], [0, 0, 1]])
    f = _write(tmp_path / "out_camera_data.xml", calibration_time="now", image_width=1280, image_height=1024,
               camera_matrix=K, distortion_coefficients=RATIONAL.reshape(-1, 1), avg_reprojection_error=0.21)
    rc, _, err = _run(capsys, "import", f"cam5={f}", "--anchor", "cam5")
    assert rc == 0, err
    m, was = load_calibration(config.calibration_file).model("cam5"), current.model("cam5")
    assert np.array_equal(m.K, K) and np.array_equal(m.dist, RATIONAL)
    assert np.array_equal(m.R_cam_station, was.R_cam_station) and np.array_equal(m.t_cam_station, was.t_cam_station)


# --- refusals: a clear message, exit 2, nothing saved -----------------------------------------------
def _bad_inputs(tmp_path: Path, current) -> dict:
    """case -> (the import's arguments, texts its message must hold)."""
    intr, extr, _ = _stereo_files(tmp_path, current, 8)
    (tmp_path / "mm").mkdir()
    intr_mm, extr_mm, _ = _stereo_files(tmp_path / "mm", current, 8, unit=1e-3)
    K, R3, t3 = current.model("cam3").K, current.model("cam3").R_cam_station, current.model("cam3").t_cam_station

    def cam3(name, **items):  # a camera file given as cam3's, its pose kept
        return [f"cam3={_write(tmp_path / name, **items)}", "--anchor", "cam3"]

    png = tmp_path / "photo.yml"
    png.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    text = tmp_path / "notes.yml"
    text.write_text("cam3 was recalibrated on Monday\n")
    pair, pair_mm = [f"FL={intr}", f"FL={extr}"], [f"FL={intr_mm}", f"FL={extr_mm}", "--unit", "mm"]
    return {
        "only the intrinsics": ([f"FL={intr}", "--anchor", "cam3"], [f"{intr}: no key R", "extrinsics.yml"]),
        "no pose": (pair, ["nothing places either in the station frame", "--anchor cam3"]),
        "no target": ([intr, extr], [f"{intr}: which pair the file describes is not known", f"FL={intr}"]),
        "wrong shape": (cam3("c.yml", camera_matrix=K[:2], distortion_coefficients=RATIONAL),
                        ["c.yml: camera_matrix: expected a 3x3 matrix", "got 2x3"]),
        "no distortion": (cam3("k.yml", camera_matrix=K), ["k.yml: no key distortion_coefficients"]),
        "six coefficients": (cam3("d.yml", camera_matrix=K, distortion_coefficients=np.zeros(6)),
                             ["d.yml: distortion_coefficients: 6 coefficients; OpenCV writes"]),
        "implausible distortion": (cam3("x.yml", camera_matrix=K, distortion_coefficients=np.array(
            [-0.2, 0.1, 0, 0, 0, 8.0, 0, 0])), ["x.yml: distortion_coefficients (cam3): the distortion cannot be undone"]),
        "other resolution": (cam3("r.yml", camera_matrix=K, distortion_coefficients=RATIONAL, image_width=640,
                                  image_height=480),
                             ["r.yml: image_width x image_height = 640x480, but camera cam3 is configured for 1280x1024"]),
        "a PNG": ([f"cam3={png}"], [f"{png}: not an OpenCV FileStorage file", "line 1"]),
        "a text": ([f"cam3={text}"], [f"{text}: not an OpenCV FileStorage file"]),
        "missing file": ([f"cam3={tmp_path / 'nope.yml'}"], ["nope.yml: no such file"]),
        "unknown camera": ([f"cam9={_write(tmp_path / 'n.yml', camera_matrix=K, distortion_coefficients=RATIONAL)}"],
                           ["'cam9' is not one of the station's cameras"]),
        "millimetres as metres": ([*pair, "--pose", f"cam3={_write(tmp_path / 'p.yml', R=R3, T=t3 * 1000)}"],
                                  ["p.yml: T (cam3): puts the camera", "--unit mm"]),
        "metres as millimetres": ([*pair, "--unit", "mm", "--anchor", "cam3"],
                                  ["extrinsics.yml (R, T): puts cameras cam3 and cam4 0.592 mm apart"]),
        "a pose in metres, T in mm": ([*pair_mm, "--pose", f"cam3={_write(tmp_path / 'm.yml', R=R3, T=t3)}"],
                                      ["camera cam3: the import places it at (-0.002, 0.002, 0.000) m",
                                       "from its mount in the configuration", "m.yml (--pose)", "--unit"]),
        "placed twice": ([*pair, "--anchor", "cam3", "--anchor", "cam4"],
                         ["places cam4 relative to cam3, but both are already placed"]),
        "a pose for a camera not imported": ([*pair, "--anchor", "cam3", "--anchor", "cam1"],
                                             ["--anchor cam1: no file gives camera cam1's intrinsics"]),
        "a pose given twice": ([*pair, "--pose", f"cam3={_write(tmp_path / 'q.yml', R=R3, T=t3)}",
                                "--pose", f"cam3={tmp_path / 'q.yml'}"], ["--pose cam3= is given twice"]),
    }


BAD = ["only the intrinsics", "no pose", "no target", "wrong shape", "no distortion", "six coefficients",
       "implausible distortion", "other resolution", "a PNG", "a text", "missing file", "unknown camera",
       "millimetres as metres", "metres as millimetres", "a pose in metres, T in mm", "placed twice",
       "a pose for a camera not imported", "a pose given twice"]


@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_refused_with_the_file_and_key_and_nothing_is_saved(tmp_path, capsys, case):
    config, current = _station()
    before = config.calibration_file.read_bytes()
    argv, expected = _bad_inputs(tmp_path, current)[case]
    rc, out, err = _run(capsys, "import", *argv)
    assert rc == 2, (out, err)
    for text in expected:
        assert text in err, (text, err)
    assert err.startswith(("error 300 (calibration): ", "error 301 (calibration): ", "error 302 (calibration): "))
    assert "Traceback" not in err and "internal error" not in err
    assert config.calibration_file.read_bytes() == before


def test_a_refused_import_exits_non_zero_through_the_real_command(tmp_path):
    data = tmp_path / "data"
    env = {**os.environ, "STATION_DATA_DIR": str(data), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    bad = _write(tmp_path / "cam.yml", camera_matrix=np.eye(3)[:2])
    proc = subprocess.run([sys.executable, "-m", "station.cli", "calibration", "import", f"cam3={bad}"], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert f"{bad}: camera_matrix: expected a 3x3 matrix" in proc.stderr and "Traceback" not in proc.stderr
    assert not (data / "calibration").exists()


def test_export_without_a_calibration_says_so(tmp_path, capsys):
    rc, _, err = _run(capsys, "export", tmp_path / "out")
    assert rc == 2 and "calibration file not found" in err and "station calibrate" in err


def test_a_partial_import_without_a_current_calibration_names_the_missing_cameras(tmp_path, capsys):
    config, current = _station()
    intr, extr, _ = _stereo_files(tmp_path, current, 8)
    pose = _write(tmp_path / "pose.yml", R=current.model("cam3").R_cam_station,
                  T=current.model("cam3").t_cam_station.reshape(3, 1))
    config.calibration_file.unlink()
    rc, _, err = _run(capsys, "import", f"FL={intr}", f"FL={extr}", "--pose", f"cam3={pose}")
    assert rc == 2 and "camera(s) cam1, cam2, cam5, cam6, cam7, cam8: in none of the files" in err
    assert not config.calibration_file.exists()


def test_dry_run_checks_and_saves_nothing(tmp_path, capsys):
    config, current = _station()
    before = config.calibration_file.read_bytes()
    intr, extr, _ = _stereo_files(tmp_path, current, 12)
    rc, out, _ = _run(capsys, "import", f"FL={intr}", f"FL={extr}", "--anchor", "cam3", "--dry-run")
    assert rc == 0 and "nothing saved" in out and config.calibration_file.read_bytes() == before
    assert json.loads(before)["method"] != "imported from OpenCV files"


def test_a_damaged_current_calibration_is_replaced_by_a_complete_import_but_cannot_lend_poses(tmp_path, capsys):
    config, current = _station()
    assert _run(capsys, "export", tmp_path / "ocv")[0] == 0
    intr, extr, _ = _stereo_files(tmp_path, current, 8)
    config.calibration_file.write_text('{"format": "wheel-alignment-station/calibration", "form')
    rc, _, err = _run(capsys, "import", f"FL={intr}", f"FL={extr}", "--anchor", "cam3")
    assert rc == 2 and "the current calibration cannot be used" in err and "not valid JSON" in err
    rc, out, err = _run(capsys, "import", *sorted((tmp_path / "ocv").glob("*.yaml")))
    assert rc == 0, err
    assert "replacing a file that could not be read" in out
    assert load_calibration(config.calibration_file, config).model("cam3").dist.size == 5


# --- an imported lens through the measurement -----------------------------------------------------
@pytest.mark.slow
def test_a_twelve_term_lens_measures_the_wheel_and_its_extra_terms_matter(tmp_path):
    """The simulator renders the FL pair through lenses with OpenCV's rational and thin-prism
    terms; the wheel measured with those 12-term cameras comes out as with any true camera, and
    with the terms dropped (the 5-term model) its rim is off by millimetres."""
    from simulators.world import SimWorld
    from station.wheel.pair import measure_wheel
    from tests.station_fixtures import small_station_config

    cfg = small_station_config(tmp_path)
    world = SimWorld.from_config(cfg)
    scene = world.vehicle_scene(3)
    world.set_scene(scene)
    extra = np.array([0.15, -0.08, 0.05, 3e-3, -1e-3, -2e-3, 1e-3])  # k4 k5 k6 s1 s2 s3 s4
    for c in ("cam3", "cam4"):
        world.cameras[c] = replace(world.cameras[c], dist=np.r_[world.cameras[c].dist, extra])
    images = {c: world.render(c) for c in ("cam3", "cam4")}
    truth = world.truth(scene)["wheels"]["FL"]

    def errors(cameras):
        out = measure_wheel("FL", ("cam3", "cam4"), images, cameras, cfg)
        assert out.observation is not None, out.error
        fit = out.observation.circle
        axis = np.degrees(np.arccos(min(1.0, abs(float(fit.axis_station @ np.array(truth["axis_station"]))))))
        centre = 1000 * np.linalg.norm(fit.center_station - np.array(truth["center_station_m"]))
        return axis, centre, 1000 * abs(fit.radius_m - truth["rim_radius_m"])

    axis, centre, radius = errors(world.cameras)
    assert axis < 0.1 and centre < 0.3 and radius < 0.3, (axis, centre, radius)   # measured 0.054 deg, 0.07, 0.001 mm
    _, centre5, radius5 = errors({c: replace(m, dist=m.dist[:5]) for c, m in world.cameras.items()})
    assert centre5 > 0.8 and radius5 > 1.0, (centre5, radius5)                     # measured 1.2 mm, 1.6 mm
