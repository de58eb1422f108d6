"""The Adjust page's requests: the live stream, and the caster of the job's steering sweep.

``GET /api/live/stream?axle=front|rear|all``: Server-Sent Events, ``event: status`` messages (the
loop starting, live, paused by a step, an error with what to do) and unnamed messages with each
reading (station/ui/live_feed.py, ``reading_view``). The page's EventSource reconnects by itself.

``GET /api/adjust/steering``: the newest valid steering sweep of the current job in the history
(from this screen, ``station caster`` or a PLC): caster, SAI and included angle of each front
wheel with their uncertainty and verdict, when it was measured, and each wheel's camber straight
ahead at the sweep. Caster is not followed live: a straight-ahead wheel's pose does not hold it
(docs/ui.md, "Caster while adjusting"); the page shows the sweep's value with its age, and
whether the live camber has moved since.
"""

from __future__ import annotations

import asyncio
import json

from starlette.requests import Request
from starlette.responses import JSONResponse, StreamingResponse
from starlette.routing import Route

from station.ui.live_feed import axle_or_refuse
from station.ui.views import finite, steering_view

POLL_S = 0.01  # how often a stream looks for a new reading (the loop makes 10-30 a second)


def _event(data: dict, name: str | None = None) -> str:
    return (f"event: {name}\n" if name else "") + f"data: {json.dumps(finite(data), allow_nan=False)}\n\n"


async def stream(request: Request):
    axle = axle_or_refuse(request.query_params.get("axle"))
    feed = request.app.state.screen.feed

    async def events():
        feed.subscribe(axle)
        try:
            seen, said, beat = -1, -1, 0.0
            yield ": the station's live values\n\n"
            while True:
                n_status, status = feed.status
                if n_status != said:
                    said = n_status
                    yield _event(status, "status")
                n, message = feed.latest
                if n != seen and message is not None and message.get("axle") == axle:
                    seen = n
                    yield _event(message)
                beat += POLL_S
                if beat > 15:  # a comment now and then keeps proxies and tablets from closing the stream
                    beat = 0.0
                    yield ": keep-alive\n\n"
                await asyncio.sleep(POLL_S)
        finally:
            feed.unsubscribe()

    return StreamingResponse(events(), media_type="text/event-stream",
                             headers={"cache-control": "no-store", "x-accel-buffering": "no"})


def _newest_sweep(screen, job_id: str):
    """The newest valid result of ``job_id`` with a steering sweep, or None."""
    from station.records.history import History
    from station.result import Measurement

    path = screen.config.data_path("history.sqlite")
    if not path.exists():
        return None
    with History(path, read_only=True) as h:
        sweeps = [r for r in h.query(job=job_id) if r["valid"] and (r["result"] or {}).get("steering")]
    if not sweeps:
        return None
    return Measurement.from_json(max(sweeps, key=lambda r: (r["time_utc"], r["cycle_id"]))["result"])


def sweep_view(screen) -> dict:
    job = screen.jobs.current
    if job is None:
        return {"job_id": None, "sweep": None, "message": "no job yet: enter it on the Job page"}
    result = _newest_sweep(screen, job.job_id)
    if result is None:
        return {"job_id": job.job_id, "sweep": None,
                "message": f"no steering sweep in job {job.job_id} yet: run it (Procedure, step 3) for caster and SAI"}
    spec = screen.jobs.spec(job.vehicle)
    wheels = steering_view(result, spec)
    for w, v in wheels.items():
        r = result.wheels[w]
        v["camber_at_sweep"] = {"value": r.camber_deg, "std": r.camber_std_deg}
    return {"job_id": job.job_id, "message": None,
            "sweep": {"cycle_id": result.cycle_id, "time_utc": result.time_utc, "sweep_deg": result.steering.sweep_deg,
                      "runout_compensated": result.runout_compensated, "wheels": wheels}}


async def steering(request: Request):
    return JSONResponse(finite(await asyncio.to_thread(sweep_view, request.app.state.screen)))


routes = [Route("/api/live/stream", stream), Route("/api/adjust/steering", steering)]
