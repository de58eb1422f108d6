"""The station's history: every cycle, one interface over two backends.

One row per cycle in ``cycles`` (time, job id / VIN, vehicle spec, pass/fail, calibration id,
recording, software version, station, the full result JSON) and one row per angle in ``angles``;
a cycle is written in ONE transaction, so a process killed mid-write leaves either the whole
cycle or none of it. Every failure (corrupt file, locked database, full disk, read-only folder,
a history server that cannot be reached) is a :class:`~station.errors.StorageError` that says
what to do; the caller keeps its result.

Backends: an embedded SQLite file, the default (``station/records/history_sqlite.py``), or a
PostgreSQL server shared by the shop's stations (``history.url``,
``station/records/history_postgres.py``) with a local outbox so that a lost connection loses no
cycle (``station/records/outbox.py``). Their schema is versioned (``migrations.py``); a writer
upgrades an older history in place.

A reader (``History(path, read_only=True)``) writes nothing: a missing SQLite history reads as
an empty one (no file is made), and on a read-only disk the file is opened as SQLite's
"immutable" (history_sqlite.py).
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import json
import math
import numbers
import os
import logging
from pathlib import Path

from station.records.atomic_file import write_atomic
from station.records.printable import visible
from station.errors import StorageError
from station.records.migrations import SCHEMA_VERSION  # noqa: F401 - the history's schema version
from station.result import ANGLE_NAMES, Measurement

log = logging.getLogger("station.history")
URL_SCHEMES = ("postgresql://", "postgres://")
OUTBOX_FILE = "history-outbox.sqlite"  # in the data folder: cycles the history server has not taken yet

_COLUMNS = ("id", "cycle_id", "time_utc", "job_id", "vehicle_spec", "valid", "passed",
            "calibration_id", "recording", "software_version", "station")
ROW_COLUMNS = ("cycle_id", "time_utc", "job_id", "vehicle_spec", "valid", "passed", "calibration_id",
               "recording", "software_version", "station", "result_json")  # what a backend inserts


def jsonable(obj):
    """``obj`` with numpy scalars/arrays as Python numbers/lists and NaN/inf as None (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):  # numpy arrays and scalars
        return jsonable(obj.tolist())
    if isinstance(obj, bool) or obj is None or isinstance(obj, (str, int)):
        return obj
    if isinstance(obj, numbers.Real):
        f = float(obj)
        return f if math.isfinite(f) else None
    return str(obj)


