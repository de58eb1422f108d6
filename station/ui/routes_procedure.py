"""The Procedure page's requests: the steps in order, starting one, following the one that runs."""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Route

from station.ui.refused import Refused
from station.ui.steps import STEP_BY_KEY, STEPS, step_work


def _since(request: Request) -> int:
    try:
        return max(0, int(request.query_params.get("since", "0")))
    except ValueError:
        return 0


async def steps(request: Request):
    """Every step with its instruction and its last run (``since``: the first line wanted of the
    running or last run's lines)."""
    screen = request.app.state.screen
    since = _since(request)
    out = []
    for s in STEPS:
        last = screen.runner.last.get(s.key)
        out.append({"key": s.key, "title": s.title, "instruction": s.instruction, "command": s.command,
                    "available": True, "last": last.view(since) if last else None})
    current = screen.runner.current
    return JSONResponse({"steps": out, "current": current.view(since) if current else None,
                         "job": screen.jobs.current and {"job_id": screen.jobs.current.job_id,
                                                         "vehicle": screen.jobs.current.vehicle}})


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
    Route("/api/steps/{key}/start", start, methods=["POST"]),
]
