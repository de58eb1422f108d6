"""Log a burst of like events as two lines: the first at once, a count of the rest when quiet.

A flood of refused connections, garbage frames or writes from a read-only client must leave the
log readable: one line says what happened and what to do, one line later says how often.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass


@dataclass
class _Burst:
    first: float
    last: float
    more: int = 0
    level: int = logging.WARNING
    timer: asyncio.TimerHandle | None = None


class BurstLog:
    """``log(key, message, *args, level=...)`` on the event loop. A burst of ``key`` ends after ``quiet_s`` seconds
    without another; then, if it had more than one event, a summary line counts the rest."""

    def __init__(self, logger: logging.Logger, level: int = logging.WARNING, quiet_s: float = 10.0):
        self.logger = logger
        self.level = level
        self.quiet_s = quiet_s
        self._bursts: dict[str, _Burst] = {}

    def __call__(self, key: str, message: str, *args, level: int | None = None) -> None:
        now = time.monotonic()
        burst = self._bursts.get(key)
        if burst is not None:
            burst.more += 1
            burst.last = now
            return
        level = self.level if level is None else level
        self.logger.log(level, message, *args)
        burst = self._bursts[key] = _Burst(now, now, level=level)
        self._arm(key, burst, self.quiet_s)

    def _arm(self, key: str, burst: _Burst, delay: float) -> None:
        try:
            burst.timer = asyncio.get_running_loop().call_later(delay, self._check, key)
        except RuntimeError:  # no loop (a test calling from outside): summarise at flush()
            burst.timer = None

    def _check(self, key: str) -> None:
        burst = self._bursts[key]
        quiet = time.monotonic() - burst.last
        if quiet < self.quiet_s:
            self._arm(key, burst, self.quiet_s - quiet)
            return
        self._end(key)

    def _end(self, key: str) -> None:
        burst = self._bursts.pop(key)
        if burst.timer is not None:
            burst.timer.cancel()
        if burst.more:
            self.logger.log(burst.level, "%s: %d more like it in %.1f s", key, burst.more, burst.last - burst.first)

    def flush(self) -> None:
        """End every burst now (the server stops)."""
        for key in list(self._bursts):
            self._end(key)
