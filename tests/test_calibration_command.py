"""`station calibrate` / `station box-print` at the command line: bad input gives one clear
message, a non-zero exit, and never overwrites a saved calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from station import cli

CONFIG = Path(__file__).resolve().parent.parent / "config" / "station.yaml"


def _config_copy(tmp_path, edit=None) -> Path:
    raw = yaml.safe_load(CONFIG.read_text())
    raw["data_dir"] = str(tmp_path / "var")
    raw["vehicle_specs"] = str(CONFIG.parent / raw.get("vehicle_specs", "vehicles.yaml"))
    raw["calibration"]["box"] = str(CONFIG.parent / raw["calibration"].get("box", "box.yaml"))
    if edit:
        edit(raw)
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_box_not_seen_refuses_and_keeps_the_saved_file(tmp_path, monkeypatch, capsys):
    from simulators import world as world_mod
    monkeypatch.setattr(world_mod.SimWorld, "render",
                        lambda self, cam_id, rng=None, scene=None, exposure=1.0: np.full((1024, 1280), 90, np.uint8))
    cfg = _config_copy(tmp_path)
    saved = tmp_path / "var" / "calibration" / "station.calib.json"
    saved.parent.mkdir(parents=True)
    saved.write_text("previous good calibration")
    rc = cli.main(["--config", str(cfg), "calibrate", "--poses", "3"])
    err = capsys.readouterr().err
    assert rc != 0
    assert "cam3" in err and "found in only 0 of 3" in err and "Traceback" not in err
    assert saved.read_text() == "previous good calibration"


def test_every_box_image_is_the_mean_of_a_burst(tmp_path, monkeypatch, capsys):
    """The box stands still like the car: each of its images is capture.frames_averaged frames."""
    from simulators import world as world_mod
    renders: dict[str, int] = {}

    def render(self, cam_id, rng=None, scene=None, exposure=1.0):
        renders[cam_id] = renders.get(cam_id, 0) + 1
        return np.full((1024, 1280), 90, np.uint8)
    monkeypatch.setattr(world_mod.SimWorld, "render", render)
    cfg = _config_copy(tmp_path, lambda raw: raw["capture"].update(frames_averaged=3))
    assert cli.main(["--config", str(cfg), "calibrate", "--poses", "3"]) != 0  # no box: refused
    capsys.readouterr()
    # the first pair's two cameras: 3 intrinsic poses and the fixture, 3 frames each
    assert sorted(renders.values()) == [12, 12], renders


def test_nine_cameras_are_refused_with_a_clear_message(tmp_path, capsys):
    def add(raw):
        raw["cameras"]["cam9"] = dict(raw["cameras"]["cam1"], uri="sim://cam9")
    rc = cli.main(["--config", str(_config_copy(tmp_path, add)), "calibrate"])
    err = capsys.readouterr().err
    assert rc != 0 and "exactly 8 cameras" in err and "cam9" in err


def test_too_few_poses_refused(tmp_path, capsys):
    rc = cli.main(["--config", str(_config_copy(tmp_path)), "calibrate", "--poses", "2"])
    assert rc != 0 and "at least 3" in capsys.readouterr().err


def test_box_print_writes_true_scale_faces(tmp_path, capsys):
    import cv2
    rc = cli.main(["box-print", "--out", str(tmp_path / "print"), "--dpi", "100"])
    assert rc == 0
    img = cv2.imread(str(tmp_path / "print" / "box-px.png"), cv2.IMREAD_GRAYSCALE)
    # 0.50 x 0.60 m at 100 dpi
    assert abs(img.shape[1] - 0.5 / 0.0254 * 100) <= 1 and abs(img.shape[0] - 0.6 / 0.0254 * 100) <= 1
    data = (tmp_path / "print" / "box-px.png").read_bytes()
    assert b"pHYs" in data[:64]
    from calibration.box_detect import BoxDetector
    from station.config import load_box
    box = load_box(CONFIG.parent / "box.yaml")
    padded = cv2.copyMakeBorder(img, 30, 30, 30, 30, cv2.BORDER_CONSTANT, value=255)
    det = BoxDetector(box).detect(padded)
    assert det.faces.get("px", 0) == 11 * 13


def test_box_print_bad_dpi(tmp_path, capsys):
    assert cli.main(["box-print", "--out", str(tmp_path), "--dpi", "5"]) != 0
    assert "--dpi" in capsys.readouterr().err


def test_tables_show_every_camera_parameter_std_and_pair(capsys):
    from station.commands.calibrate import print_tables
    from station.config import load_config
    from tests.station_fixtures import nominal_calibration
    calib = nominal_calibration(load_config())
    print_tables(calib)
    out = capsys.readouterr().out
    assert all(f"cam{i} " in out for i in range(1, 9))
    assert "standard deviations" in out and "k3" in out
    assert "FR    cam1  cam2" in out


def test_a_camera_whose_grey_is_not_linear_is_named_while_calibrating(tmp_path, monkeypatch, capsys):
    """The box's bursts show a camera encoding sRGB as they show it in a cycle (tests/test_linearity.py):
    its corners would hold, its rims will not, so calibrate says so once, as soon as it sees it."""
    from simulators import world as world_mod

    ramp = np.tile(np.linspace(20, 230, 1280, dtype=np.float32), (1024, 1))

    def render(self, cam_id, rng=None, scene=None, exposure=1.0):
        return np.clip(np.rint(ramp + rng.standard_normal(ramp.shape, dtype=np.float32) * 2), 0, 255).astype(np.uint8)
    monkeypatch.setattr(world_mod.SimWorld, "render", render)

    def edit(raw):
        raw["capture"].update(frames_averaged=4)
        raw["cameras"]["cam3"]["uri"] = "sim://cam3?gamma=0.45"
    assert cli.main(["--config", str(_config_copy(tmp_path, edit)), "calibrate", "--poses", "3"]) != 0  # no box
    err = capsys.readouterr().err
    assert err.count("warning: cam3: its noise falls as its light grows") == 1
    assert "cam4: its noise" not in err and "Traceback" not in err
