"""Copy a station's SQLite history into a shared PostgreSQL history (``station history migrate --to URL``).

Every cycle with all its angle rows (value, uncertainty, pass/fail) and its whole result JSON;
each tagged with its station (the row's own ``station``, else the given default). The insert is
idempotent by (station, cycle id): a copy run twice, or resumed after a lost connection, adds
no duplicate. The source is opened read-only (nothing is written beside it) and upgraded by
nothing; the server's schema is migrated first.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from station.errors import StorageError
from station.records.history import ROW_COLUMNS
from station.records.history_postgres import PostgresBackend
from station.records.history_sqlite import SqliteBackend

BATCH = 250  # cycles per transaction on the server


@dataclass
class CopyReport:
    cycles: int = 0          # in the source
    inserted: int = 0        # new on the server
    already: int = 0         # on the server before (a second run)
    on_server: int = 0       # the server's cycles of the copied stations, after the copy
    seconds: float = 0.0


def copy_history(source, url: str, *, station: str | None = None, default_station: str = "station",
                 timeout_s: float = 10.0) -> CopyReport:
    """Copy the SQLite history ``source`` into the server at ``url``. ``station`` tags every
    cycle (default: each row's own station, else ``default_station``)."""
    t0 = time.perf_counter()
    report = CopyReport()
    src = SqliteBackend(source, read_only=True)
    dst = PostgresBackend(url, timeout_s=timeout_s)
    stations: set[str] = set()
    try:
        try:
            angles: dict[int, list[tuple]] = {}
            for cycle, *rest in src.scalar_rows("SELECT cycle, name, value_deg, std_deg, passed FROM angles "
                                                "ORDER BY cycle, name"):
                angles.setdefault(cycle, []).append(tuple(rest))
            rows = src.scalar_rows("SELECT id, " + ", ".join(ROW_COLUMNS) + " FROM cycles ORDER BY id")
        except Exception as e:  # noqa: BLE001
            if src.is_database_error(e):
                raise src.error(e, "cannot read the history to copy") from e
            raise
        at = ROW_COLUMNS.index("station")
        items = []
        for rowid, *row in rows:
            tag = station or row[at] or default_station
            row[at] = tag
            stations.add(tag)
            items.append((tuple(row), angles.get(rowid, [])))
        report.cycles = len(items)
        try:
            for start in range(0, len(items), BATCH):
                report.inserted += dst.insert_many(items[start:start + BATCH])
            report.already = report.cycles - report.inserted
            if stations:
                report.on_server = dst.scalar_rows("SELECT COUNT(*) FROM cycles WHERE station = ANY(%s)",
                                                   (sorted(stations),))[0][0]
        except Exception as e:  # noqa: BLE001
            if dst.is_database_error(e):
                raise dst.error(e, f"cannot copy the history ({report.inserted} of {report.cycles} cycles copied; "
                                   "run the same command again to finish: nothing is copied twice)") from e
            raise
    finally:
        src.close()
        dst.close()
    report.seconds = time.perf_counter() - t0
    if report.cycles and report.on_server < report.cycles:
        raise StorageError(f"{dst.where}: after the copy the server holds {report.on_server} of the "
                           f"{report.cycles} cycles", hint="run the same command again")
    return report
