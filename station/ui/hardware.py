"""The cameras belong to one user at a time: a step of the procedure, or the live view.

:class:`Hardware` hands the station to them in turn. A step (station/ui/runner.py) has the
right of way: it asks the live view (station/ui/live_feed.py) to let go, waits until it has
closed its cameras, runs, and gives them back; the live view opens them again when its page is
still open. The station itself is opened per use from the configuration, as the `station`
commands do (``station.cycle.Station``, ``station.live.LiveSession``); the factories can be
replaced (the tests give fakes).
"""

from __future__ import annotations

import random
import threading
from dataclasses import dataclass, field
from typing import Callable

from station.config import StationConfig


def _open_station(config: StationConfig, seed: int, progress: Callable[[str], None]):
    from station.cycle import Station

    return Station(config, seed=seed, progress=progress)


def _open_live(config: StationConfig, seed: int, axle: str, progress: Callable[[str], None], job_id: str | None,
               adjust_steps: int):
    from station.live import LiveSession

    return LiveSession(config, axle=axle, seed=seed, progress=progress, job_id=job_id, n_steps=adjust_steps)


@dataclass
class Hardware:
    """The configured station, taken in turn. ``seed``: the simulated station's vehicle (one car
    stands on the lift for the whole session); ``adjust_steps``: the simulated technician's tie-rod
    steps in the live view (simulated station only)."""

    config: StationConfig
    seed: int = field(default_factory=lambda: random.randrange(1_000_000))
    adjust_steps: int = 7
    open_station: Callable = _open_station
    open_live: Callable = _open_live
    lock: threading.Lock = field(default_factory=threading.Lock)
    step_waiting: threading.Event = field(default_factory=threading.Event)  # the live view must let go

    def station(self, progress: Callable[[str], None]):
        """An open station (a context manager); the caller holds :meth:`for_step`."""
        return self.open_station(self.config, self.seed, progress)

    def live(self, axle: str, progress: Callable[[str], None], job_id: str | None):
        return self.open_live(self.config, self.seed, axle, progress, job_id, self.adjust_steps)

    def for_step(self) -> "_StepHold":
        """Hold the cameras for a step (the live view lets go first)."""
        return _StepHold(self)


class _StepHold:
    def __init__(self, hw: Hardware):
        self.hw = hw

    def __enter__(self):
        self.hw.step_waiting.set()
        self.hw.lock.acquire()
        return self

    def __exit__(self, *exc):
        self.hw.step_waiting.clear()
        self.hw.lock.release()
