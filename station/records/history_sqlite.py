"""The history's SQLite backend: one file in the data folder (WAL journal, ``synchronous=FULL``).

A cycle is written in ONE transaction, so a process killed mid-write leaves either the whole
cycle or none of it, and SQLite's journal keeps the file consistent. Every failure (corrupt
file, locked database, full disk, read-only folder) is a :class:`~station.errors.StorageError`
that says what to do.

A reader (``read_only``) writes nothing: a missing history reads as an empty one (no file is
made), and on a read-only disk the file is opened as SQLite's "immutable" (no lock, no -shm/-wal
files made), or read-only through its existing -shm index when cycles are still in the -wal
file, or as a private copy when only the -wal is there. The schema is
:mod:`station.records.migrations`' (``PRAGMA user_version``); a writer upgrades an older file in
place, a reader reads any version up to the current one.
"""

from __future__ import annotations

import os
import re
import shutil
import sqlite3
import tempfile
import threading
from pathlib import Path
from urllib.parse import quote

from station.compute.orphans import remove_orphans
from station.errors import StorageError
from station.records.migrations import SCHEMA_VERSION, pending, sqlite_schema

_COPY = re.compile(r"station-history-(?P<pid>\d+)-.+")  # a reader's private copy (read-only disk)


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


def _newer(where, version: int) -> StorageError:
    return StorageError(f"{where}: history written by a newer station (schema {version})",
                        hint="update the station software, or point data_dir elsewhere")


class SqliteBackend:
    """The SQL of :class:`station.records.history.History` on one SQLite file."""

    placeholder = "?"
    shared = False  # one station's history: a cycle is unique by its cycle_id alone
    connection_errors = ()  # no server to lose

    def __init__(self, path, *, timeout_s: float = 5.0, read_only: bool = False):
        self.path = Path(path)
        self.where = str(self.path)
        self.timeout_s = timeout_s
        self._lock = threading.RLock()
        self._copy_dir: str | None = None
        self._conn = None
        if read_only:
            try:
                self._conn = self._connect_read_only()
            except (sqlite3.Error, OSError) as e:
                self.close()
                raise self.error(e, "cannot open the history") from e
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
            self.migrate()
        except (sqlite3.Error, OSError) as e:
            raise self.error(e, "cannot open the history") from e

    # -- schema ------------------------------------------------------------------------------------
    def version(self) -> int:
        return self._conn.execute("PRAGMA user_version").fetchone()[0]

    def migrate(self) -> list[int]:
        """Apply the migrations this file lacks (each in one transaction); their versions."""
        version = self.version()
        if version > SCHEMA_VERSION:
            raise _newer(self.path, version)
        done = []
        for m in pending(version):
            self._conn.executescript(f"BEGIN IMMEDIATE;{m.sqlite}PRAGMA user_version={m.version};COMMIT;")
            done.append(m.version)
        return done

    # -- reading without writing -------------------------------------------------------------------
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
            raise _newer(self.path, version)
        if version < 1:  # an empty file (a first cycle that found the disk full): no cycles yet
            conn.close()
            return self._empty()
        return conn  # any older version reads as it is: the migrations since 1 add no column

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
        conn.executescript(sqlite_schema())
        return conn

    # -- errors ------------------------------------------------------------------------------------
    def error(self, e: Exception, doing: str) -> StorageError:
        text = str(e)
        if isinstance(e, StorageError):
            return e
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

    def is_duplicate(self, e: Exception) -> bool:
        return isinstance(e, sqlite3.IntegrityError)

    def is_database_error(self, e: Exception) -> bool:
        return isinstance(e, (sqlite3.Error, OSError))

    # -- writing -----------------------------------------------------------------------------------
    def insert(self, row: tuple, angles: list[tuple], *, idempotent: bool = False) -> int | None:
        """Insert one cycle (``row`` in history.ROW_COLUMNS order) and its angle rows in one
        transaction; its row id (None when ``idempotent`` and the cycle is already there)."""
        c = self._conn
        with self._lock:
            c.execute("BEGIN IMMEDIATE")
            try:
                cur = c.execute(
                    "INSERT " + ("OR IGNORE " if idempotent else "") + "INTO cycles (cycle_id, time_utc, job_id, "
                    "vehicle_spec, valid, passed, calibration_id, recording, software_version, station, result_json) "
                    "VALUES (?,?,?,?,?,?,?,?,?,?,?)", row)
                if idempotent and cur.rowcount == 0:
                    c.execute("ROLLBACK")
                    return None
                rowid = cur.lastrowid
                c.executemany("INSERT INTO angles (cycle, name, value_deg, std_deg, passed) VALUES (?,?,?,?,?)",
                              [(rowid, *a) for a in angles])
                c.execute("COMMIT")
            except BaseException:
                if c.in_transaction:
                    c.execute("ROLLBACK")
                raise
        return int(rowid)

    # -- reading -----------------------------------------------------------------------------------
    def select(self, sql: str, args: list) -> tuple[list, dict]:
        """(rows, {row id: {angle name: deg}}) of a SELECT on cycles that includes ``id``."""
        with self._lock:
            rows = self._conn.execute(sql, args).fetchall()[::-1]
            ids = [r["id"] for r in rows]
            angles: dict[int, dict] = {i: {} for i in ids}
            for start in range(0, len(ids), 500):
                part = ids[start:start + 500]
                for a in self._conn.execute(
                        f"SELECT cycle, name, value_deg FROM angles WHERE cycle IN ({','.join('?' * len(part))})", part):
                    angles[a["cycle"]][a["name"]] = a["value_deg"]
        return rows, angles

    def scalar_rows(self, sql: str, args=()) -> list[tuple]:
        with self._lock:
            return [tuple(r) for r in self._conn.execute(sql, args)]

    def check(self) -> str:
        """SQLite's integrity check: 'ok' or the problems found."""
        return "\n".join(r[0] for r in self.scalar_rows("PRAGMA integrity_check"))

    def close(self) -> None:
        if getattr(self, "_conn", None) is not None:
            self._conn.close()
        if self._copy_dir is not None:
            shutil.rmtree(self._copy_dir, ignore_errors=True)
            self._copy_dir = None
