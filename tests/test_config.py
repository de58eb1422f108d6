"""Configuration: the default loads; every mistake names the file, the key and what was expected."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from station.config import DEFAULT_CONFIG, load_config
from station.errors import ConfigError


def _write(tmp_path, mutate):
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    mutate(data)
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_default_config_loads_eight_cameras_in_four_pairs():
    cfg = load_config()
    assert len(cfg.cameras) == 8
    assert {w: (p.precision, p.reference) for w, p in cfg.pairs.items()} == {
        "FL": ("cam3", "cam4"), "FR": ("cam1", "cam2"), "RL": ("cam5", "cam6"), "RR": ("cam7", "cam8")}
    cam = cfg.cameras["cam1"]
    assert (cam.width, cam.height, cam.pixel_format) == (1280, 1024, "Mono8")
    assert cam.response_gamma == 1.0  # linear cameras unless told otherwise
    assert cfg.plc.host == "127.0.0.1"


@pytest.mark.parametrize("mutate, expected", [
    (lambda d: d["cameras"]["cam3"].update(wheell="FL"), r"cameras\.cam3\.wheell: unknown key \(did you mean 'wheel'"),
    (lambda d: d["cameras"]["cam3"].update(resolution=[1280]), r"cameras\.cam3\.resolution: expected a list of 2"),
    (lambda d: d["cameras"]["cam3"].update(uri="ftp://x"), r"cameras\.cam3\.uri: unknown scheme"),
    (lambda d: d["cameras"]["cam3"].update(uri="sim://cam1"), r"already used by cam1"),
    (lambda d: d["cameras"].update(cam9=dict(d["cameras"]["cam1"], uri="sim://cam9")), r"exactly 8 cameras; this file names 9"),
    (lambda d: d["calibration"]["fixture"].pop("RR"), r"calibration\.fixture: missing entry 'RR'"),
    (lambda d: d["plc"].update(port=70000), r"plc\.port: expected a value in"),
    (lambda d: d.pop("version"), r"version: missing required key"),
    (lambda d: d["simulation"].update(noise_sigma="high"), r"simulation\.noise_sigma: expected a number"),
    (lambda d: d["cameras"]["cam3"].update(response_gamma=0), r"cameras\.cam3\.response_gamma: expected a value in"),
    (lambda d: d["cameras"]["cam3"]["nominal"].update(position_m=[1e308, 0, 1]),
     r"cameras\.cam3\.nominal\.position_m: expected a value in \[-100\.0, 100\.0\]"),
    (lambda d: d["calibration"]["fixture"]["FL"].update(position_m=[0, 0, -1e5]), r"calibration\.fixture\.FL\.position_m"),
    (lambda d: d["cameras"]["cam5"]["nominal"].update(look_at_m=d["cameras"]["cam5"]["nominal"]["position_m"]),
     r"cameras\.cam5\.nominal: look_at_m is position_m itself"),
    (lambda d: d["cameras"]["cam6"]["nominal"].update(look_at_m=[*d["cameras"]["cam6"]["nominal"]["position_m"][:2], 0]),
     r"cameras\.cam6\.nominal: look_at_m is straight above or below position_m"),
])
def test_mistakes_are_named(tmp_path, mutate, expected):
    path = _write(tmp_path, mutate)
    with pytest.raises(ConfigError, match=expected) as info:
        load_config(path)
    assert str(path) in str(info.value)


def test_missing_and_broken_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("cameras: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML at line"):
        load_config(bad)


@pytest.mark.parametrize("content, expected", [
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", "the configuration file is not text: byte 0 is not UTF-8"),
    (b"version: 1\nname: st\x00ation\n", "not valid YAML"),
    (b"[" * 50_000, "not valid YAML"),
    (b"", "missing required key"),
    (b"[1, 2]\n", r"station\.yaml: the file's top level must be a mapping of keys \(version, name, data_dir, \.\.\.\); "
                 "expected a mapping, got list"),
    (b"just a sentence\n", "top level must be a mapping of keys .*got str"),
])
def test_files_that_are_not_a_configuration(tmp_path, content, expected):
    path = tmp_path / "station.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=expected):
        load_config(path)


def test_a_number_beyond_any_float_is_named(tmp_path):
    path = _write(tmp_path, lambda d: d["capture"].update(timeout_s=10**400))
    with pytest.raises(ConfigError, match=r"capture\.timeout_s: expected a value in \[0\.01, 600\], got inf"):
        load_config(path)
    path = _write(tmp_path, lambda d: d["cameras"]["cam2"]["nominal"].update(position_m=[0, -(10**400), 1]))
    with pytest.raises(ConfigError, match=r"cameras\.cam2\.nominal\.position_m"):
        load_config(path)


def test_a_truncated_configuration_is_refused_or_complete(tmp_path):
    """Cut anywhere, the file is refused with a ConfigError, or what is left is a whole
    configuration (the optional sections at its end take their defaults)."""
    text = DEFAULT_CONFIG.read_bytes()
    path = tmp_path / "station.yaml"
    for n in range(0, len(text), max(1, len(text) // 150)):
        path.write_bytes(text[:n].replace(b"vehicles.yaml", str(DEFAULT_CONFIG.parent / "vehicles.yaml").encode()))
        try:
            load_config(path)
        except ConfigError:
            pass


@pytest.mark.parametrize("mutate, expected", [
    (lambda d: d["faces"]["px"].update(squares=[1, 1]), r"faces\.px\.squares: expected a value in \[2, 1000\]"),
    (lambda d: d["faces"]["px"].update(squares=[12.5, 14]), r"faces\.px\.squares: expected an integer"),
    (lambda d: d["faces"]["py"].update(first_id=None), r"faces\.py\.first_id: expected an integer"),
    (lambda d: d["faces"].update(nx=None), r"faces\.nx\.squares: missing required key"),
    (lambda d: d.update(square_m="big"), r"square_m: expected a number"),
    (lambda d: d.update(size_m=[0.5, 0.5, 10**400]), r"size_m: expected a value in \[0\.01, 10\], got inf"),
    (lambda d: d.update(dictionary=7), r"dictionary: expected a non-empty string"),
    (lambda d: d.update(dictionary="DICT_NOPE"), r"unknown ArUco dictionary 'DICT_NOPE'"),
    (lambda d: d.update(marker_m=0.05), r"marker_m must be positive and smaller than square_m"),
    (lambda d: d.update(colour="red"), r"colour: unknown key"),
])
def test_box_file_mistakes_are_named(tmp_path, mutate, expected):
    from station.config import load_box

    data = yaml.safe_load((DEFAULT_CONFIG.parent / "box.yaml").read_text())
    mutate(data)
    path = tmp_path / "box.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=expected) as info:
        load_box(path)
    assert str(path) in str(info.value)


def test_cli_reports_a_binary_configuration_without_traceback(tmp_path):
    path = tmp_path / "station.yaml"
    path.write_bytes(bytes(range(256)))
    out = subprocess.run([sys.executable, "-m", "station.cli", "--config", str(path), "history"],
                         capture_output=True, text=True)
    assert out.returncode == 2 and "is not text: byte 128 is not UTF-8" in out.stderr
    assert "Traceback" not in out.stderr and "internal error" not in out.stderr


def test_cli_reports_config_errors_without_traceback(tmp_path):
    path = _write(tmp_path, lambda d: d["cameras"]["cam3"].update(role="main"))
    out = subprocess.run([sys.executable, "-m", "station.cli", "--config", str(path), "errors"],
                         capture_output=True, text=True)
    # `errors` does not load the config; commands that do are tested by their own suites.
    assert out.returncode == 0 and "Traceback" not in out.stderr


def test_the_5mp_station_is_the_default_station_with_twice_the_resolution_and_focal_length():
    """config/station-5mp.yaml must not drift from config/station.yaml: same mounts, lenses,
    limits and vehicle; only the sensor (2560x2048), the focal lengths, the data dir, the
    unseen-error terms of the stated uncertainty (each station's own maximum likelihood) and
    the frames averaged per cycle (each station's figures were measured so) differ."""
    base = yaml.safe_load(DEFAULT_CONFIG.read_text())
    big = yaml.safe_load((DEFAULT_CONFIG.parent / "station-5mp.yaml").read_text())
    assert big["camera_defaults"]["resolution"] == [2 * v for v in base["camera_defaults"]["resolution"]]
    for cid, cam in base["cameras"].items():
        assert big["cameras"][cid]["nominal"]["focal_px"] == 2 * cam["nominal"]["focal_px"]
        big["cameras"][cid]["nominal"]["focal_px"] = cam["nominal"]["focal_px"]
    big["camera_defaults"]["resolution"] = base["camera_defaults"]["resolution"]
    assert big["data_dir"] != base["data_dir"]  # its own calibration and history
    for key in ("uncertainty_floor_deg", "uncertainty_light_gain", "uncertainty_toe_scale", "uncertainty_blur_gain"):
        big["measurement"].pop(key, None), base["measurement"].pop(key, None)
    big["capture"].pop("frames_averaged", None), base["capture"].pop("frames_averaged", None)  # measured so
    for key in ("name", "data_dir"):
        big.pop(key), base.pop(key)
    assert big == base
    cfg = load_config(DEFAULT_CONFIG.parent / "station-5mp.yaml")
    assert (cfg.cameras["cam1"].width, cfg.cameras["cam1"].height) == (2560, 2048)
