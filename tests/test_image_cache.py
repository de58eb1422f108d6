"""Rendered-image caches are read back only by the station that rendered them."""

import numpy as np
import yaml

from simulators import image_cache
from simulators.world import SimWorld
from station.config import load_config
from tests.station_fixtures import small_station_config


def _images(world):
    return {c: np.full((4, 5), i, np.uint8) for i, c in enumerate(world.cameras)}


def test_a_cache_is_read_back_by_its_own_world(tmp_path):
    world = SimWorld.from_config(small_station_config(tmp_path))
    path = tmp_path / "cache" / "sigma2-1000.npz"
    image_cache.save(path, _images(world), world)
    got = image_cache.load(path, world)
    assert set(got) == set(world.cameras)
    assert all(np.array_equal(got[c], im) for c, im in _images(world).items())
    assert not list(path.parent.glob(".*part*"))  # no temporary file left behind


def test_another_layout_lens_or_noise_renders_again(tmp_path):
    world = SimWorld.from_config(small_station_config(tmp_path))
    path = tmp_path / "sigma2-1000.npz"
    image_cache.save(path, _images(world), world)
    moved = yaml.safe_load((tmp_path / "station.yaml").read_text())
    moved["cameras"]["cam2"]["nominal"]["position_m"][1] += 0.3  # one camera mounted elsewhere
    (tmp_path / "moved.yaml").write_text(yaml.safe_dump(moved))
    assert image_cache.load(path, SimWorld.from_config(load_config(tmp_path / "moved.yaml"))) is None
    assert image_cache.load(path, SimWorld.from_config(small_station_config(tmp_path, scale=0.25))) is None
    assert image_cache.load(path, SimWorld.from_config(small_station_config(tmp_path), noise_sigma=5.0)) is None
    assert image_cache.load(path, SimWorld.from_config(small_station_config(tmp_path))) is not None


def test_unstamped_missing_or_broken_files_are_not_read(tmp_path):
    world = SimWorld.from_config(small_station_config(tmp_path))
    old = tmp_path / "old.npz"
    np.savez(old, **_images(world))  # written before the stamp existed: origin unknown
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"PK\x03\x04 not really a zip")
    assert image_cache.load(old, world) is None
    assert image_cache.load(broken, world) is None
    assert image_cache.load(tmp_path / "missing.npz", world) is None
