"""The Job page's requests: the session's CSRF token, the vehicles (with search), the current job."""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Route

from station.ui.refused import Refused
from station.ui.views import spec_view


async def session(request: Request):
    screen = request.app.state.screen
    s = request.state.session
    return JSONResponse({"csrf": s.csrf, "login": screen.login, "station": screen.config.name,
                         "angle_format": screen.config.ui.angle_format,
                         "simulated_seed": screen.hardware.seed if screen.simulated else None})


async def vehicles(request: Request):
    q = request.query_params.get("q", "")[:100]
    return JSONResponse({"vehicles": request.app.state.screen.jobs.search(q)})


def job_view(screen) -> dict:
    job = screen.jobs.current
    if job is None:
        return {"job": None}
    return {"job": {"job_id": job.job_id, "vehicle": job.vehicle}, "spec": spec_view(screen.jobs.spec(job.vehicle))}


async def get_job(request: Request):
    return JSONResponse(job_view(request.app.state.screen))


async def set_job(request: Request):
    screen = request.app.state.screen
    body = await json_body(request)
    running = screen.runner.busy()
    if running is not None:
        raise Refused(409, f"'{running.title}' is running for job {running.job_id}; the job can be changed when it "
                           "has finished", "wait for the step to finish")
    screen.jobs.set(body.get("job_id"), body.get("vehicle"))
    return JSONResponse(job_view(screen))


async def json_body(request: Request) -> dict:
    """The request's JSON object; Refused (400) for anything else."""
    try:
        body = await request.json()
    except ValueError:
        body = None
    if not isinstance(body, dict):
        raise Refused(400, "the request's body is not a JSON object", "use the station's page")
    return body


routes = [
    Route("/api/session", session),
    Route("/api/vehicles", vehicles),
    Route("/api/job", get_job, methods=["GET"]),
    Route("/api/job", set_job, methods=["POST"]),
]
