"""The history's schema, as versioned migrations for both backends (one tool, plain SQL).

Each :class:`Migration` has a version, a name and its SQL for SQLite and for PostgreSQL; the
same version number means the same tables and columns in both. A history at version ``v`` gets
every migration above ``v`` applied in order, each in its own transaction, when a writer opens
it (``station history migrate`` does it on demand):

* SQLite keeps its version in ``PRAGMA user_version`` (version 1 is the layout every station
  wrote before migrations existed, so an existing history upgrades in place);
* PostgreSQL in the table ``schema_migrations`` (one row per applied migration, with its time),
  under an advisory lock so that two stations starting at once do not both migrate.

A history newer than :data:`SCHEMA_VERSION` is refused (written by a newer station).

PostgreSQL differs where the shop needs it: one history holds several stations, so a cycle is
unique by ``(station, cycle_id)`` (a cycle id is unique only within its station) and ``station``
is required; the result is ``jsonb`` (queryable), ids are ``bigint``.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Migration:
    version: int
    name: str
    sqlite: str
    postgresql: str


_SQLITE_1 = """
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

_POSTGRES_1 = """
CREATE TABLE IF NOT EXISTS cycles (
    id               BIGSERIAL PRIMARY KEY,
    cycle_id         TEXT NOT NULL,
    station          TEXT NOT NULL,          -- the station (config name) that measured it
    time_utc         TEXT NOT NULL,          -- ISO 8601, UTC, 'YYYY-MM-DDTHH:MM:SS.fffZ' (sortable)
    job_id           TEXT,
    vehicle_spec     TEXT,
    valid            SMALLINT NOT NULL,
    passed           SMALLINT,               -- NULL: no vehicle spec
    calibration_id   TEXT,
    recording        TEXT,
    software_version TEXT,
    result_json      JSONB NOT NULL,
    UNIQUE (station, cycle_id)
);
CREATE INDEX IF NOT EXISTS cycles_time ON cycles(time_utc);
CREATE INDEX IF NOT EXISTS cycles_job ON cycles(job_id, time_utc);
CREATE INDEX IF NOT EXISTS cycles_vehicle ON cycles(vehicle_spec, time_utc);
CREATE TABLE IF NOT EXISTS angles (
    cycle     BIGINT NOT NULL REFERENCES cycles(id) ON DELETE CASCADE,
    name      TEXT NOT NULL,
    value_deg DOUBLE PRECISION,
    std_deg   DOUBLE PRECISION,
    passed    SMALLINT,
    PRIMARY KEY (cycle, name)
);
"""

# version 2: the shop's listing of one bay ("what did bay 3 measure today") without a full scan
_STATION_INDEX = "CREATE INDEX IF NOT EXISTS cycles_station ON cycles(station, time_utc);"

MIGRATIONS: tuple[Migration, ...] = (
    Migration(1, "cycles and angles", _SQLITE_1, _POSTGRES_1),
    Migration(2, "index of cycles by station and time", _STATION_INDEX, _STATION_INDEX),
)
SCHEMA_VERSION = MIGRATIONS[-1].version
assert [m.version for m in MIGRATIONS] == list(range(1, SCHEMA_VERSION + 1))


def pending(version: int) -> list[Migration]:
    """The migrations a history at ``version`` still needs, in order."""
    return [m for m in MIGRATIONS if m.version > version]


def sqlite_schema() -> str:
    """The whole current schema for SQLite (an empty in-memory history)."""
    return "".join(m.sqlite for m in MIGRATIONS)
