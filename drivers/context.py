"""What the drivers in use bring to the assembled station, built once by
:func:`drivers.registry.build_context`.

A real station's drivers bring nothing: the context is empty. The sim:// driver brings a
simulated station (:class:`Simulation`): the cameras render its world, and it adds what a
simulation can and a real station cannot: the true angles of the car on the lift, an operator
who places the calibration box, a tie rod turned while ``station live`` watches, a replay set of
any vehicle. The station asks for these through this interface only, never by importing the
simulator.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol


class Simulation(Protocol):
    """A simulated station, as the station sees it (simulators/sim_station.py implements it)."""

    def truth(self) -> dict:
        """The true scene the cameras see now: per wheel toe and camber (deg), the totals, the
        true cameras (``simulators.world.SimWorld.truth``)."""

    def calibration_operator(self, box: Any, seed: int = 0) -> Any:
        """An operator (station.operator.Operator) who places ``box`` (a BoxTarget) in the
        simulated world; ``seed`` draws its poses."""

    def start_toe_adjustment(self, wheel: str, toe_span_deg: float, n_steps: int, live_cams: list[str],
                             cache_dir: Path, progress: Callable[[str], None], hold: int) -> None:
        """From now on, ``wheel``'s toe steps through ``n_steps`` values over ``toe_span_deg``
        and back, one step every ``hold`` frames of the ``live_cams``, as a technician turning
        its tie rod (rendered once into ``cache_dir``); :meth:`truth` follows it."""

    def roll_car(self, distance_m: float) -> None:
        """The simulated technician rolls the car forward (+) or back (-) by ``distance_m``."""

    def steer(self, angle_deg: float) -> None:
        """The simulated technician turns the steering wheel: the front wheels point about
        ``angle_deg`` to the left (+) or right (-) of straight ahead."""

    def place_vehicle(self, seed: int) -> None:
        """Put the random vehicle ``seed`` (``simulators.world.SimWorld.vehicle_scene(seed)``) on
        the lift: the cameras see it from the next frame on; :meth:`truth` and
        :meth:`replay_set` follow it."""

    def replay_set(self, noise_sigma: float | None = None) -> tuple[dict, dict, dict]:
        """({camera id: image}, truth, what was rendered) of the vehicle on the lift, rendered
        once with sensor noise ``noise_sigma`` (grey levels; None: the configuration's)."""


@dataclass
class DriverContext:
    """``capture_timeout_s``: a capture deadline the cameras need beyond the configured one
    (simulated cameras render for seconds); ``trigger_board_port``: a trigger board the drivers
    started (the simulated one), used instead of the configured port; ``simulation``: the
    simulated station, or None for real cameras. :meth:`close` stops what the drivers started."""

    capture_timeout_s: float = 0.0
    trigger_board_port: str | None = None
    simulation: Simulation | None = None
    closers: list[Callable[[], None]] = field(default_factory=list)

    def add(self, other: DriverContext) -> None:
        """Take what another driver brings (one context per scheme in use)."""
        self.capture_timeout_s = max(self.capture_timeout_s, other.capture_timeout_s)
        self.trigger_board_port = other.trigger_board_port or self.trigger_board_port
        self.simulation = other.simulation or self.simulation
        self.closers += other.closers

    def close(self) -> None:
        for close in self.closers:
            close()
