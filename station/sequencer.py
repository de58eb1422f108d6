"""The states of a measurement cycle, as a declared transition table (docs/cameras.md).

    idle --start--> capturing --captured--> measuring --measured--> reporting --reported--> done
    capturing / measuring / reporting --fail--> fault        (the error is kept: code + sentence)
    capturing / measuring / reporting --abort--> idle
    done / fault --start--> capturing                        (a fault never blocks the next cycle)
    done / fault --reset--> idle

Anything else is an :class:`IllegalCommand` naming the state, the command and what is allowed
there; the state does not change. ``Sequencer.run_cycle`` drives one cycle through the table
and turns any coded error (the station's, a driver's, the calibration's) into the fault state,
so the station is ready for the next command.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from station.errors import CODED_ERRORS, CodedError, StationError, IllegalCommand

log = logging.getLogger("station.sequencer")

STATES = ("idle", "capturing", "measuring", "reporting", "done", "fault")
EVENTS = ("start", "captured", "measured", "reported", "fail", "abort", "reset")

# (state, event) -> next state. The whole behaviour; nothing else moves the state.
TRANSITIONS: dict[tuple[str, str], str] = {
    ("idle", "start"): "capturing",
    ("done", "start"): "capturing",
    ("fault", "start"): "capturing",
    ("capturing", "captured"): "measuring",
    ("measuring", "measured"): "reporting",
    ("reporting", "reported"): "done",
    ("capturing", "fail"): "fault",
    ("measuring", "fail"): "fault",
    ("reporting", "fail"): "fault",
    ("capturing", "abort"): "idle",
    ("measuring", "abort"): "idle",
    ("reporting", "abort"): "idle",
    ("done", "reset"): "idle",
    ("fault", "reset"): "idle",
}
BUSY = ("capturing", "measuring", "reporting")



@dataclass
class Fault:
    code: int
    message: str
    state: str  # the state the cycle failed in
    hint: str | None = None


@dataclass
class Sequencer:
    """The station's cycle state; thread-safe. ``listeners`` get (old, event, new) after a move."""

    state: str = "idle"
    fault: Fault | None = None
    cycle: int = 0
    listeners: list[Callable[[str, str, str], None]] = field(default_factory=list)
    history: list[tuple[float, str, str, str]] = field(default_factory=list)

    def __post_init__(self):
        self._lock = threading.RLock()

    def allowed(self, state: str | None = None) -> list[str]:
        state = state or self.state
        return [e for (s, e) in TRANSITIONS if s == state]

    def fire(self, event: str, error: CodedError | None = None) -> str:
        """Apply ``event``; the new state, or IllegalCommand (state unchanged)."""
        with self._lock:
            if event not in EVENTS:
                raise IllegalCommand(f"unknown command {event!r}; commands are {', '.join(EVENTS)}")
            old = self.state
            new = TRANSITIONS.get((old, event))
            if new is None:
                raise IllegalCommand(f"cannot {event} while {old}; allowed now: {', '.join(self.allowed(old)) or 'nothing'}",
                                     hint="wait for the cycle to finish, or abort it")
            if event == "fail":
                e = error or StationError("unspecified failure")
                self.fault = Fault(getattr(e, "code", 1), str(e), old, getattr(e, "hint", None))
            elif event == "start":
                self.fault = None
                self.cycle += 1
            elif event == "reset":
                self.fault = None
            self.state = new
            self.history.append((time.time(), old, event, new))
            del self.history[:-100]
        log.info("sequencer: %s --%s--> %s", old, event, new)
        for listener in list(self.listeners):
            try:
                listener(old, event, new)
            except Exception as e:  # noqa: BLE001 - a listener must not break the cycle
                log.warning("sequencer listener failed: %s", e)
        return new

    @property
    def busy(self) -> bool:
        return self.state in BUSY

    def run_cycle(self, capture: Callable[[], Any], measure: Callable[[Any], Any],
                  report: Callable[[Any], Any]) -> Any:
        """start -> capture() -> measure(frames) -> report(result) -> done; the report's value.

        A coded error (station.errors.CODED_ERRORS) in any step moves to ``fault`` (kept in
        ``self.fault``) and is re-raised; the next ``start`` is accepted. Other exceptions do the
        same, as an internal error.
        """
        self.fire("start")
        try:
            frames = capture()
            self.fire("captured")
            result = measure(frames)
            self.fire("measured")
            out = report(result)
            self.fire("reported")
            return out
        except CODED_ERRORS as e:
            if self.busy:
                self.fire("fail", e)
            raise
        except Exception as e:
            if self.busy:
                self.fire("fail", StationError(f"internal error: {type(e).__name__}: {e}"))
            raise


def transition_table_markdown() -> str:
    """The table as Markdown (docs/cameras.md embeds it; a test keeps them equal)."""
    rows = ["| state | command | next state |", "|---|---|---|"]
    rows += [f"| {s} | {e} | {n} |" for (s, e), n in TRANSITIONS.items()]
    return "\n".join(rows)
