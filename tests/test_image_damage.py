"""A damaged image (simulators/image_damage.py) never ends a cycle in a traceback: the cycle is
valid or refused with a reason, and the damages the station can see are named."""

import numpy as np
import pytest

from simulators.image_damage import KINDS, damage
from calibration.station_frame import WHEELS
from station.measure import measure_frames
from station.plc.results import result_station_warning_bits
from station.result import WarningFlag
from tests.station_fixtures import rendered_small_station


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    cfg, world, _, images = rendered_small_station(tmp_path_factory.mktemp("station"), seed=3)
    return cfg, world, images


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_damaged_image_is_measured_or_refused_never_a_traceback(sim, kind):
    cfg, world, images = sim
    damaged = dict(images, cam6=damage(images["cam6"], kind, np.random.default_rng(1)))
    assert damaged["cam6"].dtype == np.uint8 and damaged["cam6"].shape == images["cam6"].shape
    assert not np.array_equal(damaged["cam6"], images["cam6"])
    result = measure_frames(damaged, world.cameras, cfg)
    if not result.valid:
        assert result.failure.message
        return
    for w in WHEELS:
        assert np.isfinite(result.wheels[w].toe_deg) and np.isfinite(result.wheels[w].camber_deg)
    if kind == "over-exposed":
        assert any(x.startswith("RL cam6: ") and "sensor's white" in x for x in result.warnings), result.warnings
        assert WarningFlag("exposure", "RL", camera="cam6") in result.warning_flags
        assert result_station_warning_bits(result) & (1 << 1)  # the PLC's "a camera at the white"
    if kind == "soft-focus":
        assert WarningFlag("focus", "RL", camera="cam6") in result.warning_flags, result.warnings
        assert result_station_warning_bits(result) & (1 << 2)
    if kind == "knocked":  # the pair cannot agree: a drift warning for RL (or a refusal, above)
        assert WarningFlag("drift", "RL") in result.warning_flags, result.warnings


def test_an_unknown_damage_is_named():
    with pytest.raises(ValueError, match="unknown damage 'rain'"):
        damage(np.zeros((4, 4), np.uint8), "rain", np.random.default_rng(0))
