"""A simulated toe adjustment for `station live`: pre-rendered frames served with fresh noise.

Rendering one 1280x1024 frame takes seconds, far too slow for a 10 Hz live display. So the
adjustment is simulated honestly in two parts:

1. :func:`prerender` renders, once, the noise-free frames of a short sequence in which one
   wheel's toe is stepped through an adjustment (``toe_steps_deg``): every camera at step 0
   (the whole vehicle, for the car frame) and the live cameras at every step. The frames are
   cached on disk (an .npz per step, keyed by everything that changes them).
2. :class:`AdjustmentWorld` stands in for the SimWorld behind the sim:// cameras: each camera's
   k-th frame is step ``k // hold`` of the sequence, played forwards then backwards (a tie rod
   turned in and out), plus fresh Gaussian sensor noise, so the live loop detects and measures
   every frame for real, through the normal camera and capture path.

``SimulatedStation.start_toe_adjustment`` (simulators/sim_station.py) puts the AdjustmentWorld
behind the sim:// cameras before they are opened.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Callable

import numpy as np

from simulators.scene import Scene

NOISE_BANK = 8  # noise fields per camera; each frame takes one, rolled by a random offset


def _key(world, seed: int, wheel: str, toe_steps_deg, cams: list[str], supersample: int) -> str:
    parts = {"seed": seed, "wheel": wheel, "steps": [round(float(t), 6) for t in toe_steps_deg],
             "cams": cams, "ss": supersample, "world": world.fingerprint(), "version": 3}  # the world: cameras, body
    return hashlib.sha1(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:16]


def adjustment_scenes(world, seed: int, wheel: str, toe_steps_deg) -> list[Scene]:
    """The vehicle of ``seed`` with ``wheel``'s toe set to each value of ``toe_steps_deg``."""
    from dataclasses import replace

    base = world.vehicle_scene(seed)
    out = []
    for toe in toe_steps_deg:
        toes = dict(base.vehicle.toe_deg)
        toes[wheel] = float(toe)
        out.append(replace(base, vehicle=replace(base.vehicle, toe_deg=toes)))
    return out


def prerender(world, seed: int, wheel: str, toe_steps_deg, live_cams: list[str], cache_dir: Path,
              progress: Callable[[str], None] = print, supersample: int = 8) -> list[dict[str, np.ndarray]]:
    """Noise-free frames per step: [{camera id: (H,W) uint8}], step 0 with every camera.

    Cached in ``cache_dir``; a cached step is loaded, not rendered again.
    """
    from simulators.render import render

    cache_dir = Path(cache_dir)
    cache_dir.mkdir(parents=True, exist_ok=True)
    key = _key(world, seed, wheel, toe_steps_deg, live_cams, supersample)
    scenes = adjustment_scenes(world, seed, wheel, toe_steps_deg)
    steps = []
    for i, scene in enumerate(scenes):
        path = cache_dir / f"adjust-{key}-{i:02d}.npz"
        cams = list(world.cameras) if i == 0 else live_cams
        if path.exists():
            with np.load(path) as z:
                steps.append({c: z[c] for c in cams})
            continue
        progress(f"pre-rendering adjustment step {i + 1}/{len(scenes)} ({len(cams)} cameras, "
                 f"{wheel} toe {toe_steps_deg[i]:+.3f} deg); cached in {cache_dir}")
        frames = {c: render(world.cameras[c], scene, world.lighting_for(c, scene), np.random.default_rng(0),
                            0.0, world.blur_sigma[c], supersample=supersample, body=world.body)
                  for c in cams}
        tmp = path.with_name(f".{path.stem}.tmp.npz")
        np.savez(tmp, **frames)
        tmp.replace(path)
        steps.append(frames)
    return steps


class AdjustmentWorld:
    """The SimWorld interface the sim:// cameras use (``cameras``, ``config``, ``render``,
    ``truth``), serving the pre-rendered adjustment with fresh sensor noise."""

    def __init__(self, world, scenes: list[Scene], steps: list[dict[str, np.ndarray]], hold: int = 5,
                 noise_sigma: float | None = None, seed: int = 0):
        self.world = world
        self.config = world.config
        self.cameras = world.cameras
        self.scenes = scenes
        self.steps = steps
        self.hold = max(1, int(hold))
        self.noise_sigma = float(world.noise_sigma if noise_sigma is None else noise_sigma)
        self._calls: dict[str, int] = {}
        rng = np.random.default_rng(seed)
        shape = {c: img.shape for c, img in steps[0].items()}
        # (NOISE_BANK, H, W) int16 per camera: drawing 1.3 Mpx of Gaussians costs ~25 ms, more
        # than the rest of a live update's capture; a random roll of a bank field is ~2 ms.
        self._noise = {c: np.round(rng.normal(0.0, self.noise_sigma, (NOISE_BANK, *s))).astype(np.int16)
                       for c, s in shape.items()}

    def step_of(self, n: int) -> int:
        """The step shown at a camera's n-th frame: forwards, then backwards, repeated."""
        k = len(self.steps)
        if k == 1:
            return 0
        i = (n // self.hold) % (2 * k - 2)
        return i if i < k else 2 * k - 2 - i

    def render(self, cam_id: str, rng: np.random.Generator | None = None, scene=None,
               exposure: float = 1.0) -> np.ndarray:
        n = self._calls.get(cam_id, 0)
        self._calls[cam_id] = n + 1
        step = self.step_of(n)
        frames = self.steps[step] if cam_id in self.steps[step] else self.steps[0]
        clean = frames[cam_id] if exposure == 1.0 else frames[cam_id] * exposure
        rng = rng or np.random.default_rng(n)
        bank = self._noise[cam_id]
        noise = np.roll(bank[int(rng.integers(len(bank)))], int(rng.integers(clean.size)))
        return np.clip(clean.astype(np.int16) + noise, 0, 255).astype(np.uint8)

    def current_step(self, cam_id: str) -> int:
        """The step of the frame ``cam_id`` served last."""
        return self.step_of(max(self._calls.get(cam_id, 1) - 1, 0))

    def truth(self, scene=None) -> dict:
        """The scene of the step the adjusted wheel's cameras served last. (Not the first camera
        ever served: the baseline captures all cameras in threads, in no fixed order, and a camera
        outside the live axle stays at step 0.)"""
        live = sorted(self.steps[-1]) if len(self.steps) > 1 else sorted(self.cameras)
        served = [c for c in live if c in self._calls]
        return self.world.truth(scene or self.scenes[self.current_step(served[0]) if served else 0])

