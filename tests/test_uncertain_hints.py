"""Which camera a refused wheel's message names when its two views disagree (station/stated_uncertainty.py,
``_edge_off``): the one whose lip is at the sensor's white, else the one whose edge is not the
rim's on some arcs (station/rim/metal_side.py), else the fainter one; both where both show it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from station.config import load_config
from station.stated_uncertainty import _edge_off


def _pair(white=(0.0, 0.0), dark=(0.0, 0.0), steps=(50.0, 20.0)):
    dets = [SimpleNamespace(details={"white_share": w, "metal_side_dark_share": d},
                            points_contrast=np.full(100, s)) for w, d, s in zip(white, dark, steps)]
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
