"""Small stand-ins for the camera tests: a world that renders in microseconds, a config.

FakeWorld has SimWorld's interface as SimCamera uses it (``cameras[id].width/height``,
``config.simulation.station_seed``, ``render(cam_id, rng)``) and renders pure noise from the
given rng, so frame determinism is checkable exactly. ``delay`` makes a camera slow, ``dead``
makes its render fail.
"""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from station.config import DEFAULT_CONFIG, load_config

IDS = [f"cam{i}" for i in range(1, 9)]


class FakeWorld:
    def __init__(self, ids=IDS, width=40, height=30, seed=7, delay=None):
        self.cameras = {cid: SimpleNamespace(width=width, height=height) for cid in ids}
        self.config = SimpleNamespace(simulation=SimpleNamespace(station_seed=seed))
        self.delay = dict(delay or {})
        self.dead: set[str] = set()
        self.renders = 0

    def render(self, cam_id, rng=None, exposure=1.0):
        if cam_id in self.dead:
            raise RuntimeError("sensor fault")
        time.sleep(self.delay.get(cam_id, 0.0))
        self.renders += 1
        c = self.cameras[cam_id]
        return rng.integers(0, 256, (c.height, c.width), dtype=np.uint8)


def station_config(tmp_path: Path, uris: dict[str, str] | None = None, width=40, height=30, extra=""):
    """The default station configuration with other URIs / resolution, loaded from tmp_path."""
    text = DEFAULT_CONFIG.read_text()
    for cid, uri in (uris or {}).items():
        text = text.replace(f'"sim://{cid}"', f'"{uri}"')
    text = text.replace("resolution: [1280, 1024]", f"resolution: [{width}, {height}]")
    text = text.replace("data_dir: ../var", f"data_dir: {tmp_path / 'var'}") + extra
    path = tmp_path / "station.yaml"
    path.write_text(text)
    return load_config(path)
