"""The Adjust page's live values: the live loop of station/live.py in a thread of the screen.

While an Adjust page is open (a subscriber of the stream), :class:`LiveFeed` runs a
``LiveSession`` as ``station live`` does: one full measurement of all four wheels (the car
frame, and each wheel's stated uncertainty), then the live axle's cameras over and over. Each
reading becomes one message (:func:`reading_view`): per wheel toe and camber with the
uncertainty of that full measurement and the verdict against the job's specification, total
toe per axle, thrust, and the front toe against the thrust line; wheels not on the live axle
keep their values of the full measurement (``live: false``). The loop stops a few seconds after
the last page closes (the cameras rest, the CPU is free), and lets go at once when a step of
the procedure needs the cameras (station/ui/hardware.py); it starts again after the step.
"""

from __future__ import annotations

import threading
import time
from collections import deque

from calibration.station_frame import WHEELS
from station import alignment
from station.errors import CODED_ERRORS
from station.live import AXLES
from station.ui.units import rim_diameter_m, toe_mm_view
from station.ui.views import spec_window, verdict

LINGER_S = 4.0   # the loop goes on this long after the last page closed (a page reloaded keeps it)


def reading_view(reading, centers: dict, axes: dict, base, spec, live_wheels: tuple, rate_hz: float) -> dict:
    """One live message. ``centers``/``axes``: every wheel's latest (the session's); ``base``: the
    full measurement at the start (its uncertainties, and the values of wheels not live)."""
    angles = alignment.compute_angles(centers, axes)
    wheels = {}
    spec_rim = getattr(spec, "rim_diameter_m", None)  # config/vehicles.yaml gives none yet: the measured rims then
    for w in WHEELS:
        b = base.wheels[w]
        a = angles["wheels"][w]
        live = w in reading.wheels
        seen = live or w not in live_wheels
        entry = {"live": live, "error": reading.errors.get(w)}
        for kind in ("toe", "camber"):
            value = float(a[f"{kind}_deg"]) if seen else None
            window = spec_window(spec, f"{w}.{kind}")
            entry[kind] = {"value": value, "std": getattr(b, f"{kind}_std_deg"), "ok": verdict(window, value),
                           "window": window}
        diameter = rim_diameter_m(b.rim_radius_m, spec_rim)
        entry["rim_diameter_mm"] = None if diameter is None else round(diameter * 1e3, 1)
        entry["toe"]["mm"] = toe_mm_view(entry["toe"]["value"], diameter)
        if "toe_thrust_deg" in a:
            entry["toe_thrust"] = float(a["toe_thrust_deg"]) if seen else None
        wheels[w] = entry
    axles = {}
    for axle, (left, right) in (("front", ("FL", "FR")), ("rear", ("RL", "RR"))):
        both = all(wheels[x]["toe"]["value"] is not None for x in (left, right))
        value = float(angles["axles"][axle]["total_toe_deg"]) if both else None
        window = spec_window(spec, f"{axle}.total_toe")
        diameters = [rim_diameter_m(base.wheels[x].rim_radius_m, spec_rim) for x in (left, right)]
        diameter = sum(diameters) / 2 if None not in diameters else None
        axles[axle] = {"value": value, "std": base.axles[axle].total_toe_std_deg, "ok": verdict(window, value),
                       "window": window, "mm": toe_mm_view(value, diameter)}
    rear_seen = all(wheels[x]["toe"]["value"] is not None for x in ("RL", "RR"))
    thrust = float(angles["thrust_deg"]) if rear_seen else None
    window = spec_window(spec, "thrust")
    return {"n": reading.n, "wheels": wheels, "axles": axles,
            "thrust": {"value": thrust, "std": base.thrust_std_deg, "ok": verdict(window, thrust), "window": window},
            "live_wheels": list(live_wheels), "rate_hz": round(rate_hz, 1),
            "update_ms": round(reading.timing_s.get("total", 0.0) * 1e3, 1),
            "truth_toe": reading.truth_toe_deg}


