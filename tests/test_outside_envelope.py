"""bench/outside_envelope.py: each scenario changes what it says and nothing else."""

import numpy as np
import pytest

from bench import outside_envelope as oe
from tests.station_fixtures import small_station_config


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    from simulators.world import SimWorld

    cfg = small_station_config(tmp_path_factory.mktemp("station"))
    return cfg, SimWorld.from_config(cfg)


def test_each_scenario_changes_its_own_quantity_on_the_same_car(world):
    cfg, w = world
    plain = oe.scene_for(w, None, 1000, cfg.nominal_vehicle)
    lip = oe.scene_for(w, "narrow-lip", 1000, cfg.nominal_vehicle)
    assert 0.004 <= lip.vehicle.wheel.flange_width_m <= 0.008
    assert lip.vehicle.toe_deg == plain.vehicle.toe_deg and lip.vehicle.wheel.rim_radius_m == plain.vehicle.wheel.rim_radius_m
    harsh = oe.scene_for(w, "harsh-light", 1000, cfg.nominal_vehicle)
    assert all(0.05 <= light.ambient <= 0.12 and 1.0 <= light.key_strength <= 1.4 for light in harsh.lighting.values())
    assert harsh.vehicle == plain.vehicle
    diffuse = oe.scene_for(w, "diffuse-light", 1000, cfg.nominal_vehicle)
    assert all(0.45 <= light.ambient <= 0.75 and light.key_strength <= 0.15 for light in diffuse.lighting.values())
    assert diffuse.vehicle == plain.vehicle and "diffuse-light" in oe.KINDS


def test_soft_focus_sets_the_lenses_and_the_next_scenario_restores_them(world):
    cfg, w = world
    own = dict(w.blur_sigma)
    oe.scene_for(w, "soft-focus", 1000, cfg.nominal_vehicle)
    assert all(1.3 <= b <= 2.0 for b in w.blur_sigma.values())
    oe.scene_for(w, None, 1001, cfg.nominal_vehicle)
    assert w.blur_sigma == own


def test_gamma_encodes_the_images_and_gamma_known_tells_the_station(world):
    cfg, _ = world
    img = {"cam1": np.array([[0, 64, 128, 255]], np.uint8)}
    enc = oe.encode("gamma", img)["cam1"]
    assert enc[0, 0] == 0 and enc[0, -1] == 255 and np.all(enc[0, 1:3] > img["cam1"][0, 1:3])  # darks lifted
    assert oe.encode(None, img) is img
    told = oe.configured("gamma-known", cfg)
    assert all(c.response_gamma == pytest.approx(1 / 2.2) for c in told.cameras.values())
    assert all(c.response_gamma == 1.0 for c in cfg.cameras.values())      # the original untouched
    assert oe.images_of("gamma-known") == "gamma" and oe.configured("gamma", cfg) is cfg
