"""The Procedure page's progress stream (``/api/steps/stream``, Server-Sent Events) over a real
HTTP connection: uvicorn serves the screen in a thread on a loopback port, a fake station writes
numbered progress lines while the test reads the stream. The lines arrive in order, each once;
a reconnect with the browser's ``Last-Event-ID`` gets only the lines it missed; the outcome and
the result arrive at the end."""

from __future__ import annotations

import json
import socket
import threading
import time

import httpx
import pytest
import uvicorn

from station.config import load_config
from station.ui.app import build_app
from station.ui.hardware import Hardware
from tests.result_builder import make_result


class LineStation:
    """What a step sees of station.cycle.Station: measure() writes ``n`` lines, ``line i``, one
    each time the test lets it (``go``), and returns a result."""

    def __init__(self, progress, go: threading.Semaphore, n: int):
        self.progress, self.go, self.n = progress, go, n
        self.context = type("Ctx", (), {"simulation": None})()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def measure(self, *, job_id=None, vehicle_spec=None, **kw):
        for i in range(self.n):
            if not self.go.acquire(timeout=20):
                raise TimeoutError("the test stopped letting the lines out")
            self.progress(f"line {i}")
        result = make_result(1, cycle=3)
        result.job_id, result.vehicle_spec = job_id, vehicle_spec
        return result


@pytest.fixture
def served():
    """(base URL, semaphore letting the fake station write its next line) of `station ui` on uvicorn."""
    go = threading.Semaphore(0)
    config = load_config()
    hw = Hardware(config, seed=5, open_station=lambda cfg, seed, progress: LineStation(progress, go, 12))
    app = build_app(config, hardware=hw)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.02)
    assert server.started
    yield f"http://127.0.0.1:{port}", go
    for _ in range(20):
        go.release()  # a step still writing finishes
    server.should_exit = True
    thread.join(20)


def _messages(response):
    """(id, data) of each message of an SSE response, as they arrive."""
    event_id, data = None, []
    for line in response.iter_lines():
        if line.startswith("id: "):
            event_id = line[4:]
        elif line.startswith("data: "):
            data.append(line[6:])
        elif line == "" and data:
            yield event_id, json.loads("\n".join(data))
            data = []


def _read_until(messages, done, timeout=20.0):
    """Messages until ``done(message)``; all of them."""
    got, deadline = [], time.monotonic() + timeout
    for event_id, m in messages:
        got.append((event_id, m))
        if done(m):
            return got
        assert time.monotonic() < deadline, "the stream did not deliver in time"
    raise AssertionError("the stream ended")


def test_progress_lines_arrive_streamed_in_order_each_once_and_resume_after_a_reconnect(served):
    base, go = served
    with httpx.Client(base_url=base, timeout=10) as c:
        token = {"x-csrf-token": c.get("/api/session").json()["csrf"]}
        assert c.post("/api/job", json={"job_id": "VIN-SSE", "vehicle": "dodge-caravan-2007"},
                      headers=token).status_code == 200
        t0 = time.monotonic()
        with c.stream("GET", "/api/steps/stream") as r:
            assert r.headers["content-type"].startswith("text/event-stream")
            messages = _messages(r)
            first_id, first = next(messages)
            assert first["job"] == {"job_id": "VIN-SSE", "vehicle": "dodge-caravan-2007"} and first["current"] is None
            assert [s["key"] for s in first["steps"]] == ["calibration-check", "runout", "steering", "measurement"]
            assert first_id is None  # nothing run yet
            assert c.post("/api/steps/measurement/start", headers=token).status_code == 202
            for _ in range(5):
                go.release()
            got = _read_until(messages, lambda m: m["current"] and "line 4" in m["current"]["lines"])
        lines = [x for _, m in got if m["current"] for x in m["current"]["lines"]]
        assert lines == ["Measurement: opening the cameras"] + [f"line {i}" for i in range(5)]  # in order, each once
        last_id = got[-1][0]
        assert last_id.startswith("measurement@") and last_id.endswith("#6")
        assert time.monotonic() - t0 < 5  # pushed, not waited for

        # the page was closed (a reload, a dropped Wi-Fi): meanwhile three more lines
        for _ in range(3):
            go.release()
        deadline = time.monotonic() + 10
        while "line 7" not in c.get("/api/steps").json()["current"]["lines"]:
            assert time.monotonic() < deadline
            time.sleep(0.02)
        with c.stream("GET", "/api/steps/stream", headers={"last-event-id": last_id}) as r:
            messages = _messages(r)
            for _ in range(4):
                go.release()  # lines 8..11, then the result
            got = _read_until(messages, lambda m: m["current"]["state"] != "running")
        lines = [x for _, m in got for x in m["current"]["lines"]]
        assert lines == [f"line {i}" for i in range(5, 12)] + ["Measurement: done"]  # only what it missed
        end = got[-1][1]
        assert end["current"]["summary"]["valid"] and end["current"]["summary"]["cycle_id"]
        assert {s["key"]: (s["last"] or {}).get("state") for s in end["steps"]}["measurement"] == "done"

        with c.stream("GET", "/api/steps/stream") as r:  # a new page: the whole run from its first line
            _, m = next(_messages(r))
        assert m["current"]["lines"][0] == "Measurement: opening the cameras" and len(m["current"]["lines"]) == 14
