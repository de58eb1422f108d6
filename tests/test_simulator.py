"""The simulated station: exact geometry, unbiased anti-aliasing, determinism, the CLI."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calibration.camera_model import CameraModel, look_at
from simulators.render import lattice_offsets, render, render_radiance
from simulators.scene import Lighting, Scene, TexturedQuad
from simulators.vehicle import Vehicle, WheelGeometry
from station.config import load_config
from simulators.world import SimWorld

FLAT = Lighting(ambient=1.0, key_strength=0.0, vignetting=0.0, gain=1.0, background_level=0.0)


def small_camera(dist=(0, 0, 0, 0, 0), width=160, height=128, f=600.0, position=(0.0, 0.0, 1.0),
                 target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)):
    R, t = look_at(np.array(position, float), np.array(target, float), np.array(up, float))
    K = np.array([[f, 0, (width - 1) / 2 + 3.3], [0, f, (height - 1) / 2 - 2.1], [0, 0, 1]])
    return CameraModel("test", width, height, K, np.array(dist, float), R, t)


def white_disc_quad(center, radius, normal_axis=2, texels=64):
    """A square quad with a white texture (the quad itself is the bright shape)."""
    c = np.asarray(center, float)
    e = radius
    corners = c + np.array([[-e, e, 0], [e, e, 0], [e, -e, 0], [-e, -e, 0]])
    return TexturedQuad(corners, np.full((texels, texels), 255, np.uint8), 1.0)


def test_lattice_has_distinct_levels_and_centred_mean():
    off = lattice_offsets(34)
    assert len(np.unique(np.round(off[:, 0], 9))) == 34
    assert len(np.unique(np.round(off[:, 1], 9))) == 34
    np.testing.assert_allclose(off.mean(axis=0), 0, atol=1e-12)


def test_determinism_and_gain():
    cam = small_camera()
    scene = Scene(quads=(white_disc_quad((0.0, 0.0, 0.2), 0.05),))
    a = render(cam, scene, Lighting(), np.random.default_rng(5), 2.0)
    b = render(cam, scene, Lighting(), np.random.default_rng(5), 2.0)
    c = render(cam, scene, Lighting(), np.random.default_rng(6), 2.0)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    dark = render(cam, scene, replace(Lighting(), gain=0.8), np.random.default_rng(5), 2.0)
    ratio = dark.astype(float).mean() / a.astype(float).mean()
    assert 0.76 < ratio < 0.84
