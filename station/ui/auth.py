"""Who may use the screen: the password (kept hashed), sessions, and their CSRF tokens.

Bound to loopback, the screen needs no login (only the station PC reaches it) unless a password
hash is configured; bound to any other address it refuses to start without one
(:func:`login_required`). Every request then needs a session cookie from ``POST /login``.

Whatever the address, a request that changes anything (every method but GET and HEAD) must carry
its session's CSRF token in the ``X-CSRF-Token`` header, and an ``Origin`` header, when the
browser sends one, must be the screen's own: a page from elsewhere open in the same browser can
neither start a step nor edit the job. The cookie is ``HttpOnly`` and ``SameSite=Strict``. On
loopback the ``Host`` header must name loopback too (a DNS name rebound to 127.0.0.1 is refused).

The password hash is PBKDF2-HMAC-SHA256 from the standard library,
``pbkdf2_sha256$ITERATIONS$SALT$HASH`` (salt and hash in URL-safe base64), made by
``station ui --hash-password``.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import ipaddress
import secrets
import threading
import time
from dataclasses import dataclass, field

from station.errors import ConfigError

ALGORITHM = "pbkdf2_sha256"
ITERATIONS = 600_000  # OWASP's figure for PBKDF2-HMAC-SHA256 (2023); about 0.5 s here per login
COOKIE = "station_session"
CSRF_HEADER = "x-csrf-token"
SESSION_IDLE_S = 12 * 3600.0
MAX_SESSIONS = 200
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1", "[::1]")


def _b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).decode().rstrip("=")


def _unb64(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def hash_password(password: str, *, iterations: int = ITERATIONS, salt: bytes | None = None) -> str:
    """The configuration's form of ``password``: ``pbkdf2_sha256$ITERATIONS$SALT$HASH``."""
    if not password:
        raise ValueError("the password is empty")
    salt = salt or secrets.token_bytes(16)
    digest = hashlib.pbkdf2_hmac("sha256", password.encode(), salt, iterations)
    return f"{ALGORITHM}${iterations}${_b64(salt)}${_b64(digest)}"


def parse_hash(stored: str) -> tuple[int, bytes, bytes]:
    """(iterations, salt, digest) of a stored hash; ConfigError naming ``ui.password_hash`` if
    it is not one."""
    try:
        algorithm, iterations, salt, digest = stored.split("$")
        n = int(iterations)
        if algorithm != ALGORITHM or n < 1 or not salt or not digest:
            raise ValueError
        return n, _unb64(salt), _unb64(digest)
    except (ValueError, TypeError, AttributeError) as e:
        raise ConfigError("ui.password_hash: not a password hash of the form "
                          f"{ALGORITHM}$ITERATIONS$SALT$HASH",
                          hint="make one with `station ui --hash-password` and paste its line") from e


def verify_password(password: str, stored: str) -> bool:
    """Whether ``password`` is the one ``stored`` was made from (constant-time comparison)."""
    n, salt, digest = parse_hash(stored)
    return hmac.compare_digest(hashlib.pbkdf2_hmac("sha256", password.encode(), salt, n), digest)


def is_loopback(host: str) -> bool:
    """Whether binding to ``host`` keeps the screen on this PC."""
    if host in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def login_required(host: str, password_hash: str | None) -> bool:
    """Whether every request needs a login. Bound beyond loopback without a password hash:
    ConfigError (the screen must not start open to the shop network)."""
    if password_hash:
        parse_hash(password_hash)
        return True
    if not is_loopback(host):
        raise ConfigError(f"the screen would be open to the network at {host} without a password",
                          hint="set ui.password_hash in the station configuration (`station ui --hash-password` "
                               "makes one), or bind to 127.0.0.1")
    return False


@dataclass
class Session:
    """One browser's session: its CSRF token and when it was last used (monotonic s)."""

    csrf: str = field(default_factory=lambda: secrets.token_urlsafe(24))
    last_used: float = field(default_factory=time.monotonic)


class Sessions:
    """The sessions of this server process (in memory: a restarted station asks for the
    password again). Thread-safe."""

    def __init__(self, idle_s: float = SESSION_IDLE_S, max_sessions: int = MAX_SESSIONS):
        self.idle_s = idle_s
        self.max_sessions = max_sessions
        self._sessions: dict[str, Session] = {}
        self._lock = threading.Lock()

    def new(self) -> tuple[str, Session]:
        """A new session (the least recently used one dropped beyond ``max_sessions``)."""
        sid, session = secrets.token_urlsafe(32), Session()
        with self._lock:
            if len(self._sessions) >= self.max_sessions:
                del self._sessions[min(self._sessions, key=lambda k: self._sessions[k].last_used)]
            self._sessions[sid] = session
        return sid, session

    def get(self, sid: str | None) -> Session | None:
        """The live session of cookie value ``sid``, or None (none, unknown or idle too long)."""
        if not sid:
            return None
        with self._lock:
            session = self._sessions.get(sid)
            now = time.monotonic()
            if session is None:
                return None
            if now - session.last_used > self.idle_s:
                del self._sessions[sid]
                return None
            session.last_used = now
            return session

    def end(self, sid: str | None) -> None:
        with self._lock:
            self._sessions.pop(sid or "", None)


def csrf_ok(session: Session | None, token: str | None) -> bool:
    return session is not None and bool(token) and hmac.compare_digest(session.csrf, token)
