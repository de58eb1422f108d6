"""The history's PostgreSQL backend: one history shared by the shop's stations.

``history.url: postgresql://user:password@host:port/database`` (docs/configuration.md). Each
cycle is tagged with its station's name and is unique by ``(station, cycle_id)``; the schema is
:mod:`station.records.migrations`' (table ``schema_migrations``), applied by the first writer
under an advisory lock. Driver: psycopg 3.

A writer with an outbox connects lazily and never fails for want of the server: its cycles
wait in the outbox (station/records/outbox.py) and are inserted idempotently
(``ON CONFLICT DO NOTHING``) once it answers. A reader without the server gets a
:class:`~station.errors.StorageError` naming the server (never its password) and the reason.
"""

from __future__ import annotations

import threading
from urllib.parse import urlsplit, urlunsplit

from station.errors import StorageError
from station.records.migrations import SCHEMA_VERSION, pending

MIGRATION_LOCK = 0x57A7_1015  # pg_advisory_xact_lock key: one station migrates at a time


def redacted(url: str) -> str:
    """``url`` without its password, for messages and logs."""
    try:
        parts = urlsplit(url)
        if parts.password is None:
            return url
        netloc = parts.netloc.rsplit("@", 1)
        user = parts.username or ""
        return urlunsplit(parts._replace(netloc=f"{user}:***@{netloc[-1]}"))
    except ValueError:
        return "the configured history URL"


def _driver():
    try:
        import psycopg
        from psycopg.rows import dict_row
    except ImportError:
        raise StorageError("history.url names a PostgreSQL server, and the PostgreSQL driver is not installed",
                           hint="pip install 'psycopg[binary]' (the station's `shop` extra), or remove "
                                "history.url to keep the history in SQLite") from None
    return psycopg, dict_row


