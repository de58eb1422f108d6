"""The Procedure page's requests: the steps in order, starting one, following the one that runs.

``GET /api/steps/stream``: Server-Sent Events, one message whenever something the page shows
changes (a step's progress line, its state, the job): the steps with their last state, the job,
and the running (or last) step with the lines the stream has not sent yet. Each message's ``id``
names the run and the number of its lines sent, so a browser that reconnects (the EventSource
sends ``Last-Event-ID``) gets only the lines it missed. ``GET /api/steps`` gives the same once.
"""

from __future__ import annotations

import asyncio
import json

from starlette.requests import Request
from starlette.responses import JSONResponse, StreamingResponse
from starlette.routing import Route

from station.ui.refused import Refused
from station.ui.steps import STEP_BY_KEY, STEPS, step_work
from station.ui.views import finite

POLL_S = 0.05      # how often a stream looks for news (the guides write a few lines a second)
KEEP_ALIVE_S = 15  # a comment now and then keeps proxies and tablets from closing the stream


def _since(request: Request) -> int:
    try:
        return max(0, int(request.query_params.get("since", "0")))
    except ValueError:
        return 0


def steps_view(screen, since: int = 0) -> dict:
    """Every step with its instruction and its last run; the running (or last) run with its lines
    from number ``since``; the job."""
    out = []
    for s in STEPS:
        last = screen.runner.last.get(s.key)
        out.append({"key": s.key, "title": s.title, "instruction": s.instruction, "command": s.command,
                    "available": True, "last": last.view(since) if last else None})
    current = screen.runner.current
    return {"steps": out, "current": current.view(since) if current else None,
            "job": screen.jobs.current and {"job_id": screen.jobs.current.job_id,
                                            "vehicle": screen.jobs.current.vehicle}}


async def steps(request: Request):
    """The steps once (``since``: the first line wanted of the running or last run's lines)."""
    return JSONResponse(steps_view(request.app.state.screen, _since(request)))


def _run_id(run) -> str:
    return f"{run.key}@{run.started_utc}"


def _resume(last_event_id: str | None, run) -> int:
    """The first line to send of ``run`` to a browser whose last message had ``last_event_id``."""
    if not last_event_id or run is None or "#" not in last_event_id:
        return 0
    run_id, _, sent = last_event_id.rpartition("#")
    try:
        return int(sent) if run_id == _run_id(run) else 0
    except ValueError:
        return 0


def _revision(screen) -> tuple:
    """Changes whenever the page would show something else."""
    current = screen.runner.current
    return (id(current), current and (current.state, current.first_line + len(current.lines)),
            tuple((k, id(r), r.state) for k, r in screen.runner.last.items()), screen.jobs.current)


async def stream(request: Request):
    screen = request.app.state.screen

    async def events():
        sent_run, sent = None, 0
        current = screen.runner.current
        if current is not None:
            sent_run, sent = _run_id(current), _resume(request.headers.get("last-event-id"), current)
        said, quiet = None, 0.0
        yield ": the steps of the job\n\n"
        while True:
            revision = _revision(screen)
            if revision != said:
                said, quiet = revision, 0.0
                current = screen.runner.current
                if current is not None and _run_id(current) != sent_run:
                    sent_run, sent = _run_id(current), 0  # another run: from its first line
                view = steps_view(screen, sent)
                if view["current"] is not None:
                    sent = view["current"]["next_line"]
                yield (f"id: {sent_run}#{sent}\n" if sent_run else "") + \
                    f"data: {json.dumps(finite(view), allow_nan=False)}\n\n"
            quiet += POLL_S
            if quiet > KEEP_ALIVE_S:
                quiet = 0.0
                yield ": keep-alive\n\n"
            await asyncio.sleep(POLL_S)

    return StreamingResponse(events(), media_type="text/event-stream",
                             headers={"cache-control": "no-store", "x-accel-buffering": "no"})


async def start(request: Request):
    screen = request.app.state.screen
    key = request.path_params["key"]
    step = STEP_BY_KEY.get(key)
    if step is None:
        raise Refused(404, f"there is no step {key!r}; the steps are {', '.join(STEP_BY_KEY)}")
    job = screen.jobs.current
    if job is None:
        raise Refused(400, "no job yet: enter the job id / VIN and pick the vehicle first", "open the Job page")
    run = screen.runner.start(step.key, step.title, job.job_id, step_work(step, job, screen.jobs.spec(job.vehicle)))
    return JSONResponse(run.view(), status_code=202)


routes = [
    Route("/api/steps", steps),
    Route("/api/steps/stream", stream),
    Route("/api/steps/{key}/start", start, methods=["POST"]),
]
