"""The technician's screen as an ASGI application (Starlette): its pages, requests and gate.

:func:`build_app` assembles it once: the station's configuration, who holds the cameras
(station/ui/hardware.py), the step runner, the current job, the live feed and the sessions.
The pages are plain HTML, CSS and JavaScript files under station/ui/static/ (no build step,
nothing from the internet); each fetches its data from the ``/api/`` requests of the
``routes_*`` modules. A request the screen refuses answers JSON ``{"error", "hint"}`` with its
status; a station error its code and sentence; anything unexpected a 500 with the crash log's
path, never a traceback, and the screen goes on.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from station.config import StationConfig
from station.errors import CODED_ERRORS
from station.ui import routes_adjust, routes_cameras, routes_history, routes_job, routes_procedure, routes_station
from station.ui.auth import COOKIE, Sessions, is_loopback, login_required, verify_password
from station.ui.guard import Guard, session_cookie
from station.ui.hardware import Hardware
from station.ui.job import Jobs
from station.ui.live_feed import LiveFeed
from station.ui.refused import Refused
from station.ui.runner import StepRunner

STATIC = Path(__file__).resolve().parent / "static"
PAGES = {"/": "job.html", "/procedure": "procedure.html", "/adjust": "adjust.html", "/cameras": "cameras.html",
         "/history": "history.html", "/station": "station.html", "/login": "login.html"}
WRONG_PASSWORD_DELAY_S = 1.0  # each wrong password waits this long: guessing stays slow


@dataclass
class Screen:
    """Everything the requests share."""

    config: StationConfig
    hardware: Hardware
    runner: StepRunner
    jobs: Jobs
    feed: LiveFeed
    sessions: Sessions
    login: bool
    password_hash: str | None
    simulated: bool
    crash_dir: Path


def build_app(config: StationConfig, *, host: str = "127.0.0.1", hardware: Hardware | None = None,
              password_hash: str | None = None, crash_dir: Path | None = None) -> Starlette:
    """The screen of ``config``'s station, to be served on ``host``. ConfigError when ``host`` is
    not loopback and there is no password hash (station/ui/auth.py)."""
    login = login_required(host, password_hash)
    hardware = hardware or Hardware(config)
    crash_dir = crash_dir or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "station"  # as station.cli
    runner = StepRunner(hardware, crash_dir)
    jobs = Jobs(config)
    screen = Screen(config, hardware, runner, jobs, LiveFeed(hardware, jobs, runner), Sessions(), login,
                    password_hash, any(c.uri.startswith("sim://") for c in config.cameras.values()), crash_dir)

    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        await asyncio.to_thread(screen.feed.close)  # the live loop closes its cameras
        running = runner.busy()
        if running is not None:  # a running step finishes and is kept before the screen ends
            print(f"stopping: waiting for '{running.title}' to finish (it is kept in the history)", flush=True)
            await asyncio.to_thread(runner.wait, 600)

    routes = [Route(path, _page(name)) for path, name in PAGES.items() if path != "/login"]
    routes += [Route("/login", _page("login.html"), methods=["GET"]), Route("/login", login_post, methods=["POST"]),
               Route("/logout", logout, methods=["POST"]), Route("/favicon.ico", lambda r: Response(status_code=204))]
    for module in (routes_job, routes_procedure, routes_adjust, routes_cameras, routes_history, routes_station):
        routes += module.routes
    routes.append(Mount("/static", StaticFiles(directory=STATIC), name="static"))
    app = Starlette(routes=routes, lifespan=lifespan,
                    exception_handlers={Refused: refused, **{e: station_error for e in CODED_ERRORS},
                                        404: not_found, 405: not_allowed, Exception: internal_error})
    app.state.screen = screen
    app.add_middleware(Guard, sessions=screen.sessions, login=login, loopback=is_loopback(host))
    return app


def _page(name: str):
    async def page(request: Request):
        return FileResponse(STATIC / name, media_type="text/html")
    return page


async def login_post(request: Request):
    screen: Screen = request.app.state.screen
    if not screen.login:
        return JSONResponse({"ok": True, "message": "this screen needs no password"})
    try:
        form = await request.json()
        password = form.get("password") if isinstance(form, dict) else None
    except ValueError:
        password = None
    if not isinstance(password, str) or not password or not verify_password(password, screen.password_hash):
        await asyncio.sleep(WRONG_PASSWORD_DELAY_S)
        raise Refused(401, "wrong password", "type the station's password (the workshop manager has it)")
    sid, _ = screen.sessions.new()
    response = JSONResponse({"ok": True})
    response.headers.append("set-cookie", session_cookie(sid, secure=request.url.scheme == "https"))
    return response


async def logout(request: Request):
    request.app.state.screen.sessions.end(request.cookies.get(COOKIE))
    response = JSONResponse({"ok": True})
    response.headers.append("set-cookie", f"{COOKIE}=; Path=/; Max-Age=0; HttpOnly; SameSite=Strict")
    return response


async def refused(request: Request, exc: Refused):
    return JSONResponse({"error": str(exc), "hint": exc.hint}, status_code=exc.status)


async def station_error(request: Request, exc):
    status = 503 if exc.code >= 600 or 200 <= exc.code < 300 else 400
    return JSONResponse({"error": str(exc), "hint": exc.hint, "code": exc.code}, status_code=status)


async def not_found(request: Request, exc):
    return JSONResponse({"error": f"nothing here: {request.url.path}", "hint": "use the menu"}, status_code=404)


async def not_allowed(request: Request, exc):
    return JSONResponse({"error": f"{request.method} is not accepted at {request.url.path}"}, status_code=405)


async def internal_error(request: Request, exc: Exception):
    screen: Screen = request.app.state.screen
    where = "the station's log"
    try:
        screen.crash_dir.mkdir(parents=True, exist_ok=True)
        path = screen.crash_dir / f"crash-ui-{time.strftime('%Y%m%dT%H%M%S')}.log"
        path.write_text("".join(traceback.format_exception(exc)))
        where = str(path)
    except OSError:
        pass
    return JSONResponse({"error": f"internal error: {type(exc).__name__}: {exc}",
                         "hint": f"the details are in {where}; the station keeps running"}, status_code=500)
