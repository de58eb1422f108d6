"""The ellipse vote (station/rim/hough.py) on edge pixels of known concentric contours."""

import numpy as np

from station.rim import hough
from station.rim.edges import EdgeSet

CENTRE = np.array([240.3, 170.6])


def _circle_edges(radii, rng, shown=None) -> EdgeSet:
    """Edge pixels a pixel apart on concentric circles, brighter inside (gradient inward);
    shown: per circle, the share of its perimeter with edges (the rest in 12 gaps)."""
    pts, grad = [], []
    for k, r in enumerate(radii):
        t = np.arange(0, 2 * np.pi, 1.0 / r)
        if shown is not None:
            t = t[np.mod(t, 2 * np.pi / 12) < shown[k] * 2 * np.pi / 12]
        u = np.stack([np.cos(t), np.sin(t)], axis=1)
        pts.append(CENTRE + r * u + rng.normal(0, 0.3, u.shape))
        grad.append(-u)
    p, g = np.concatenate(pts), np.concatenate(grad)
    return EdgeSet(np.round(p), g, np.full(len(p), 50.0), (341, 480))


def test_two_contours_five_pixels_apart_are_two_candidates():
    """A narrow lip: the flange edge and the lip's inner edge 5 px apart at the search scale.
    A band of 5 % of the size around one takes in the other, and a consensus on that band
    alone keeps the one with more pixels for both sizes, leaving the flange no candidate at
    all: both sizes must come out as candidates."""
    edges = _circle_edges((112.0, 117.0, 37.0), np.random.default_rng(4), shown=(1.0, 0.8, 1.0))
    cands = hough.find_candidates(edges, 12.0, 240.0)
    sizes = sorted(c.ellipse.axes_px[0] for c in cands if c.coverage > 0.6)
    for r in (112.0, 117.0):
        assert min(abs(np.array(sizes) - r)) < 0.6, sizes
    near = [c for c in cands if abs(c.ellipse.axes_px[0] - 117.0) < 0.6]
    assert np.linalg.norm(near[0].ellipse.center_px - CENTRE) < 0.3


def test_a_lone_contour_keeps_the_wide_band():
    edges = _circle_edges((112.0,), np.random.default_rng(5))
    cands = hough.find_candidates(edges, 12.0, 240.0)
    assert len(cands) >= 1 and abs(cands[0].ellipse.axes_px[0] - 112.0) < 0.5 and cands[0].coverage > 0.95