class PostgresBackend:
    """The SQL of :class:`station.records.history.History` on a PostgreSQL server."""

    placeholder = "%s"
    shared = True

    def __init__(self, url: str, *, timeout_s: float = 3.0, read_only: bool = False, lazy: bool = False):
        self.url = url
        self.where = redacted(url)
        self.timeout_s = timeout_s
        self.read_only = read_only
        self._psycopg, self._dict_row = _driver()
        self.connection_errors = (self._psycopg.OperationalError, self._psycopg.InterfaceError)
        self._lock = threading.RLock()
        self._conn = None
        self._migrated = False
        self.applied: list[int] = []  # migrations this station applied
        self.last_error: str | None = None
        if not lazy:
            try:
                self._connect()
            except self.connection_errors as e:
                raise self.error(e, "cannot open the history") from e

    # -- the connection ----------------------------------------------------------------------------
    def _connect(self):
        if self._conn is not None and not self._conn.closed:
            return self._conn
        self._conn = None
        try:
            conn = self._psycopg.connect(self.url, connect_timeout=max(1, round(self.timeout_s)),
                                         autocommit=True, row_factory=self._dict_row,
                                         application_name="wheel-alignment-station")
        except self.connection_errors as e:
            self.last_error = _first_line(e)
            raise
        except self._psycopg.ProgrammingError as e:  # a URL psycopg cannot parse
            raise StorageError(f"{self.where}: not a usable PostgreSQL URL ({_first_line(e)})",
                               hint="history.url: postgresql://user:password@host:port/database") from None
        self._conn = conn
        if not self.read_only and not self._migrated:
            try:
                self.applied += self._apply(conn)
            except BaseException:
                self._drop()
                raise
        self.last_error = None
        return conn

    def _drop(self) -> None:
        if self._conn is not None:
            try:
                self._conn.close()
            except Exception:  # noqa: BLE001 - a connection already broken
                pass
        self._conn = None

    def _run(self, fn, retry: bool = True):
        """``fn(connection)`` under the lock; a lost connection is dropped and re-raised. A connection
        that died while idle (the server restarted since) is replaced once when ``retry`` (reads and
        idempotent writes only)."""
        with self._lock:
            fresh = self._conn is None or self._conn.closed
            conn = self._connect()
            try:
                return fn(conn)
            except self.connection_errors as e:
                self.last_error = _first_line(e)
                self._drop()
                if fresh or not retry:
                    raise
            conn = self._connect()
            try:
                return fn(conn)
            except self.connection_errors as e:
                self.last_error = _first_line(e)
                self._drop()
                raise

    # -- schema ------------------------------------------------------------------------------------
    def version(self) -> int:
        def read(conn):
            exists = conn.execute("SELECT to_regclass('schema_migrations') IS NOT NULL AS t").fetchone()["t"]
            if not exists:
                return 0
            return conn.execute("SELECT COALESCE(MAX(version), 0) AS v FROM schema_migrations").fetchone()["v"]
        return self._run(read)

    def migrate(self) -> list[int]:
        """Apply the migrations the server's history lacks; the versions this station applied."""
        with self._lock:
            conn = self._connect()
            self.applied += self._apply(conn)
            return sorted(set(self.applied))

    def _apply(self, conn) -> list[int]:
        """The pending migrations, in one transaction under an advisory lock."""
        done = []
        with conn.transaction():
            conn.execute("SELECT pg_advisory_xact_lock(%s)", (MIGRATION_LOCK,))
            conn.execute("CREATE TABLE IF NOT EXISTS schema_migrations (version INTEGER PRIMARY KEY, "
                         "name TEXT NOT NULL, applied_utc TIMESTAMPTZ NOT NULL DEFAULT now())")
            version = conn.execute("SELECT COALESCE(MAX(version), 0) AS v FROM schema_migrations").fetchone()["v"]
            if version > SCHEMA_VERSION:
                raise StorageError(f"{self.where}: history written by a newer station (schema {version})",
                                   hint="update the station software on every station sharing this history")
            for m in pending(version):
                conn.execute(m.postgresql)
                conn.execute("INSERT INTO schema_migrations (version, name) VALUES (%s, %s)", (m.version, m.name))
                done.append(m.version)
        self._migrated = True
        return done

    # -- errors ------------------------------------------------------------------------------------
    def is_duplicate(self, e: Exception) -> bool:
        return isinstance(e, self._psycopg.errors.UniqueViolation)

    def is_database_error(self, e: Exception) -> bool:
        return isinstance(e, self._psycopg.Error)

    def is_connection_error(self, e: Exception) -> bool:
        return isinstance(e, self.connection_errors)

    def error(self, e: Exception, doing: str) -> StorageError:
        if isinstance(e, StorageError):
            return e
        text = _first_line(e)
        if isinstance(e, self.connection_errors):
            if "password authentication failed" in text or "no password supplied" in text:
                return StorageError(f"{self.where}: {doing}: the history server refused the login ({text})",
                                    hint="check the user and password in history.url")
            if "does not exist" in text:
                return StorageError(f"{self.where}: {doing}: {text}",
                                    hint="create the database (createdb) or correct history.url")
            return StorageError(f"{self.where}: {doing}: cannot reach the history server ({text})",
                                hint="check that the PostgreSQL server runs and this station can reach it; "
                                     "measurements wait in the station's outbox meanwhile")
        return StorageError(f"{self.where}: {doing}: {text}")

    # -- writing -----------------------------------------------------------------------------------
    def contains(self, station: str, cycle_id: str) -> bool:
        return bool(self._run(lambda c: c.execute("SELECT 1 FROM cycles WHERE station = %s AND cycle_id = %s",
                                                  (station, cycle_id)).fetchone()))

    def insert(self, row: tuple, angles: list[tuple], *, idempotent: bool = False) -> int | None:
        """Insert one cycle and its angles in one transaction; its row id (None when
        ``idempotent`` and the server has the cycle already)."""
        def write(conn):
            with conn.transaction():
                got = conn.execute(
                    "INSERT INTO cycles (cycle_id, time_utc, job_id, vehicle_spec, valid, passed, calibration_id, "
                    "recording, software_version, station, result_json) "
                    "VALUES (%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s::jsonb)"
                    + (" ON CONFLICT (station, cycle_id) DO NOTHING" if idempotent else "") + " RETURNING id",
                    row).fetchone()
                if got is None:
                    return None
                with conn.cursor() as cur:
                    cur.executemany("INSERT INTO angles (cycle, name, value_deg, std_deg, passed) "
                                    "VALUES (%s,%s,%s,%s,%s)", [(got["id"], *a) for a in angles])
                return int(got["id"])
        return self._run(write, retry=idempotent)

    def insert_many(self, items: list[tuple[tuple, list[tuple]]]) -> int:
        """Insert many (row, angle rows) in one transaction, idempotently; how many were new."""
        def write(conn):
            new = 0
            with conn.transaction(), conn.cursor() as cur:
                for row, angles in items:
                    got = cur.execute(
                        "INSERT INTO cycles (cycle_id, time_utc, job_id, vehicle_spec, valid, passed, calibration_id, "
                        "recording, software_version, station, result_json) "
                        "VALUES (%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s::jsonb) "
                        "ON CONFLICT (station, cycle_id) DO NOTHING RETURNING id", row).fetchone()
                    if got is not None:
                        new += 1
                        cur.executemany("INSERT INTO angles (cycle, name, value_deg, std_deg, passed) "
                                        "VALUES (%s,%s,%s,%s,%s)", [(got["id"], *a) for a in angles])
            return new
        return self._run(write)

    # -- reading -----------------------------------------------------------------------------------
    def select(self, sql: str, args: list) -> tuple[list, dict]:
        def read(conn):
            rows = conn.execute(sql, args).fetchall()[::-1]
            ids = [r["id"] for r in rows]
            angles: dict[int, dict] = {i: {} for i in ids}
            if ids:
                for a in conn.execute("SELECT cycle, name, value_deg FROM angles WHERE cycle = ANY(%s)", (ids,)):
                    angles[a["cycle"]][a["name"]] = a["value_deg"]
            return rows, angles
        return self._run(read)

    def scalar_rows(self, sql: str, args=()) -> list[tuple]:
        return self._run(lambda c: [tuple(r.values()) for r in c.execute(sql, args).fetchall()])

    def check(self) -> str:
        """'ok', or the cycles whose angles are missing (the schema's keys guard the rest)."""
        bad = self.scalar_rows("SELECT c.cycle_id FROM cycles c LEFT JOIN angles a ON a.cycle = c.id "
                               "GROUP BY c.id, c.cycle_id HAVING COUNT(a.cycle) = 0 LIMIT 20")
        return "ok" if not bad else "cycles without angles: " + ", ".join(r[0] for r in bad)

    def close(self) -> None:
        with self._lock:
            self._drop()


def _first_line(e: Exception) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__
