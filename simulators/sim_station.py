"""The simulated station behind sim:// cameras, and what it adds to the station
(drivers.context.Simulation): the truth, the calibration operator, a toe adjustment for
``station live``, another vehicle on the lift, a replay set of the vehicle on the lift.

The sim:// cameras (simulators/sim_camera.py) render :attr:`SimulatedStation.world`, listen on
its trigger wires and draw their noise from its seed.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from drivers.context import DriverContext
from simulators.trigger_board_sim import TriggerLines


class SimulatedStation:
    """``world``: a simulators.world.SimWorld (or a stand-in with ``cameras``, ``config``,
    ``render``, ``truth``); ``vehicle_seed``: the random vehicle on the lift (None: an empty
    lift); ``seed``: the cameras' noise streams (default the station seed)."""

    def __init__(self, world, *, vehicle_seed: int | None = None, seed: int | None = None,
                 trigger_lines: TriggerLines | None = None):
        self.world = world
        self.vehicle_seed = vehicle_seed
        self.seed = int(world.config.simulation.station_seed if seed is None else seed)
        self.trigger_lines = trigger_lines or TriggerLines()

    def context(self, capture_timeout_s: float = 0.0) -> DriverContext:
        """A driver context holding this simulation (tests build cameras on a stand-in world so)."""
        return DriverContext(capture_timeout_s=capture_timeout_s, simulation=self)

    def truth(self) -> dict:
        return self.world.truth()

    def calibration_operator(self, box, seed: int = 0):
        from simulators.sim_operator import SimOperator  # places the box in the simulated world

        return SimOperator(self.world, box, self.world.config, seed=seed)

    def start_toe_adjustment(self, wheel: str, toe_span_deg: float, n_steps: int, live_cams: list[str],
                             cache_dir: Path, progress: Callable[[str], None] = print, hold: int = 5) -> None:
        from simulators.adjustment import AdjustmentWorld, adjustment_scenes, prerender

        world = self.world
        toe0 = world.scene.vehicle.toe_deg[wheel]
        steps = toe0 + np.linspace(0.0, toe_span_deg, n_steps)
        frames = prerender(world, self.vehicle_seed, wheel, steps, live_cams, cache_dir, progress)
        self.world = AdjustmentWorld(world, adjustment_scenes(world, self.vehicle_seed, wheel, steps), frames,
                                     hold=hold, seed=self.vehicle_seed)

    def roll_car(self, distance_m: float) -> None:
        """The car rolls forward (+) or back (-) along the runways by ``distance_m``."""
        self._move(roll_m=self.world.scene.vehicle.roll_m + float(distance_m))

    def steer(self, angle_deg: float) -> None:
        """The steering wheel is turned until a wheel midway between the front wheels points
        ``angle_deg`` left of straight ahead (each front wheel by its own, Ackermann, angle)."""
        self._move(steer_deg=float(angle_deg))

    def _move(self, **change) -> None:
        from dataclasses import replace

        scene = self.world.scene
        self.world.set_scene(replace(scene, vehicle=replace(scene.vehicle, **change)))

    def place_vehicle(self, seed: int) -> None:
        self.vehicle_seed = int(seed)
        self.world.set_scene(self.world.vehicle_scene(self.vehicle_seed))

    def replay_set(self, noise_sigma: float | None = None) -> tuple[dict, dict, dict]:
        from simulators.world import SimWorld

        world = SimWorld.from_config(self.world.config, noise_sigma=noise_sigma)
        scene = world.vehicle_scene(self.vehicle_seed)
        world.set_scene(scene)
        start = time.perf_counter()
        images = world.render_all(np.random.default_rng([self.vehicle_seed, 1]))
        info = {"seed": int(self.vehicle_seed), "noise_sigma": world.noise_sigma,
                "render_seconds": round(time.perf_counter() - start, 2)}
        return images, world.truth(scene), info
