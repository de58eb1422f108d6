"""The metal-side test (station/rim/metal_side.py): an edge whose bright side is a lit line on
the tyre, not the rim's metal, and the share of a detected rim on arcs of such edges."""

from __future__ import annotations

import numpy as np

from station.rim.ellipse import Ellipse
from station.rim.metal_side import dark_side_share, metal_brighter, wrong_arcs
from station.rim.preprocess import PixelMap

CENTRE = np.array([200.0, 200.0])
RADIUS = 120.0
METAL, TYRE, LINE = 150.0, 20.0, 160.0


def _wheel(glow_from_deg: float | None = None, glow_to_deg: float | None = None) -> np.ndarray:
    """(400,400) float32: a disc of metal inside RADIUS on dark tyre; between the two angles
    (image angle about the centre, 0 right, 90 down) the lip's edge is shaded to the tyre's
    level and the tyre's shoulder is lit: a bright line peaking 2 px outside the flange, fading
    outward over a few pixels (its half-height about 4 px out)."""
    y, x = np.mgrid[0:400, 0:400].astype(float)
    r = np.hypot(x - CENTRE[0], y - CENTRE[1])
    ang = np.degrees(np.arctan2(y - CENTRE[1], x - CENTRE[0])) % 360
    img = np.where(r < RADIUS, METAL, TYRE)
    if glow_from_deg is not None:
        on = (ang >= glow_from_deg) & (ang < glow_to_deg)
        lip = on & (r < RADIUS) & (r > RADIUS - 8)
        img = np.where(lip, TYRE, img)
        line = on & (r >= RADIUS) & (r < RADIUS + 20)
        img = np.where(line, TYRE + (LINE - TYRE) * np.exp(-np.abs(r - RADIUS - 2.0) / 3.0), img)
    return img.astype(np.float32)


def _ring(radius: float, n: int = 720) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (n,2) on a circle of ``radius``, their outward normals (n,2) and angles (n,) rad."""
    a = (np.arange(n) + 0.5) * 2 * np.pi / n
    normals = np.stack([np.cos(a), np.sin(a)], axis=1)
    return CENTRE + radius * normals, normals, a


def test_a_plain_rim_edge_has_metal_on_its_bright_side():
    pts, nrm, _ = _ring(RADIUS - 0.5)
    assert metal_brighter(_wheel(), pts, nrm).all()


def test_the_outer_fall_of_a_lit_tyre_line_is_not_a_rim_edge():
    img = _wheel(90.0, 180.0)
    pts, nrm, a = _ring(RADIUS + 4.0)  # the lit line's outer fall, where a step detector finds an edge
    on = (np.degrees(a) > 95) & (np.degrees(a) < 175)
    bright = metal_brighter(img, pts, nrm)
    assert not bright[on].any()
    edge, nrm_e, a_e = _ring(RADIUS - 0.5)
    off = (np.degrees(a_e) < 80) | (np.degrees(a_e) > 190)
    assert metal_brighter(img, edge, nrm_e)[off].all()


def test_an_arc_of_failing_points_is_a_wrong_arc_and_only_it():
    a = (np.arange(3600) + 0.5) * 2 * np.pi / 3600
    bright = np.ones(3600, bool)
    bright[(np.degrees(a) >= 100) & (np.degrees(a) < 140)] = False
    wrong = wrong_arcs(a, bright)
    deg = np.degrees(a)
    assert wrong[(deg >= 100) & (deg < 140)].all()
    assert not wrong[(deg < 100) | (deg >= 140)].any()


def test_scattered_failures_are_noise_not_a_wrong_arc():
    rng = np.random.default_rng(3)
    a = np.sort(rng.uniform(0, 2 * np.pi, 2000))
    bright = rng.uniform(size=2000) > 0.1   # one point in ten, everywhere
    assert not wrong_arcs(a, bright).any()


def test_the_dark_side_share_of_a_detection_is_its_lit_line_arc():
    img = _wheel(90.0, 150.0)
    e = Ellipse(center_px=CENTRE, axes_px=np.array([RADIUS + 4.0, RADIUS + 4.0]), angle_rad=0.0)
    pts, _, a = _ring(RADIUS + 4.0)
    deg = np.degrees(a)
    inside = (deg > 90) & (deg < 150)   # there the detector followed the lit line's fall
    pts = np.where(inside[:, None], pts, CENTRE + (RADIUS - 0.5) * (pts - CENTRE) / (RADIUS + 4.0))
    assert abs(dark_side_share(img, e, pts, PixelMap(None)) - 60 / 360) < 0.03
    assert dark_side_share(_wheel(), e, CENTRE + (RADIUS - 0.5) * (pts - CENTRE) / np.linalg.norm(
        pts - CENTRE, axis=1, keepdims=True), PixelMap(None)) == 0.0
