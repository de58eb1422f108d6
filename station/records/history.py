"""The station's history: every cycle in an embedded SQLite database (WAL journal).

One row per cycle in ``cycles`` (time, job id / VIN, vehicle spec, pass/fail, calibration id,
recording, software version, the full result JSON) and one row per angle in ``angles``; a cycle
is written in ONE transaction, so a process killed mid-write leaves either the whole cycle or
none of it, and SQLite's journal keeps the file consistent. Every failure (corrupt file, locked
database, full disk, read-only folder) is a :class:`~station.errors.StorageError` that says what
to do; the caller keeps its result.

A reader (``History(path, read_only=True)``) writes nothing: a missing history reads as an
empty one (no file is made), and on a read-only disk the file is opened as SQLite's
"immutable" (no lock, no -shm/-wal files made), or read-only through its existing -shm
index when cycles are still in the -wal file.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import json
import math
import numbers
import os
import re
import shutil
import sqlite3
import tempfile
import threading
from pathlib import Path
from urllib.parse import quote

from station.compute.orphans import remove_orphans
from station.records.atomic_file import write_atomic
from station.records.printable import visible
from station.errors import StorageError
from station.result import ANGLE_NAMES, Measurement

SCHEMA_VERSION = 1
_SCHEMA = """
CREATE TABLE IF NOT EXISTS cycles (
    id               INTEGER PRIMARY KEY,
    cycle_id         TEXT NOT NULL UNIQUE,
    time_utc         TEXT NOT NULL,          -- ISO 8601, UTC, 'YYYY-MM-DDTHH:MM:SS.fffZ' (sortable)
    job_id           TEXT,
    vehicle_spec     TEXT,
    valid            INTEGER NOT NULL,
    passed           INTEGER,                -- NULL: no vehicle spec
    calibration_id   TEXT,
    recording        TEXT,
    software_version TEXT,
    station          TEXT,
    result_json      TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS cycles_time ON cycles(time_utc);
CREATE INDEX IF NOT EXISTS cycles_job ON cycles(job_id, time_utc);
CREATE INDEX IF NOT EXISTS cycles_vehicle ON cycles(vehicle_spec, time_utc);
CREATE TABLE IF NOT EXISTS angles (
    cycle     INTEGER NOT NULL REFERENCES cycles(id) ON DELETE CASCADE,
    name      TEXT NOT NULL,                 -- FL.toe ... thrust (docs/result-schema.md)
    value_deg REAL,
    std_deg   REAL,
    passed    INTEGER,                       -- NULL: no spec figure
    PRIMARY KEY (cycle, name)
) WITHOUT ROWID;
"""
_COPY = re.compile(r"station-history-(?P<pid>\d+)-.+")  # a reader's private copy (read-only disk)
_COLUMNS = ("id", "cycle_id", "time_utc", "job_id", "vehicle_spec", "valid", "passed",
            "calibration_id", "recording", "software_version", "station")


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


def _writable(path: Path) -> bool:
    """Whether SQLite may write ``path`` and create its -wal/-shm files beside it."""
    return os.access(path.parent, os.W_OK) and (not path.exists() or os.access(path, os.W_OK))


def _disk_problem(folder: Path) -> str | None:
    """Why ``folder`` cannot be written (read-only file system, full disk, permissions), if known."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return None
    if st.f_flag & os.ST_RDONLY:
        return "the data folder is on a read-only file system"
    if st.f_bavail == 0:
        return "the data disk is full"
    if not os.access(folder, os.W_OK):
        return "the data folder is not writable"
    return None


class History:
    """The history database at ``path`` (created on first use). ``timeout_s``: wait for a lock.
    ``read_only``: for reading only, creating no file (module docstring)."""

    def __init__(self, path: str | os.PathLike, *, timeout_s: float = 5.0, read_only: bool = False):
        self.path = Path(path)
        self.timeout_s = timeout_s
        self._lock = threading.RLock()
        self._copy_dir: str | None = None
        if read_only:
            try:
                self._conn = self._connect_read_only()
            except (sqlite3.Error, OSError) as e:
                self.close()
                raise self._error(e, "cannot open the history") from e
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # one connection, usable from the server's threads; self._lock serialises its use
            self._conn = sqlite3.connect(self.path, timeout=timeout_s, isolation_level=None,
                                         check_same_thread=False)
            self._conn.row_factory = sqlite3.Row
            self._conn.execute("PRAGMA foreign_keys=ON")
            mode = self._conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise sqlite3.OperationalError(f"cannot switch the journal to WAL (got {mode})")
            self._conn.execute("PRAGMA synchronous=FULL")
            version = self._conn.execute("PRAGMA user_version").fetchone()[0]
            if version > SCHEMA_VERSION:
                raise StorageError(f"{self.path}: history written by a newer station (schema {version})",
                                   hint="update the station software, or point data_dir elsewhere")
            if version < SCHEMA_VERSION:
                self._conn.executescript(f"BEGIN IMMEDIATE;{_SCHEMA}PRAGMA user_version={SCHEMA_VERSION};COMMIT;")
        except (sqlite3.Error, OSError) as e:
            raise self._error(e, "cannot open the history") from e

    def _connect_read_only(self) -> sqlite3.Connection:
        wal = self.path.with_name(self.path.name + "-wal")
        shm = self.path.with_name(self.path.name + "-shm")
        if not self.path.exists():
            return self._empty()
        if _writable(self.path):
            conn = self._connect(self.path, "mode=ro")
        elif not wal.exists() or wal.stat().st_size == 0:
            conn = self._connect(self.path, "immutable=1")  # every cycle is in the main file
        elif shm.exists():
            conn = self._connect(self.path, "mode=ro")  # SQLite reads the -wal through the -shm index
        else:
            # cycles in the -wal but no index to read them by, and none may be made there:
            # read a private copy (SQLite rebuilds the index beside the copy)
            remove_orphans(Path(tempfile.gettempdir()), _COPY)  # copies of readers that were killed
            self._copy_dir = tempfile.mkdtemp(prefix=f"station-history-{os.getpid()}-")
            copy = Path(self._copy_dir) / self.path.name
            shutil.copyfile(self.path, copy)
            shutil.copyfile(wal, copy.with_name(copy.name + "-wal"))
            conn = self._connect(copy, "mode=ro")
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION:
            conn.close()
            raise StorageError(f"{self.path}: history written by a newer station (schema {version})",
                               hint="update the station software, or point data_dir elsewhere")
        if version < SCHEMA_VERSION:  # an empty file (a first cycle that found the disk full): no cycles yet
            conn.close()
            return self._empty()
        return conn

    def _connect(self, path: Path, options: str) -> sqlite3.Connection:
        conn = sqlite3.connect(f"file:{quote(str(path))}?{options}", uri=True, timeout=self.timeout_s,
                               isolation_level=None, check_same_thread=False)
        conn.row_factory = sqlite3.Row
        return conn

    @staticmethod
    def _empty() -> sqlite3.Connection:
        """An empty history in memory: what a reader sees where no cycle was stored yet."""
        conn = sqlite3.connect(":memory:", isolation_level=None, check_same_thread=False)
        conn.row_factory = sqlite3.Row
        conn.executescript(_SCHEMA)
        return conn

    # -- errors ------------------------------------------------------------------------------------
    def _error(self, e: Exception, doing: str) -> StorageError:
        text = str(e)
        if isinstance(e, sqlite3.DatabaseError) and ("not a database" in text or "malformed" in text
                                                     or "corrupt" in text):
            return StorageError(f"{self.path}: {doing}: the history database is corrupt ({text})",
                                hint="move the file aside (keep it for recovery with `sqlite3 FILE .recover`); "
                                     "the station starts a new one")
        if "locked" in text or "busy" in text:
            return StorageError(f"{self.path}: {doing}: the history database is locked by another program "
                                f"for more than {self.timeout_s:g} s ({text})",
                                hint="close the program holding it (an open sqlite3 shell, a backup tool) and retry")
        if isinstance(e, OSError) or "readonly" in text or "read-only" in text or "disk" in text \
                or "unable to open" in text or "full" in text:
            reason = getattr(e, "strerror", None) or text
            problem = _disk_problem(self.path.parent)
            return StorageError(f"{self.path}: {doing}: {reason}" + (f" ({problem})" if problem else ""),
                                hint="check that the data folder exists, is writable and has free space")
        return StorageError(f"{self.path}: {doing}: {text}")

    # -- writing -----------------------------------------------------------------------------------
    def store(self, result: Measurement) -> int:
        """Store one cycle (its JSON, docs/result-schema.md) and its angles in one transaction.
        Returns the row id."""
        try:
            if result.cycle_id is None:
                raise KeyError("cycle_id")
            cycle_id = str(result.cycle_id)
            time_utc = normalize_time(result.time_utc)
        except (KeyError, TypeError, ValueError) as e:
            raise StorageError(f"cannot store a result without a valid cycle_id and time_utc ({e})") from None
        passed = (result.verdicts or {}).get("overall")
        row = (cycle_id, time_utc, result.job_id, result.vehicle_spec, int(bool(result.valid)),
               None if passed is None else int(bool(passed)), result.calibration_id, result.recording,
               result.software_version, result.station, json.dumps(jsonable(result.to_json()), allow_nan=False))
        try:
            c = self._conn
            self._lock.acquire()
            c.execute("BEGIN IMMEDIATE")
            try:
                cur = c.execute(
                    "INSERT INTO cycles (cycle_id, time_utc, job_id, vehicle_spec, valid, passed, "
                    "calibration_id, recording, software_version, station, result_json) "
                    "VALUES (?,?,?,?,?,?,?,?,?,?,?)", row)
                rowid = cur.lastrowid
                c.executemany("INSERT INTO angles (cycle, name, value_deg, std_deg, passed) VALUES (?,?,?,?,?)",
                              [(rowid, *a) for a in _angle_rows(result)])
                c.execute("COMMIT")
            except BaseException:
                if c.in_transaction:
                    c.execute("ROLLBACK")
                raise
            finally:
                self._lock.release()
        except sqlite3.IntegrityError as e:
            raise StorageError(f"{self.path}: cycle {cycle_id} is already in the history ({e})",
                               hint="every cycle needs a unique cycle_id") from None
        except ValueError as e:  # json: NaN/inf
            raise StorageError(f"cannot store cycle {cycle_id}: {e}") from None
        except (sqlite3.Error, OSError) as e:
            raise self._error(e, f"cannot store cycle {cycle_id}") from e
        return int(rowid)

    # -- reading -----------------------------------------------------------------------------------
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
            with self._lock:
                rows, angles = self._select(sql, args)
        except sqlite3.Error as e:
            raise self._error(e, "cannot read the history") from e
        out = []
        for r in rows:
            d = {k: r[k] for k in _COLUMNS}
            d["valid"] = bool(d["valid"])
            d["passed"] = None if d["passed"] is None else bool(d["passed"])
            d["angles"] = {n: angles[r["id"]].get(n) for n in ANGLE_NAMES}
            d["result"] = json.loads(r["result_json"])
            out.append(d)
        return out

    def _select(self, sql: str, args: list) -> tuple[list, dict]:
        rows = self._conn.execute(sql, args).fetchall()[::-1]
        ids = [r["id"] for r in rows]
        angles: dict[int, dict] = {i: {} for i in ids}
        for start in range(0, len(ids), 500):
            part = ids[start:start + 500]
            for a in self._conn.execute(
                    f"SELECT cycle, name, value_deg FROM angles WHERE cycle IN ({','.join('?' * len(part))})", part):
                angles[a["cycle"]][a["name"]] = a["value_deg"]
        return rows, angles

    def jobs(self, job_id: str) -> list[Measurement]:
        """The results of one job, in time order."""
        return [Measurement.from_json(r["result"]) for r in self.query(job=job_id)]

    def get(self, cycle_id: str) -> dict | None:
        """One cycle's row (as :meth:`query` returns), or None."""
        try:
            row = self._conn.execute("SELECT time_utc FROM cycles WHERE cycle_id = ?", (cycle_id,)).fetchone()
        except sqlite3.Error as e:
            raise self._error(e, "cannot read the history") from e
        if row is None:
            return None
        return next((r for r in self.query(since=row[0], until=row[0]) if r["cycle_id"] == cycle_id), None)

    def job_ids(self) -> list[tuple[str, int, str]]:
        """(job id, number of cycles, last time) of every job, newest first."""
        try:
            return [tuple(r) for r in self._conn.execute(
                "SELECT job_id, COUNT(*), MAX(time_utc) FROM cycles WHERE job_id IS NOT NULL "
                "GROUP BY job_id ORDER BY MAX(time_utc) DESC")]
        except sqlite3.Error as e:
            raise self._error(e, "cannot read the history") from e

    def check(self) -> str:
        """SQLite's integrity check: 'ok' or the problems found."""
        try:
            return "\n".join(r[0] for r in self._conn.execute("PRAGMA integrity_check"))
        except sqlite3.Error as e:
            raise self._error(e, "cannot check the history") from e

    def close(self) -> None:
        if getattr(self, "_conn", None) is not None:
            self._conn.close()
        if self._copy_dir is not None:
            shutil.rmtree(self._copy_dir, ignore_errors=True)
            self._copy_dir = None

    def __enter__(self) -> "History":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


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
