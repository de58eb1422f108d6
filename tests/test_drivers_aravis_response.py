"""The Aravis driver makes a camera's grey response linear where its GenICam features allow
(a stand-in camera: the emulator has no Gamma or LUT feature)."""

from __future__ import annotations

import pytest

from drivers.aravis import make_linear
from drivers.errors import DriverError


class _Cam:
    """The few ArvCamera calls make_linear uses, on a dict of features; ``locked`` refuse writes."""

    def __init__(self, features: dict, locked=(), unreadable=()):
        self.features, self.locked, self.unreadable = dict(features), set(locked), set(unreadable)

    def is_feature_available(self, name):
        return name in self.features

    def get_boolean(self, name):
        if name in self.unreadable:
            raise RuntimeError(f"{name} is an integer node")  # GLib.Error in Aravis
        return self.features[name]

    get_float = get_boolean

    def set_boolean(self, name, value):
        if name in self.locked:
            raise RuntimeError(f"{name} is not writable")  # GLib.Error in Aravis
        self.features[name] = value

    set_float = set_boolean


def test_gamma_and_lut_are_switched_off():
    cam = _Cam({"LUTEnable": True, "GammaEnable": True, "Gamma": 0.45, "ExposureTime": 8000.0})
    assert make_linear(cam, "cam3", "192.0.2.3") == ["LUTEnable", "GammaEnable"]
    assert cam.features == {"LUTEnable": False, "GammaEnable": False, "Gamma": 0.45, "ExposureTime": 8000.0}
    plain = _Cam({"Gamma": 0.7})                       # no enable switch: the exponent itself
    assert make_linear(plain, "cam3", "192.0.2.3") == ["Gamma"] and plain.features["Gamma"] == 1.0


def test_a_linear_camera_or_one_without_the_features_is_left_alone():
    assert make_linear(_Cam({"ExposureTime": 8000.0}), "cam3", "192.0.2.3") == []
    assert make_linear(_Cam({"Gamma": 1.0, "LUTEnable": False}), "cam3", "192.0.2.3") == []
    # unreadable (a node of another type): nothing known to undo, nothing refused
    assert make_linear(_Cam({"Gamma": 45}, unreadable={"Gamma"}), "cam3", "192.0.2.3") == []
    # switched off, its locked exponent does not apply
    assert make_linear(_Cam({"GammaEnable": False, "Gamma": 0.45}, locked={"Gamma"}), "cam3", "192.0.2.3") == []


def test_a_camera_that_refuses_the_linear_setting_is_named_with_the_remedy():
    cam = _Cam({"Gamma": 0.45}, locked={"Gamma"})
    with pytest.raises(DriverError, match="cam3: the camera at 192.0.2.3 does not let Gamma be set to 1.0") as e:
        make_linear(cam, "cam3", "192.0.2.3")
    assert "cameras.cam3.response_gamma" in e.value.hint


def test_the_configured_response_reaches_the_driver(tmp_path):
    from station.capture.cameras import settings_for
    from tests.station_fixtures import small_station_config

    cfg = small_station_config(tmp_path, camera_defaults__response_gamma=0.45)
    assert settings_for(cfg.cameras["cam3"]).response_gamma == 0.45
    (tmp_path / "b").mkdir()
    assert settings_for(small_station_config(tmp_path / "b").cameras["cam3"]).response_gamma == 1.0
