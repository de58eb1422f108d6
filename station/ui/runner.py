"""Steps run in a worker thread, one at a time, whoever is watching.

A step (station/ui/steps.py) started from the page runs in its own thread with the cameras held
(station/ui/hardware.py); its progress lines (the station's ``progress`` and the guides'
``show``) are kept here for any page to read (the Procedure page's stream,
station/ui/routes_procedure.py), with the outcome: the result's summary, or the
station's message and what to do. A second step while one runs is refused with a sentence
naming the one that runs. The step does not depend on the browser: a page closed mid-step
changes nothing (the cycle is kept in the history as from the command line), and a page opened
later shows where it stands.
"""

from __future__ import annotations

import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from station.errors import CODED_ERRORS
from station.ui.hardware import Hardware
from station.ui.refused import Refused

MAX_LINES = 400  # per step: the guides show several lines a second; the page shows the last ones


@dataclass
class StepRun:
    """One run of a step: its lines (numbered from 0 over the whole run), how it ended."""

    key: str
    title: str
    job_id: str | None
    started_utc: str
    state: str = "running"            # running | done (measured) | failed (the station's refusal) | error
    lines: list[str] = field(default_factory=list)
    first_line: int = 0               # the number of lines[0] (older ones dropped beyond MAX_LINES)
    summary: dict | None = None       # the result, as the page shows it (station/ui/views.py)
    message: str | None = None        # a failure's sentence
    hint: str | None = None           # and what to do
    code: int | None = None
    finished_utc: str | None = None
    output: Any = None                # the step's own output (a camera check's images)
    _lines_lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def add(self, line: str) -> None:
        with self._lines_lock:
            self._append(line)

    def _append(self, line: str) -> None:
        self.lines.append(line)
        if len(self.lines) > MAX_LINES:
            drop = len(self.lines) - MAX_LINES
            del self.lines[:drop]
            self.first_line += drop

    def end(self, state: str, code: int | None = None, message: str | None = None, hint: str | None = None) -> None:
        """How the run ended, all at once with its last line: a page never sees it ended
        without its message and hint (a crash's hint names the log, written first)."""
        with self._lines_lock:
            self.code, self.message, self.hint, self.finished_utc = code, message, hint, _now()
            self.state = state
            self._append(f"{self.title}: {state}" + (f": {message}" if message else ""))

    def view(self, since: int = 0) -> dict:
        with self._lines_lock:  # one moment's lines, their numbers and state (the step goes on meanwhile)
            first, lines = self.first_line, self.lines[max(since - self.first_line, 0):]
            return {"key": self.key, "title": self.title, "job_id": self.job_id, "state": self.state,
                    "started_utc": self.started_utc, "finished_utc": self.finished_utc,
                    "lines": lines, "next_line": first + len(self.lines),
                    "summary": self.summary, "message": self.message, "hint": self.hint, "code": self.code}


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


class StepRunner:
    """Runs one step at a time; keeps the last run of each step."""

    def __init__(self, hardware: Hardware, crash_dir: Path | None = None):
        self.hardware = hardware
        self.crash_dir = crash_dir
        self.current: StepRun | None = None
        self.last: dict[str, StepRun] = {}
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    def busy(self) -> StepRun | None:
        run = self.current
        return run if run is not None and run.state == "running" else None

    def start(self, key: str, title: str, job_id: str | None,
              work: Callable[[Any, Callable[[str], None]], tuple[Any, dict | None]]) -> StepRun:
        """Start ``work(station, show) -> (output, summary)`` in a thread; Refused (409) while a
        step runs."""
        with self._lock:
            running = self.busy()
            if running is not None:
                raise Refused(409, f"'{running.title}' is running (started {running.started_utc}); one step at a "
                                   "time: wait until it has finished",
                              "follow it on the Procedure page")
            run = StepRun(key, title, job_id, _now())
            self.current = run
            self.last[key] = run
            self._thread = threading.Thread(target=self._run, args=(run, work), name=f"step-{key}", daemon=True)
            self._thread.start()
        return run

    def wait(self, timeout: float | None = None) -> None:
        """Wait for the running step's thread (tests, shutdown)."""
        t = self._thread
        if t is not None:
            t.join(timeout)

    def _run(self, run: StepRun, work) -> None:
        ending: tuple = ("error", None, "the step stopped without an outcome", None)
        try:
            with self.hardware.for_step():
                run.add(f"{run.title}: opening the cameras")
                with self.hardware.station(progress=run.add) as station:
                    run.output, run.summary = work(station, run.add)
            failure = (run.summary or {}).get("failure")
            ending = (("failed", failure.get("code"), failure.get("message"), failure.get("hint")) if failure
                      else ("done",))
        except CODED_ERRORS as e:
            ending = ("failed", e.code, str(e), e.hint)
        except Exception as e:  # noqa: BLE001 - the screen and the station keep running
            ending = ("error", None, f"internal error: {type(e).__name__}: {e}", self._crash_log(run, e))
        finally:
            run.end(*ending)

    def _crash_log(self, run: StepRun, e: Exception) -> str:
        text = "".join(traceback.format_exception(e))
        if self.crash_dir is not None:
            try:
                self.crash_dir.mkdir(parents=True, exist_ok=True)
                path = self.crash_dir / f"crash-ui-{time.strftime('%Y%m%dT%H%M%S')}-{run.key}.log"
                path.write_text(text)
                return f"the details are in {path}; please send that file with the job id"
            except OSError:
                pass
        return "the details are in the station's log"
