"""Helpers for tests that need a small simulated station (half resolution: 640x512, f/2)."""

from __future__ import annotations

from pathlib import Path

import yaml

from station.config import DEFAULT_CONFIG, load_config


def small_station_config(tmp_path: Path, scale: float = 0.5, **overrides):
    """A copy of config/station.yaml with every camera at ``scale`` resolution and focal length.

    Its rims span ``scale`` times the pixels and its cycles are single frames: it states toe
    and camber uncertainties of 0.02-1.6 deg where the built-in station states 0.003-0.03, so
    its ``measurement.uncertainty_limit_deg`` is 5 deg, leaving its cycles valid for the tests
    of everything else; the tests of the refusal set their own limit. Its single frames' rim edges carry the noise's
    slowly varying share as well: clean rims' two views differ by up to 0.12 px's worth of edge
    bias (vehicles 3, 5 and 7, one wheel in twelve beyond), so ``view_edge_bias_px`` is 0.15."""
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["measurement"].update(uncertainty_limit_deg=5.0, view_edge_bias_px=0.15)
    w, h = data["camera_defaults"]["resolution"]
    data["camera_defaults"]["resolution"] = [int(w * scale), int(h * scale)]
    for cam in data["cameras"].values():
        cam["nominal"]["focal_px"] = cam["nominal"]["focal_px"] * scale
    data["data_dir"] = str(tmp_path / "var")
    data["vehicle_specs"] = str(DEFAULT_CONFIG.parent / data.get("vehicle_specs", "vehicles.yaml"))
    data["calibration"]["box"] = str(DEFAULT_CONFIG.parent / data["calibration"].get("box", "box.yaml"))
    for key, value in overrides.items():
        section, name = key.split("__")
        data.setdefault(section, {})[name] = value
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_config(path)


def rendered_small_station(tmp_path: Path, seed: int = 3):
    """(config, SimWorld, scene, {camera: image}): vehicle ``seed`` on the small station, rendered."""
    import numpy as np

    from simulators.world import SimWorld

    cfg = small_station_config(tmp_path)
    world = SimWorld.from_config(cfg)
    scene = world.vehicle_scene(seed)
    world.set_scene(scene)
    return cfg, world, scene, world.render_all(np.random.default_rng(seed))


def truth_calibration(config):
    """Save the simulated station's true cameras as its calibration file (no box calibration)."""
    from calibration.calib_file import CameraCalibration, StationCalibration, save_calibration
    from simulators.world import SimWorld

    world = SimWorld.from_config(config)
    cams = {c: CameraCalibration(m, 0.1, 1000, {}) for c, m in world.cameras.items()}
    calib = StationCalibration(cams, {w: (p.precision, p.reference) for w, p in config.pairs.items()},
                               station_name=config.name)
    config.calibration_file.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(calib, config.calibration_file)
    return calib


def nominal_calibration(config, seed: int = 2):
    """A calibration of ``config``'s cameras at their nominal poses, with plausible intrinsics
    (fx about 1800 px at 1280x1024), distortion and standard deviations (not saved)."""
    import numpy as np

    from calibration.calib_file import CameraCalibration, StationCalibration
    from calibration.camera_model import CameraModel, look_at

    cams = {}
    rng = np.random.default_rng(seed)
    for cam_id, c in config.cameras.items():
        R, t = look_at(np.array(c.nominal.position_m), np.array(c.nominal.look_at_m))
        K = np.array([[1800 + rng.normal(0, 10), 0, 640 + rng.normal(0, 5)], [0, 1801.0, 512.3], [0, 0, 1]])
        dist = np.array([-0.1, 0.05, 1e-4, -2e-4, 0.01]) * rng.uniform(0.5, 1.5)
        cams[cam_id] = CameraCalibration(CameraModel(cam_id, c.width, c.height, K, dist, R, t), 0.11, 3000,
                                         {"fx": 0.08, "fy": 0.08, "position_m": [1e-5, 2e-5, 3e-5]})
    pairs = {w: (p.precision, p.reference) for w, p in config.pairs.items()}
    return StationCalibration(cams, pairs, station_name=config.name)
