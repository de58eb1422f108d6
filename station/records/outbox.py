"""The outbox: cycles a shared history's server has not taken yet, kept on the station's disk.

A station whose history is a PostgreSQL server (``history.url``) writes every cycle here first
(``<data_dir>/history-outbox.sqlite``, WAL journal, ``synchronous=FULL``: on disk before the
PLC sees the result), then sends it; a cycle leaves the outbox only after the server committed
it. The insert on the server is idempotent (unique by station and cycle id), so a connection
lost between the server's commit and the removal here sends the cycle again harmlessly: each
cycle reaches the server exactly once. ``station history`` shows how many wait.
"""

from __future__ import annotations

import datetime as dt
import json
import sqlite3
import threading
from dataclasses import dataclass
from pathlib import Path

from station.errors import StorageError

_SCHEMA = """
CREATE TABLE IF NOT EXISTS outbox (
    seq        INTEGER PRIMARY KEY,
    station    TEXT NOT NULL,
    cycle_id   TEXT NOT NULL,
    row_json   TEXT NOT NULL,     -- [cycle row, angle rows] as the history inserts them
    queued_utc TEXT NOT NULL,
    attempts   INTEGER NOT NULL DEFAULT 0,
    last_error TEXT,
    UNIQUE (station, cycle_id)
);
"""


@dataclass(frozen=True)
class Pending:
    seq: int
    station: str
    cycle_id: str
    row: tuple
    angles: list[tuple]


class Outbox:
    """The outbox file at ``path`` (created on first use)."""

    def __init__(self, path, *, timeout_s: float = 5.0):
        self.path = Path(path)
        self._lock = threading.RLock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._conn = sqlite3.connect(self.path, timeout=timeout_s, isolation_level=None,
                                         check_same_thread=False)
            self._conn.execute("PRAGMA journal_mode=WAL")
            self._conn.execute("PRAGMA synchronous=FULL")
            self._conn.executescript(_SCHEMA)
        except (sqlite3.Error, OSError) as e:
            raise StorageError(f"{self.path}: cannot open the history's outbox ({e})",
                               hint="check that the data folder exists, is writable and has free space") from e

    def put(self, station: str, cycle_id: str, row: tuple, angles: list[tuple]) -> None:
        """Keep one cycle until the server has it; StorageError if it waits here already or the disk refuses."""
        now = dt.datetime.now(dt.timezone.utc).isoformat(timespec="milliseconds")
        try:
            with self._lock:
                self._conn.execute("INSERT INTO outbox (station, cycle_id, row_json, queued_utc) VALUES (?,?,?,?)",
                                   (station, cycle_id, json.dumps([list(row), [list(a) for a in angles]]), now))
        except sqlite3.IntegrityError:
            raise StorageError(f"cycle {cycle_id} of station {station} waits in the outbox already",
                               hint="every cycle needs a unique cycle_id") from None
        except sqlite3.Error as e:
            raise StorageError(f"{self.path}: cannot keep cycle {cycle_id} in the outbox ({e})",
                               hint="check that the data folder is writable and has free space") from e

    def pending(self, limit: int = 1000) -> list[Pending]:
        """The waiting cycles, oldest first."""
        with self._lock:
            rows = self._conn.execute("SELECT seq, station, cycle_id, row_json FROM outbox ORDER BY seq LIMIT ?",
                                      (limit,)).fetchall()
        out = []
        for seq, station, cycle_id, text in rows:
            row, angles = json.loads(text)
            out.append(Pending(seq, station, cycle_id, tuple(row), [tuple(a) for a in angles]))
        return out

    def remove(self, seq: int) -> None:
        with self._lock:
            self._conn.execute("DELETE FROM outbox WHERE seq = ?", (seq,))

    def note(self, seq: int, error: str) -> None:
        """Count a failed attempt to send cycle ``seq`` and keep why."""
        with self._lock:
            self._conn.execute("UPDATE outbox SET attempts = attempts + 1, last_error = ? WHERE seq = ?",
                               (error[:500], seq))

    def count(self) -> int:
        with self._lock:
            return self._conn.execute("SELECT COUNT(*) FROM outbox").fetchone()[0]

    def close(self) -> None:
        self._conn.close()