def finite_number(v) -> float | None:
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def normalize_time(text: str | dt.datetime) -> str:
    """Any ISO 8601 time -> 'YYYY-MM-DDTHH:MM:SS.fffZ' in UTC (naive times are taken as UTC)."""
    if isinstance(text, dt.datetime):
        t = text
    else:
        t = dt.datetime.fromisoformat(str(text).strip().replace("Z", "+00:00"))
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.timezone.utc)
    t = t.astimezone(dt.timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def time_bound(value, *, end: bool) -> str:
    """A --since/--until value -> a normalised time. A bare date as ``until`` covers that whole day."""
    if isinstance(value, dt.date) and not isinstance(value, dt.datetime):
        day = value
    else:
        text = str(value).strip()
        if len(text) == 10:
            day = dt.date.fromisoformat(text)
        else:
            return normalize_time(value)
    t = dt.datetime.combine(day, dt.time(0), tzinfo=dt.timezone.utc)
    if end:
        t += dt.timedelta(days=1) - dt.timedelta(milliseconds=1)
    return normalize_time(t)


def _angle_rows(result: Measurement) -> list[tuple[str, float | None, float | None, int | None]]:
    """(name, value deg, std deg, passed) of every named angle of a result."""
    passes = result.verdicts or {}
    rows = []
    for name in ANGLE_NAMES:
        head, _, kind = name.partition(".")
        if name == "thrust":
            std = result.thrust_std_deg
        elif head in result.axles:
            std = result.axles[head].total_toe_std_deg
        else:
            std = getattr(result.wheels.get(head), f"{kind}_std_deg", None)
        p = passes.get(name)
        rows.append((name, finite_number(result.angle(name)), finite_number(std), None if p is None else int(bool(p))))
    return rows


def is_url(text) -> bool:
    """Whether ``text`` names a history server (``postgresql://...``) rather than a file."""
    return isinstance(text, str) and text.startswith(URL_SCHEMES)


class History:
    """The history at ``path``: a SQLite file (created on first use) or a PostgreSQL server's URL
    (``postgresql://user:password@host:port/db``). ``timeout_s``: wait for a lock (SQLite) or a
    connection (PostgreSQL). ``read_only``: for reading only, creating nothing (module docstring).

    A server's history is shared by several stations: ``station`` tags each stored cycle (the
    configured station name), and ``outbox`` (a SQLite file in the data folder) keeps every
    cycle until the server has it, so a lost connection loses no measurement
    (:mod:`station.records.outbox`). The SQL lives in the backends
    (``history_sqlite.py``, ``history_postgres.py``); this class is what callers see.
    """

    def __init__(self, path: str | os.PathLike, *, timeout_s: float = 5.0, read_only: bool = False,
                 station: str | None = None, outbox: str | os.PathLike | None = None):
        self.station = station
        self._outbox = None
        self.last_queued = False  # whether the last store() left its cycle in the outbox
        if is_url(path):
            from station.records.history_postgres import PostgresBackend
            self._backend = PostgresBackend(path, timeout_s=timeout_s, read_only=read_only,
                                            lazy=outbox is not None and not read_only)
            if outbox is not None and not read_only:
                from station.records.outbox import Outbox
                try:
                    self._outbox = Outbox(outbox, timeout_s=max(timeout_s, 5.0))
                except StorageError:
                    self._backend.close()
                    raise
        else:
            from station.records.history_sqlite import SqliteBackend
            self._backend = SqliteBackend(path, timeout_s=timeout_s, read_only=read_only)
        self.path = getattr(self._backend, "path", None)
        self.where = self._backend.where
        self.timeout_s = timeout_s

    @property
    def _conn(self):
        """The backend's open connection (diagnostics and tests)."""
        return self._backend._conn

    @property
    def shared(self) -> bool:
        """Whether this history is a server's, shared by stations."""
        return self._backend.shared

    def version(self) -> int:
        """The schema version of the history (station/records/migrations.py)."""
        try:
            return self._backend.version()
        except Exception as e:  # noqa: BLE001 - a backend's driver error, wrapped
            if self._backend.is_database_error(e):
                raise self._backend.error(e, "cannot read the history's version") from e
            raise

    def migrate(self) -> list[int]:
        """Apply the schema migrations the history lacks; the versions applied."""
        try:
            return self._backend.migrate()
        except Exception as e:  # noqa: BLE001
            if self._backend.is_database_error(e):
                raise self._backend.error(e, "cannot upgrade the history") from e
            raise

    # -- writing -----------------------------------------------------------------------------------
    def _row(self, result: Measurement) -> tuple[tuple, list[tuple]]:
        """(cycle row in ROW_COLUMNS order, angle rows) of ``result``; StorageError if it cannot be stored."""
        try:
            if result.cycle_id is None:
                raise KeyError("cycle_id")
            cycle_id = str(result.cycle_id)
            time_utc = normalize_time(result.time_utc)
        except (KeyError, TypeError, ValueError) as e:
            raise StorageError(f"cannot store a result without a valid cycle_id and time_utc ({e})") from None
        station = result.station
        if self.shared:  # the shop's history: every cycle tagged with the station that measured it
            station = self.station or result.station or "station"
        passed = (result.verdicts or {}).get("overall")
        try:
            text = json.dumps(jsonable(result.to_json()), allow_nan=False)
        except ValueError as e:  # json: NaN/inf
            raise StorageError(f"cannot store cycle {cycle_id}: {e}") from None
        row = (cycle_id, time_utc, result.job_id, result.vehicle_spec, int(bool(result.valid)),
               None if passed is None else int(bool(passed)), result.calibration_id, result.recording,
               result.software_version, station, text)
        return row, _angle_rows(result)

    def store(self, result: Measurement) -> int:
        """Store one cycle (its JSON, docs/result-schema.md) and its angles in one transaction.
        Returns the row id; 0 for a shared history whose server cannot take it now: the cycle
        then waits in the outbox (``last_queued``) and is sent by a later store() or flush()."""
        row, angles = self._row(result)
        cycle_id = row[0]
        b = self._backend
        if self._outbox is None:
            try:
                return b.insert(row, angles)
            except Exception as e:  # noqa: BLE001 - the backend's driver errors, wrapped below
                if b.is_duplicate(e):
                    raise StorageError(f"{self.where}: cycle {cycle_id} is already in the history ({e})",
                                       hint="every cycle needs a unique cycle_id") from None
                if b.is_database_error(e):
                    raise b.error(e, f"cannot store cycle {cycle_id}") from e
                raise
        station = row[ROW_COLUMNS.index("station")]
        try:
            known = b.contains(station, cycle_id)
        except Exception as e:  # noqa: BLE001 - the server is away: the outbox keeps the cycle
            if not b.is_connection_error(e):
                raise b.error(e, f"cannot store cycle {cycle_id}") if b.is_database_error(e) else e
            known = False
        if known:
            raise StorageError(f"{self.where}: cycle {cycle_id} of station {station} is already in the history",
                               hint="every cycle needs a unique cycle_id")
        self._outbox.put(station, cycle_id, row, angles)  # on the station's disk before anything is sent
        sent = self.flush()
        self.last_queued = (station, cycle_id) not in sent
        if self.last_queued:
            log.warning("cycle %s kept in the outbox (%s): %s", cycle_id, self._outbox.path, b.last_error)
        return sent.get((station, cycle_id)) or 0

    def flush(self) -> dict[tuple[str, str], int | None]:
        """Send the outbox's cycles to the server, oldest first, each exactly once (the insert is
        idempotent by station and cycle id, and a cycle leaves the outbox only once the server
        has committed it). Returns {(station, cycle id): row id (None: it was there already)}
        of the cycles sent now; stops at the first lost connection."""
        if self._outbox is None:
            return {}
        b, sent = self._backend, {}
        for item in self._outbox.pending():
            try:
                rowid = b.insert(item.row, item.angles, idempotent=True)
            except Exception as e:  # noqa: BLE001 - the driver's; kept in the outbox either way
                if not b.is_database_error(e):
                    raise
                self._outbox.note(item.seq, str(e).splitlines()[0] if str(e) else type(e).__name__)
                if b.is_connection_error(e):
                    break
                log.warning("cycle %s refused by the history server, kept in the outbox: %s", item.cycle_id, e)
                continue
            self._outbox.remove(item.seq)
            sent[(item.station, item.cycle_id)] = rowid
        return sent

    def queued(self) -> int:
        """Cycles waiting in the outbox for the server (0 without one)."""
        return 0 if self._outbox is None else self._outbox.count()

    # -- reading -----------------------------------------------------------------------------------
    def _fail(self, e: Exception, doing: str):
        if self._backend.is_database_error(e):
            raise self._backend.error(e, doing) from e
        raise e

    def query(self, job: str | None = None, since=None, until=None, vehicle: str | None = None,
              passed: bool | None = None, limit: int | None = None) -> list[dict]:
        """Cycles in time order, filtered. ``since``/``until``: ISO date or time (a bare ``until``
        date includes that day). Each row: the columns, ``angles`` {name: deg} and ``result``."""
        where, args = [], []
        if job is not None:
            where.append("job_id = ?"); args.append(job)
        if vehicle is not None:
            where.append("vehicle_spec = ?"); args.append(vehicle)
        if since is not None:
            where.append("time_utc >= ?"); args.append(time_bound(since, end=False))
        if until is not None:
            where.append("time_utc <= ?"); args.append(time_bound(until, end=True))
        if passed is not None:
            where.append("passed = ?"); args.append(int(bool(passed)))
        sql = ("SELECT " + ", ".join(_COLUMNS) + ", result_json FROM cycles"
               + (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY time_utc DESC, id DESC")
        if limit is not None:
            sql += f" LIMIT {int(limit)}"
        try:
            rows, angles = self._backend.select(sql.replace("?", self._backend.placeholder), args)
        except Exception as e:  # noqa: BLE001
            self._fail(e, "cannot read the history")
        out = []
        for r in rows:
            d = {k: r[k] for k in _COLUMNS}
            d["valid"] = bool(d["valid"])
            d["passed"] = None if d["passed"] is None else bool(d["passed"])
            d["angles"] = {n: angles[r["id"]].get(n) for n in ANGLE_NAMES}
            raw = r["result_json"]
            d["result"] = json.loads(raw) if isinstance(raw, (str, bytes)) else raw
            out.append(d)
        return out

    def jobs(self, job_id: str) -> list[Measurement]:
        """The results of one job, in time order."""
        return [Measurement.from_json(r["result"]) for r in self.query(job=job_id)]

    def get(self, cycle_id: str) -> dict | None:
        """One cycle's row (as :meth:`query` returns), or None."""
        try:
            found = self._backend.scalar_rows(
                "SELECT time_utc FROM cycles WHERE cycle_id = ?".replace("?", self._backend.placeholder), (cycle_id,))
        except Exception as e:  # noqa: BLE001
            self._fail(e, "cannot read the history")
        if not found:
            return None
        t = found[0][0]
        return next((r for r in self.query(since=t, until=t) if r["cycle_id"] == cycle_id), None)

    def job_ids(self) -> list[tuple[str, int, str]]:
        """(job id, number of cycles, last time) of every job, newest first."""
        try:
            return self._backend.scalar_rows(
                "SELECT job_id, COUNT(*), MAX(time_utc) FROM cycles WHERE job_id IS NOT NULL "
                "GROUP BY job_id ORDER BY MAX(time_utc) DESC")
        except Exception as e:  # noqa: BLE001
            self._fail(e, "cannot read the history")

    def check(self) -> str:
        """The backend's consistency check: 'ok' or the problems found."""
        try:
            return self._backend.check()
        except Exception as e:  # noqa: BLE001
            self._fail(e, "cannot check the history")

    def close(self) -> None:
        backend = getattr(self, "_backend", None)
        if backend is not None:
            backend.close()
        if self._outbox is not None:
            self._outbox.close()

    def __enter__(self) -> "History":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_history(config, *, read_only: bool = False) -> History:
    """The configured history: ``history.url`` (a PostgreSQL server, cycles tagged with the
    station's name, an outbox in the data folder) or, by default, ``<data_dir>/history.sqlite``."""
    url = config.history.url
    if url is None:
        return History(config.data_path("history.sqlite"), read_only=read_only)
    return History(url, read_only=read_only, station=config.name, timeout_s=config.history.connect_timeout_s,
                   outbox=None if read_only else config.data_path(OUTBOX_FILE))

# --- CSV --------------------------------------------------------------------------------------------
CSV_COLUMNS = ("cycle_id", "time_utc", "job_id", "vehicle_spec", "valid", "passed", *ANGLE_NAMES,
               "calibration_id", "software_version", "recording")


def _cell(v):
    """A CSV cell; control characters are written escaped (records/printable.py) and text that a
    spreadsheet would run as a formula is quoted with a leading '."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return f"{v:.4f}"
    v = visible(str(v))
    return "'" + v if v[:1] in ("=", "+", "-", "@", "\t", "\r") else v


def export_csv(rows: list[dict], path_or_file) -> int:
    """Write rows from :meth:`History.query` as CSV (one line per cycle). Returns the row count.

    A path is written to a temporary file and renamed, so a failed export leaves no half file.
    """
    def write(f):
        w = csv.writer(f, lineterminator="\n")
        w.writerow(CSV_COLUMNS)
        for r in rows:
            w.writerow([_cell(r["angles"].get(c) if c in ANGLE_NAMES else r.get(c)) for c in CSV_COLUMNS])

    if isinstance(path_or_file, io.IOBase) or hasattr(path_or_file, "write"):
        write(path_or_file)
        return len(rows)
    path = Path(path_or_file)
    try:
        write_atomic(path, write, newline="")
    except OSError as e:
        raise StorageError(f"{path}: cannot write the CSV export: {e.strerror or e}",
                           hint="choose a writable folder with free space") from e
    return len(rows)


def send_outbox(config) -> int:
    """Send the cycles waiting in the configured station's outbox; how many the server took now
    (0 without a shared history or an outbox)."""
    if config.history.url is None or not config.data_path(OUTBOX_FILE).exists():
        return 0
    with open_history(config) as history:
        if not history.queued():
            return 0
        return len(history.flush())
