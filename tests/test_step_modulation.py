"""How unevenly the lip's edge step is lit round the rim (station/rim/subpixel.py,
``step_modulation``), and what it adds to a wheel's stated uncertainty
(station/stated_uncertainty.py, ``unseen_axis_variance``)."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from station.config import load_config
from station.rim.subpixel import step_modulation


def test_the_once_round_part_of_the_step_over_its_mean():
    t = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    assert step_modulation(t, np.full(360, 40.0)) == pytest.approx(0.0, abs=1e-12)
    assert step_modulation(t, 40.0 * (1 + 0.35 * np.cos(t - 1.2))) == pytest.approx(0.35, rel=1e-9)
    # twice round (a lamp mirrored on two sides) is not once round
    assert step_modulation(t, 40.0 * (1 + 0.35 * np.cos(2 * t))) == pytest.approx(0.0, abs=1e-9)
    assert step_modulation(t[:7], np.full(7, 40.0)) == 0.0


def test_a_gap_in_the_turn_is_not_read_as_modulation():
    """The points a view keeps leave arcs out; an evenly lit step over what is left is still
    even (a mean of c e^{-it} over half the turn would read 0.64)."""
    t = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    half = t[(t > 0.3) & (t < 0.3 + np.pi)]
    assert step_modulation(half, np.full(len(half), 25.0)) == pytest.approx(0.0, abs=1e-9)
    lit = 25.0 * (1 + 0.4 * np.sin(half))
    assert step_modulation(half, lit) == pytest.approx(0.4 * 25.0 / np.mean(lit), rel=1e-6)


def test_a_fit_over_part_of_the_turn_is_held_to_a_step_lit_on_one_half():
    """Points on a third of the turn whose step falls steeply: the harmonic's amplitude,
    extrapolated over the rest, is held at pi/2 (lit on one half, unlit on the other)."""
    t = np.linspace(-1.0, 1.0, 200)
    assert step_modulation(t, 40.0 + 60.0 * t) == pytest.approx(np.pi / 2)


def _wheel(modulation=(0.4, 0.3), axes_px=(300.0, 290.0)):
    from station.rim.ellipse import Ellipse

    dets = [SimpleNamespace(details={"blur_px": 0.9, "step_modulation": m},
                            ellipse=Ellipse(np.array([640.0, 512.0]), axes_px, 0.0)) for m in modulation]
    return SimpleNamespace(cams=("cam3", "cam4"), detections=dets, views=None,
                           circle=SimpleNamespace(reprojection_rms_px=0.06, axis_station=np.array([0.0, 1.0, 0.0])))


def test_an_unevenly_lit_lip_adds_to_what_no_residual_shows(monkeypatch):
    """(gain x the views' mean modulation x the circle's reprojection RMS / the rim's
    semi-axis)^2 rad^2, twice the RMS four times the variance; an evenly lit lip adds nothing,
    and without the gain nothing either."""
    from station.stated_uncertainty import unseen_axis_variance

    config = load_config()
    m = config.measurement
    assert m.uncertainty_light_gain > 0
    even = unseen_axis_variance(_wheel(modulation=(0.0, 0.0)), config)
    lamp = unseen_axis_variance(_wheel(modulation=(0.4, 0.3)), config)
    a = np.sqrt(300.0 * 290.0)
    assert lamp - even == pytest.approx((m.uncertainty_light_gain * 0.35 * 0.06 / a) ** 2, rel=1e-9)
    noisier = _wheel(modulation=(0.4, 0.3))
    noisier.circle.reprojection_rms_px = 0.12
    assert unseen_axis_variance(noisier, config) - even == pytest.approx(4 * (lamp - even), rel=1e-9)
    monkeypatch.setattr(m, "uncertainty_light_gain", 0.0)
    assert unseen_axis_variance(_wheel(modulation=(0.4, 0.3)), config) == even
    # a detection made before the modulation was kept (an old recording) counts as evenly lit
    old = _wheel()
    for d in old.detections:
        d.details.pop("step_modulation")
    assert unseen_axis_variance(old, config) == even


@pytest.mark.slow
def test_a_lamp_on_one_side_modulates_the_step_and_diffuse_panels_do_not(tmp_path):
    """One camera of the small station, its rim lit by a strong lamp from above, then by an even
    surround: the detector's modulation tells them apart by several times."""
    from simulators.world import SimWorld
    from station.rim import detect_rim
    from tests.station_fixtures import small_station_config

    cfg = small_station_config(tmp_path)
    world = SimWorld.from_config(cfg)
    base = world.vehicle_scene(3)
    cam = "cam3"
    found = {}
    for name, light in (("lamp", dict(ambient=0.1, key_direction_station=(0.1, -0.2, -0.97), key_strength=1.1)),
                        ("panels", dict(ambient=0.7, key_strength=0.0))):
        scene = replace(base, lighting={**base.lighting, cam: replace(base.lighting[cam], **light)})
        image = world.render(cam, np.random.default_rng(1), scene=scene)
        found[name] = detect_rim(image, camera=world.cameras[cam], camera_id=cam).details["step_modulation"]
    assert found["panels"] < 0.1
    assert found["lamp"] > 3 * found["panels"]