class LiveFeed:
    """The live loop while pages watch it. ``latest``: (sequence number, message); ``status``:
    (sequence number, {state: idle|starting|live|paused|error, message, hint})."""

    def __init__(self, hardware, jobs, runner, linger_s: float = LINGER_S):
        self.hardware = hardware
        self.jobs = jobs
        self.runner = runner
        self.linger_s = linger_s
        self.axle = "front"
        self.latest: tuple[int, dict | None] = (0, None)
        self.status: tuple[int, dict] = (0, {"state": "idle", "message": "no page is watching"})
        self.subscribers = 0
        self._last_left = 0.0
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None

    # --- pages ------------------------------------------------------------------------------
    def subscribe(self, axle: str) -> None:
        with self._lock:
            self.subscribers += 1
            self.axle = axle
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._loop, name="live-feed", daemon=True)
                self._thread.start()
        self._wake.set()

    def unsubscribe(self) -> None:
        with self._lock:
            self.subscribers -= 1
            self._last_left = time.monotonic()

    def close(self, timeout: float = 30.0) -> None:
        self._closing.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)

    # --- the loop ---------------------------------------------------------------------------
    def _wanted(self) -> bool:
        return not self._closing.is_set() and (
            self.subscribers > 0 or time.monotonic() - self._last_left < self.linger_s)

    def _say(self, state: str, message: str, hint: str | None = None, warnings: list[str] | None = None) -> None:
        self.status = (self.status[0] + 1, {"state": state, "message": message, "hint": hint,
                                            "warnings": warnings or []})

    def _loop(self) -> None:
        while not self._closing.is_set():
            if not self._wanted():
                self._say("idle", "no page is watching")
                with self._lock:  # the last page left: end the thread (a new page starts another)
                    if not self._wanted():
                        self._thread = None
                        return
            running = self.runner.busy()
            if self.hardware.step_waiting.is_set() or running is not None:
                self._say("paused", f"'{running.title if running else 'a step'}' is using the cameras; the live "
                                    "values come back when it has finished")
                self._wake.wait(0.3)
                self._wake.clear()
                continue
            if not self.hardware.lock.acquire(timeout=0.3):
                continue
            try:
                self._session(self.axle)
            except CODED_ERRORS as e:
                self._say("error", str(e), e.hint)
                self._closing.wait(3.0)
            except Exception as e:  # noqa: BLE001 - the screen keeps running; the page says what happened
                self._say("error", f"internal error in the live view: {type(e).__name__}: {e}",
                          "reload the page; if it persists, run `station live` in a terminal to see the details")
                self._closing.wait(3.0)
            finally:
                self.hardware.lock.release()

    def _session(self, axle: str) -> None:
        job = self.jobs.current
        spec = self.jobs.spec(job.vehicle) if job and job.vehicle else None
        self._say("starting", f"opening the cameras ({axle} axle)")
        with self.hardware.live(axle, progress=lambda line: self._say("starting", line),
                                job_id=job.job_id if job else None) as session:
            self._say("starting", "measuring all four wheels once (the car frame)")
            base = session.baseline()
            note = ("toe and camber of the spin axes (the job's runout applied)" if session.runout_compensated
                    else "toe and camber of the rim planes (runout not compensated)")
            self._say("live", note, warnings=base.warnings)
            times: deque = deque(maxlen=30)
            while self._wanted() and axle == self.axle and not self.hardware.step_waiting.is_set():
                reading = session.update()
                times.append(time.monotonic())
                rate = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 0.0
                message = reading_view(reading, session.centers, session.axes, base, spec, session.live_wheels, rate)
                message["axle"] = axle
                message["runout_compensated"] = session.runout_compensated
                self.latest = (self.latest[0] + 1, message)
        self._say("idle", "the live view stopped")


def axle_or_refuse(axle: str | None) -> str:
    from station.ui.refused import Refused

    axle = axle or "front"
    if axle not in AXLES:
        raise Refused(400, f"unknown axle {axle!r}; expected one of {', '.join(AXLES)}")
    return axle
