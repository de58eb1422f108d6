"""SimCamera: a camera of the simulated station, behind the same interface as real ones.

URI: ``sim://camN[?line=K&fps=F&gamma=G]``. The simulated station comes from the driver context
(``context.simulation``, a simulators.sim_station.SimulatedStation); the camera renders
``world.render(camN, rng)`` of its world's current scene. Trigger modes behave as on the station:

- software: one frame per ``trigger()``;
- hardware: one frame per pulse on trigger line K (default N-1) of the station's trigger wires
  (simulators.trigger_board_sim.TriggerLines, driven by the simulated trigger board);
- free-run: a frame every 1/F s (default 10 fps), stamped on that grid.

The exposure the camera was opened with sees the world's lighting; a later ``configure
(exposure_us=...)`` scales the light by the ratio (the read noise stays). ``gamma`` G < 1
encodes the grey as an sRGB webcam does, grey = 255 (light / 255)^G, noise and all (default 1:
linear, as a machine-vision camera's).

Frames are deterministic: frame n of camera camN is rendered with the noise stream
``default_rng([seed, N, n])``, seed = the simulated station's (default the station seed),
so the same world, scene and seed give bit-identical frames.
"""

from __future__ import annotations

import re
import threading
import time
from urllib.parse import parse_qs

import numpy as np

from drivers.base import Camera, CameraIdentity, CameraSettings, Frame
from drivers.context import DriverContext
from drivers.errors import CameraMissing, DriverError


class SimCamera(Camera):
    scheme = "sim"

    def __init__(self, camera_id: str, uri: str, settings: CameraSettings | None = None,
                 context: DriverContext | None = None):
        super().__init__(camera_id, uri, settings, context)
        rest = uri.split("://", 1)[1]
        name, _, query = rest.partition("?")
        self.sim_id = name.strip("/") or camera_id
        opts = {k: v[-1] for k, v in parse_qs(query).items()}
        m = re.search(r"(\d+)$", self.sim_id)
        self.index = int(m.group(1)) if m else 0
        self.line = int(opts.get("line", max(self.index - 1, 0)))
        self.fps = float(opts.get("fps", 10.0))
        self.gamma = float(opts.get("gamma", 1.0))
        if not 0.2 <= self.gamma <= 5:
            raise DriverError(f"{camera_id}: {uri}: gamma {self.gamma:g} out of [0.2, 5]")
        self.world = None
        self.lines = None
        self._n = 0  # frames rendered since open
        self._triggered = threading.Event()
        self._pulses_seen = 0
        self._t_open_ns = 0

    def _open(self) -> None:
        sim = self.context.simulation
        world = getattr(sim, "world", None)
        if world is None:
            raise DriverError(f"{self.camera_id}: sim:// cameras need the simulated station "
                              "(a simulators.sim_station.SimulatedStation in the driver context)",
                              hint="assemble the station with its simulator, or use real camera URIs")
        if self.sim_id not in world.cameras:
            raise CameraMissing(f"{self.camera_id}: the simulated station has no camera {self.sim_id!r} "
                                f"(it has {', '.join(world.cameras)})")
        self.world = world
        self.seed = sim.seed
        self._exposure_us = self.settings.exposure_us  # the world's lighting is what this exposure sees
        self._n = 0
        self._t_open_ns = time.monotonic_ns()

    def _configure(self, s: CameraSettings) -> None:
        if s.pixel_format not in ("Mono8", "Mono16"):
            raise DriverError(f"{self.camera_id}: the simulated camera gives Mono8 or Mono16, not {s.pixel_format}")
        model = self.world.cameras[self.sim_id]
        if (s.width, s.height) != (model.width, model.height):
            raise DriverError(f"{self.camera_id}: the simulated sensor is {model.width}x{model.height}, "
                              f"configured for {s.width}x{s.height}")
        if s.trigger == "hardware":
            self.lines = self.context.simulation.trigger_lines
            if not 0 <= self.line < self.lines.n_lines:
                raise DriverError(f"{self.camera_id}: trigger line {self.line} does not exist on the board")

    def _arm(self) -> None:
        self._triggered.clear()
        if self.settings.trigger == "hardware":
            self._pulses_seen = self.lines.count(self.line)

    def _trigger(self) -> None:
        self._trigger_ns = time.monotonic_ns()
        self._triggered.set()

    def _grab(self, timeout_s: float) -> Frame | None:
        mode = self.settings.trigger
        if mode == "software":
            if not self._triggered.wait(timeout_s):
                return None
            self._triggered.clear()
            t_ns = self._trigger_ns
        elif mode == "hardware":
            got = self.lines.wait(self.line, self._pulses_seen, timeout_s)
            if got is None:
                return None
            self._pulses_seen, t_ns = got
        else:  # free-run: the next tick of the frame clock
            period_ns = int(1e9 / self.fps)
            now = time.monotonic_ns()
            t_ns = self._t_open_ns + ((now - self._t_open_ns) // period_ns + 1) * period_ns
            if (t_ns - now) / 1e9 > timeout_s:
                return None
            time.sleep((t_ns - now) / 1e9)
        image = self.render(self._n)
        frame = Frame(self.camera_id, image, t_ns, self._n,
                      {"pixel_format": self.settings.pixel_format, "sim_seed": self.seed, "sim_frame": self._n})
        self._n += 1
        return frame

    def render(self, n: int) -> np.ndarray:
        """Frame ``n`` of this camera: (H, W) uint8 (Mono8) or uint16 (Mono16, 8 bits shifted up)."""
        rng = np.random.default_rng([self.seed, self.index, n])
        s = self.settings
        image = self.world.render(self.sim_id, rng, exposure=s.exposure_us / self._exposure_us)
        if self.gamma != 1.0:
            image = np.rint(255.0 * (image / 255.0) ** self.gamma).astype(np.uint8)
        if s.roi:
            x, y, w, h = s.roi
            image = image[y:y + h, x:x + w]
        if s.pixel_format == "Mono16":
            image = image.astype(np.uint16) << 8
        return np.ascontiguousarray(image)

    def _identity(self) -> CameraIdentity:
        model = self.world.cameras[self.sim_id]
        return CameraIdentity("simulated", "SimCamera", f"SIM-{self.sim_id}", model.width, model.height)


def build_context(config, seed: int | None = None, **_) -> DriverContext:
    """The simulated station for sim:// cameras (called through drivers.registry.build_context).

    ``seed``: a random vehicle (SimWorld.vehicle_scene(seed)) stands on the lift; None: empty.
    ``trigger_board.port: sim`` in the configuration starts the simulated trigger board on a
    pty wired to the cameras' trigger lines (its port in ``trigger_board_port``; the context's
    ``close()`` stops it). Rendering a 1280x1024 frame takes seconds on a slow machine, so the
    simulated cameras ask for a capture deadline of their own (``capture_timeout_s``), used
    instead of a shorter one.
    """
    from simulators.sim_station import SimulatedStation
    from simulators.trigger_board_sim import TriggerBoardSim
    from simulators.world import SimWorld

    world = SimWorld.from_config(config)
    if seed is not None:
        world.set_scene(world.vehicle_scene(seed))
    context = SimulatedStation(world, vehicle_seed=seed).context(capture_timeout_s=600.0)
    board = getattr(getattr(config, "trigger_board", None), "port", None)
    if board == "sim":  # trigger_board.port: sim -> the simulated board on a pty, wired to the cameras
        sim = TriggerBoardSim(context.simulation.trigger_lines)
        context.trigger_board_port = sim.port
        context.closers.append(sim.close)
    return context
