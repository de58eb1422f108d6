"""The cycle thread's side of the steps a PLC-driven cycle waits for: a roll of the car (runout
compensation, command 5) and a steer of the front wheels (a steering sweep, command 7).

The cycle runs in a worker thread; the registers and the handshake live on the server's event
loop (station/plc/device.py). A gate hands each request to the device on its loop
(``call_soon_threadsafe``) and, where the cycle must wait for the answer, waits, looking now and
then whether the server stopped (a stopped loop may never run the request). The device is
passed in, not imported: it imports this module.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import time

from station.errors import RollNotConfirmed, SteerNotReached
from station.plc.roll_operator import RollPrompt
from station.plc.steer_operator import SteerPrompt

POLL_S = 0.2  # how often a waiting cycle looks whether the server stopped
ANSWER_S = 30.0  # how long a request the device answers at once (begin, end of a steer) may take


def ask(device, loop: asyncio.AbstractEventLoop, fn, args: tuple, stopped: Exception, wait_s: float):
    """``fn(*args, done)`` on the loop, then ``done``'s result (or its exception); ``stopped``
    raised when the loop is closed, the device stopped, or no answer came within ``wait_s``."""
    done: concurrent.futures.Future = concurrent.futures.Future()
    try:
        loop.call_soon_threadsafe(fn, *args, done)
    except RuntimeError:  # the loop is closed: the server stopped
        raise stopped from None
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return done.result(timeout=POLL_S)
        except concurrent.futures.TimeoutError:
            if device.stopped or time.monotonic() > deadline:
                raise stopped from None


class LoopRollGate:
    """A compensated cycle's :class:`~station.plc.roll_operator.RollGate`: asks the device for the
    roll and waits for the PLC's in position, the roll timeout or the server stopping."""

    def __init__(self, device, loop: asyncio.AbstractEventLoop, cycle: int):
        self.device, self.loop, self.cycle = device, loop, cycle

    def roll(self, prompt: RollPrompt) -> None:
        stopped = RollNotConfirmed(f"roll {prompt.step}/{prompt.steps}: the station stopped waiting for the PLC")
        ask(self.device, self.loop, self.device._ask_roll, (self.cycle, prompt), stopped,
            self.device.roll_timeout_s + ANSWER_S)


class LoopSteerGate:
    """A steering sweep's :class:`~station.plc.steer_operator.SteerGate`: each steer asked of the
    device (state steer), its live readings handed on without waiting, its end waited for (the
    state is busy again before the station captures)."""

    def __init__(self, device, loop: asyncio.AbstractEventLoop, cycle: int):
        self.device, self.loop, self.cycle = device, loop, cycle
        self.pending = None  # the device's record of the running steer (its ``error`` set on a timeout)

    @property
    def timeout_s(self) -> float:
        return self.device.steer_timeout_s

    def begin(self, prompt: SteerPrompt) -> None:
        stopped = SteerNotReached(f"steer {prompt.step}/{prompt.steps}: the station stopped")
        self.pending = ask(self.device, self.loop, self.device._ask_steer, (self.cycle, prompt), stopped, ANSWER_S)

    def reading(self, angles: dict[str, float], reached: bool) -> None:
        pending = self.pending
        if pending is None:
            return
        if pending.error is not None:  # the steer timed out, or the station stopped
            raise pending.error
        if self.device.stopped:
            raise SteerNotReached("the station stopped waiting for the steer")
        try:
            self.loop.call_soon_threadsafe(self.device._steer_reading, pending, dict(angles), bool(reached))
        except RuntimeError:
            raise SteerNotReached("the station stopped waiting for the steer") from None

    def end(self, error: BaseException | None = None) -> None:
        pending, self.pending = self.pending, None
        if pending is None:
            return
        stopped = SteerNotReached(f"steer {pending.prompt.step}/{pending.prompt.steps}: the station stopped")
        ask(self.device, self.loop, self.device._end_steer, (pending, error), stopped, ANSWER_S)
