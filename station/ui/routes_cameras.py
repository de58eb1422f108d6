"""The Cameras page's requests: run a camera check (one capture, the rims drawn), its images."""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from station.ui.refused import Refused

KEY = "camera-check"


async def check(request: Request):
    from station.ui.camera_check import check_cameras

    run = request.app.state.screen.runner.start(KEY, "Camera check", None, check_cameras)
    return JSONResponse(run.view(), status_code=202)


async def cameras(request: Request):
    screen = request.app.state.screen
    run = screen.runner.last.get(KEY)
    configured = {cid: {"wheel": c.wheel, "uri": c.uri, "resolution": [c.width, c.height]}
                  for cid, c in screen.config.cameras.items()}
    return JSONResponse({"configured": configured, "check": run.view() if run else None})


async def image(request: Request):
    run = request.app.state.screen.runner.last.get(KEY)
    cid = request.path_params["camera"]
    if run is None or run.state != "done" or not run.output or cid not in run.output:
        raise Refused(404, f"no image of {cid!r}: run a camera check first")
    return Response(run.output[cid], media_type="image/png")


routes = [
    Route("/api/cameras", cameras),
    Route("/api/cameras/check", check, methods=["POST"]),
    Route("/api/cameras/{camera}.png", image),
]
