"""Which camera a refused wheel's message names when its two views disagree (station/stated_uncertainty.py,
``_edge_off``): the one whose lip is at the sensor's white, else the one whose edge is not the
rim's on some arcs (station/rim/metal_side.py), else the fainter one; both where both show it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from station.config import load_config
from station.stated_uncertainty import _edge_off


def _pair(white=(0.0, 0.0), dark=(0.0, 0.0), steps=(50.0, 20.0), blur=(0.9, 0.9)):
    dets = [SimpleNamespace(details={"white_share": w, "metal_side_dark_share": d, "blur_px": b},
                            points_contrast=np.full(100, s)) for w, d, s, b in zip(white, dark, steps, blur)]
    return SimpleNamespace(cams=("cam3", "cam4"), detections=dets)


CONFIG = load_config()


def test_a_lip_at_the_white_names_its_camera_and_the_exposure():
    why, hint, reason = _edge_off(_pair(white=(0.05, 0.73), dark=(0.3, 0.0)), CONFIG)
    assert "73% of cam4's" in why and "white" in why and "cam3" not in why and reason == "white_lip"
    assert "Shorten cam4's exposure (or its gain)" in hint


def test_lips_at_the_white_in_both_views_alike_are_not_the_cause_named():
    # a polished lip mirroring lamps: both cameras at the white in spots
    why, _, _ = _edge_off(_pair(white=(0.30, 0.20), dark=(0.0, 0.12)), CONFIG)
    assert "white" not in why and "12% of cam4's rim the lip is no brighter" in why


def test_a_lip_no_brighter_than_the_tyre_names_its_camera_and_the_light():
    why, hint, reason = _edge_off(_pair(dark=(0.0, 0.27)), CONFIG)
    assert "27% of cam4's rim the lip is no brighter than the tyre" in why and "cam3" not in why
    assert reason == "dark_lip"
    assert "cam4" in hint and "Shade the wheel" in hint


def test_both_cameras_are_named_where_both_show_it_the_larger_share_first():
    why, _, _ = _edge_off(_pair(dark=(0.12, 0.31)), CONFIG)
    assert why.index("31% of cam4's") < why.index("12% of cam3's")


def test_without_either_the_fainter_edge_is_named():
    why, hint, reason = _edge_off(_pair(white=(0.1, 0.3)), CONFIG)  # apart by less than the white-edge limit
    assert why == "the fainter edge is cam4's" and "cam4 a longer exposure" in hint and reason == "faint_view"


def test_a_view_blurred_beyond_the_focus_limit_is_named_before_the_fainter_one():
    why, hint, reason = _edge_off(_pair(blur=(1.7, 1.0)), CONFIG)
    assert why == "cam3's edge is blurred over 1.7 px, beyond the 1.3 px focus limit" and hint.startswith("Refocus cam3 ")
    assert reason == "faint_view"
    why, hint, _ = _edge_off(_pair(blur=(1.5, 1.9)), CONFIG)
    assert why.startswith("cam4's edge is blurred over 1.9 px") and "Refocus cam3 and cam4 " in hint


def _blurred_wheel(blur=(0.9, 1.0), rms_px=0.06, axes_px=(300.0, 290.0)):
    from station.rim.ellipse import Ellipse

    dets = [SimpleNamespace(details={"blur_px": b}, ellipse=Ellipse(np.array([640.0, 512.0]), axes_px, 0.0),
                            points_contrast=np.full(100, 30.0), points_px=np.zeros((100, 2))) for b in blur]
    return SimpleNamespace(cams=("cam3", "cam4"), detections=dets, views=None,
                           circle=SimpleNamespace(reprojection_rms_px=rms_px, n_points=(100, 100),
                                                  axis_station=np.array([0.0, 1.0, 0.0])))


def test_a_blur_beyond_the_focus_limit_adds_to_what_no_residual_shows(monkeypatch):
    """The blur part of the unseen variance: (gain x the blurrier view's blur beyond the limit /
    the rim's semi-axis)^2, nothing for views within the limit (sharp stations measure as without it)."""
    from station.stated_uncertainty import unseen_axis_variance

    config = load_config()
    m = config.measurement
    assert m.uncertainty_blur_gain > 0 and m.edge_blur_limit_px == 1.3
    sharp = unseen_axis_variance(_blurred_wheel(), config)
    assert sharp == unseen_axis_variance(_blurred_wheel(blur=(1.3, 0.5)), config)  # at the limit: nothing added
    soft = unseen_axis_variance(_blurred_wheel(blur=(1.9, 1.5)), config)
    a = np.sqrt(300.0 * 290.0)
    assert soft - sharp == pytest.approx((m.uncertainty_blur_gain * 0.6 / a) ** 2, rel=1e-9)
    monkeypatch.setattr(m, "uncertainty_blur_gain", 0.0)
    assert unseen_axis_variance(_blurred_wheel(blur=(1.9, 1.5)), config) == sharp


def test_a_faint_edge_that_is_blurred_names_the_camera_to_refocus(monkeypatch):
    import station.stated_uncertainty as su

    monkeypatch.setattr(su, "statement_parts", lambda *a, **k: {"views": 0.0, "calibration": 0.0, "noise": 1.0,
                                                                "edge": 0.0})
    why, hint, reason = su._why_uncertain(_blurred_wheel(blur=(1.0, 1.8)), "toe", 0.1, CONFIG)
    assert reason == "faint_edge" and "cam4's edge is blurred over 1.8 px, beyond the 1.3 px focus limit" in why
    assert "cam3's edge" not in why and hint.startswith("Refocus cam4 ")
    why, hint, _ = su._why_uncertain(_blurred_wheel(), "toe", 0.1, CONFIG)
    assert "blurred" not in why and "Refocus" not in hint
