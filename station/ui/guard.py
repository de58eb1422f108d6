"""The screen's gate: every request passes here first (station/ui/auth.py says the rules).

An ASGI middleware (not Starlette's BaseHTTPMiddleware, which would buffer the live stream):
it checks the Host on loopback, the session (a login where one is required; a new session
otherwise), the CSRF token and Origin of every request that changes anything, and adds the
security headers (Content-Security-Policy ``default-src 'self'``: nothing from elsewhere, no
inline script) to every answer.
"""

from __future__ import annotations

from starlette.datastructures import MutableHeaders
from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse

from station.ui.auth import COOKIE, CSRF_HEADER, LOOPBACK_NAMES, Sessions, csrf_ok

CSP = "default-src 'self'; img-src 'self' data:; object-src 'none'; base-uri 'none'; frame-ancestors 'none'; form-action 'self'"
SAFE_METHODS = ("GET", "HEAD")
OPEN_PATHS = ("/login", "/static/style.css", "/static/login.js", "/favicon.ico")  # reachable before a login


def security_headers(headers: MutableHeaders) -> None:
    headers.setdefault("content-security-policy", CSP)
    headers["x-content-type-options"] = "nosniff"
    headers["referrer-policy"] = "no-referrer"
    headers["x-frame-options"] = "DENY"
    headers.setdefault("cache-control", "no-store")


def session_cookie(sid: str, secure: bool = False) -> str:
    return f"{COOKIE}={sid}; Path=/; HttpOnly; SameSite=Strict" + ("; Secure" if secure else "")


class Guard:
    """ASGI middleware around the app: ``sessions`` (station/ui/auth.py), ``login`` (whether a
    password is required), ``loopback`` (whether the server is bound to loopback)."""

    def __init__(self, app, sessions: Sessions, login: bool, loopback: bool):
        self.app = app
        self.sessions = sessions
        self.login = login
        self.loopback = loopback

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        request = Request(scope)
        refusal = self._refusal(request)
        new_sid = None
        if refusal is None:
            sid = request.cookies.get(COOKIE)
            session = self.sessions.get(sid)
            if session is None and not self.login:
                new_sid, session = self.sessions.new()
            scope.setdefault("state", {})["session"] = session
            scope["state"]["session_id"] = new_sid or sid
            if session is None and request.url.path not in OPEN_PATHS:
                refusal = _need_login(request)
            elif request.method not in SAFE_METHODS and request.url.path != "/login" and \
                    not csrf_ok(session, request.headers.get(CSRF_HEADER)):
                refusal = _json(403, "this request did not come from the station's own page (its CSRF token is "
                                     "missing or stale)", "reload the page and try again")
        if refusal is not None:
            return await refusal(scope, receive, _with_headers(send))
        return await self.app(scope, receive, _with_headers(send, new_sid))

    def _refusal(self, request: Request):
        """A request refused whoever sends it: a foreign Host on loopback, a foreign Origin."""
        if self.loopback and (request.url.hostname or "") not in LOOPBACK_NAMES:
            return _json(400, f"this screen answers to 127.0.0.1 and localhost only, not {request.url.hostname!r}",
                         "open http://127.0.0.1:PORT/ on the station PC")
        origin = request.headers.get("origin")
        if request.method not in SAFE_METHODS and origin is not None and origin != _own_origin(request):
            return _json(403, f"a request from another site ({origin}) may not change anything here",
                         "use the station's own page")
        return None


def _own_origin(request: Request) -> str:
    return f"{request.url.scheme}://{request.headers.get('host', '')}"


def _need_login(request: Request):
    if request.url.path.startswith("/api/") or request.method not in SAFE_METHODS:
        return _json(401, "log in first: this station's screen needs its password", "open /login")
    return RedirectResponse("/login", status_code=303)


def _json(status: int, message: str, hint: str | None = None) -> JSONResponse:
    return JSONResponse({"error": message, "hint": hint}, status_code=status)


def _with_headers(send, new_sid: str | None = None):
    async def wrapped(message):
        if message["type"] == "http.response.start":
            headers = MutableHeaders(scope=message)
            security_headers(headers)
            if new_sid:
                headers.append("set-cookie", session_cookie(new_sid))
        await send(message)
    return wrapped
