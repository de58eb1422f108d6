"""The shared history on a real PostgreSQL server (Debian's package, started by these tests in a
temporary folder on 127.0.0.1), the schema migrations of both backends, the copy of a SQLite
history into the server, and the outbox that keeps every cycle while the server is away."""

from __future__ import annotations

import sqlite3

import pytest
import yaml

from result_builder import make_result
from station.errors import ConfigError, StorageError
from station.records.history import History
from station.records.migrations import MIGRATIONS, SCHEMA_VERSION
from station.result import ANGLE_NAMES

psycopg = pytest.importorskip("psycopg", reason="the PostgreSQL driver (psycopg, the `shop` extra) is not installed")
pg_server = pytest.importorskip("pg_server")
if pg_server.binaries() is None:
    pytest.skip("Debian's postgresql package is not installed (setup.sh installs it)", allow_module_level=True)

_DBS = iter(range(1, 1000))


@pytest.fixture(scope="session")
def pg():
    server = pg_server.TempPostgres()
    server.start()
    yield server
    server.destroy()


@pytest.fixture
def url(pg):
    """A fresh database on the running server for each test."""
    if not pg.running():
        pg.start()
    return pg.create_db(f"shop{next(_DBS)}")


def _fill(h: History, n: int, start: int = 1) -> list:
    results = [make_result(i, cycle=i, job_id=f"JOB-{i % 3}") for i in range(start, start + n)]
    for r in results:
        h.store(r)
    return results


def _count(url: str, sql: str = "SELECT COUNT(*) FROM cycles") -> int:
    with psycopg.connect(url) as c:
        return c.execute(sql).fetchone()[0]


def test_postgres_round_trip_matches_sqlite(url, tmp_path):
    with History(url, station="bay-1") as pgh, History(tmp_path / "h.sqlite") as sq:
        for h in (pgh, sq):
            _fill(h, 5)
            h.store(make_result(9, cycle=9, valid=False, job_id="JOB-F"))
        assert pgh.version() == sq.version() == SCHEMA_VERSION
        a, b = pgh.query(), sq.query()
        assert len(a) == len(b) == 6
        for x, y in zip(a, b):
            for k in ("cycle_id", "time_utc", "job_id", "valid", "passed", "result"):
                assert x[k] == y[k], k
            assert x["angles"] == pytest.approx(y["angles"], nan_ok=True, abs=1e-6)
            assert x["station"] == "bay-1" and y["station"] == "test bay"
        assert [r["cycle_id"] for r in pgh.query(job="JOB-1", since="2026-11-22")] == \
               [r["cycle_id"] for r in sq.query(job="JOB-1", since="2026-11-22")]
        assert pgh.job_ids() == sq.job_ids()
        assert pgh.get(a[2]["cycle_id"])["cycle_id"] == a[2]["cycle_id"] and pgh.get("nope") is None
        assert [m.cycle_id for m in pgh.jobs("JOB-2")] == [m.cycle_id for m in sq.jobs("JOB-2")]
        assert pgh.check() == "ok"
        with pytest.raises(StorageError, match="already in the history"):
            pgh.store(make_result(1, cycle=1))
    assert _count(url, "SELECT COUNT(*) FROM angles") == 6 * len(ANGLE_NAMES)


def test_two_stations_share_one_history(url, tmp_path):
    """The same cycle id from two stations is two cycles; each is tagged with its station."""
    with History(url, station="bay-1", outbox=tmp_path / "o1.sqlite") as h1, \
            History(url, station="bay-2", outbox=tmp_path / "o2.sqlite") as h2:
        _fill(h1, 3)
        _fill(h2, 3)
        rows = h1.query()
    assert sorted((r["station"], r["cycle_id"][-4:]) for r in rows) == \
        sorted((s, f"{i:04d}") for s in ("bay-1", "bay-2") for i in (1, 2, 3))


def test_sqlite_history_upgrades_in_place(tmp_path):
    """A version-1 file (what every station wrote before migrations) keeps its cycles and gets version 2."""
    p = tmp_path / "history.sqlite"
    with History(p) as h:
        _fill(h, 3)
    con = sqlite3.connect(p)
    con.execute("DROP INDEX cycles_station")
    con.execute("PRAGMA user_version=1")
    con.commit()
    con.close()
    with History(p, read_only=True) as h:  # a reader reads it as it is, writing nothing
        assert h.version() == 1 and len(h.query()) == 3
    with History(p) as h:
        assert h.version() == SCHEMA_VERSION == 2 and len(h.query()) == 3
    con = sqlite3.connect(p)
    assert con.execute("SELECT name FROM sqlite_master WHERE name='cycles_station'").fetchone()
    con.execute(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    con.commit()
    con.close()
    with pytest.raises(StorageError, match="newer station"):
        History(p)


def test_postgres_migrations_recorded_and_newer_refused(url):
    with History(url, station="bay-1") as h:
        assert h.version() == SCHEMA_VERSION
    with psycopg.connect(url, autocommit=True) as c:
        assert [r[0] for r in c.execute("SELECT version FROM schema_migrations ORDER BY version")] == \
            [m.version for m in MIGRATIONS]
        c.execute("INSERT INTO schema_migrations (version, name) VALUES (%s, 'future')", (SCHEMA_VERSION + 1,))
    with pytest.raises(StorageError, match="newer station"):
        History(url, station="bay-1")


def _config(tmp_path, url=None, name="bay-1") -> str:
    from station.config import DEFAULT_CONFIG
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    for key in ("vehicle_specs",):
        data[key] = str(DEFAULT_CONFIG.parent / data.get(key, "vehicles.yaml"))
    data["calibration"]["box"] = str(DEFAULT_CONFIG.parent / data["calibration"].get("box", "box.yaml"))
    data["name"] = name
    if url:
        data["history"] = {"url": url, "connect_timeout_s": 2}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_migrate_copies_sqlite_into_postgres_idempotently(url, tmp_path, station_data_dir, capsys):
    from station.cli import main
    station_data_dir.mkdir(parents=True, exist_ok=True)
    with History(station_data_dir / "history.sqlite") as h:
        results = _fill(h, 40)
        h.store(make_result(99, cycle=99, valid=False))
        local = h.query()
    cfg = _config(tmp_path)
    for run in (1, 2):
        assert main(["--config", cfg, "history", "migrate", "--to", url]) == 0
        out = capsys.readouterr().out
        assert "41 cycle(s) read" in out and (f"{41 if run == 1 else 0} new" in out)
        assert "s3cret" not in out
        assert _count(url) == 41 and _count(url, "SELECT COUNT(*) FROM angles") == 41 * len(ANGLE_NAMES)
    with History(url, read_only=True) as shared:
        remote = shared.query()
    assert [r["cycle_id"] for r in remote] == [r["cycle_id"] for r in local]
    assert all(r["station"] == "test bay" for r in remote)  # each cycle keeps its own station
    assert [r["result"] for r in remote] == [r["result"] for r in local]
    assert remote[0]["angles"] == pytest.approx(local[0]["angles"])
    with psycopg.connect(url) as c:  # uncertainty and pass/fail per angle came along too
        std = c.execute("SELECT COUNT(*) FROM angles WHERE std_deg IS NOT NULL").fetchone()[0]
    assert std > 0 and len(results) == 40
    # `station history` on the shared history, as any station of the shop configured for it
    assert main(["--config", _config(tmp_path, url, "desk"), "history", "--limit", "3"]) == 0
    assert "3 cycle(s)" in capsys.readouterr().out


def test_bad_urls_and_a_server_down_are_sentences(url, pg, tmp_path, capsys):
    from station.cli import main
    cfg = _config(tmp_path)
    assert main(["--config", cfg, "history", "migrate", "--to", "postgresql://u:pw@127.0.0.1:notaport/db"]) == 2
    err = capsys.readouterr().err
    assert "port" in err and "Traceback" not in err and "pw@" not in err
    bad = url.replace(pg_server.PASSWORD, "wrong-password")
    with pytest.raises(StorageError, match="refused the login") as e:
        History(bad, read_only=True)
    assert "wrong-password" not in str(e.value)
    with pytest.raises(ConfigError, match="history.url"):
        from station.config import load_config
        load_config(_config(tmp_path, "mysql://x@h/db", "bad"))
    down = f"postgresql://station:x@127.0.0.1:{pg_server.free_port()}/shop"
    with pytest.raises(StorageError, match="cannot reach the history server"):
        History(down, read_only=True)
    assert main(["--config", _config(tmp_path, down, "desk"), "history"]) == 2
    err = capsys.readouterr().err
    assert "cannot reach the history server" in err and "Traceback" not in err


def test_outbox_keeps_cycles_while_the_server_is_down_and_sends_each_once(url, pg, tmp_path):
    outbox = tmp_path / "outbox.sqlite"
    h = History(url, station="bay-1", outbox=outbox, timeout_s=2)
    _fill(h, 3)
    assert h.queued() == 0 and _count(url) == 3
    pg.stop()
    try:
        for r in [make_result(i, cycle=i) for i in (4, 5, 6)]:
            assert h.store(r) == 0 and h.last_queued  # kept, no exception: the measurement is not lost
        assert h.queued() == 3
        with pytest.raises(StorageError, match="waits in the outbox already"):
            h.store(make_result(5, cycle=5))
    finally:
        pg.start()
    assert h.store(make_result(7, cycle=7)) > 0 and not h.last_queued
    assert h.queued() == 0
    assert _count(url) == 7
    with psycopg.connect(url) as c:
        ids = [r[0][-4:] for r in c.execute("SELECT cycle_id FROM cycles ORDER BY id")]
    assert ids == ["0001", "0002", "0003", "0004", "0005", "0006", "0007"]  # in order, once each
    # the server committed a cycle but the station never heard (the connection died): sent again, no duplicate
    row, angles = h._row(make_result(8, cycle=8))
    h._backend.insert(row, angles)
    h._outbox.put("bay-1", row[0], row, angles)
    assert h.flush() == {("bay-1", row[0]): None} and h.queued() == 0
    assert _count(url) == 8 and _count(url, "SELECT COUNT(*) FROM angles") == 8 * len(ANGLE_NAMES)
    h.close()
    # a new process finds what an old one left in the outbox
    pg.stop()
    try:
        with History(url, station="bay-1", outbox=outbox, timeout_s=2) as h2:
            h2.store(make_result(9, cycle=9))
            assert h2.queued() == 1
    finally:
        pg.start()
    with History(url, station="bay-1", outbox=outbox) as h3:
        assert h3.flush() and h3.queued() == 0
    assert _count(url) == 9


def test_serve_stores_into_the_shared_history_and_resends_its_outbox(url, pg, tmp_path, station_data_dir):
    """`station serve --dry-run --store` with history.url: every acknowledged cycle is in the
    shared history, tagged with the station; with the server stopped the PLC still gets its
    results, and the cycles reach the server by serve's own resend once it is back."""
    import subprocess
    import sys
    import time
    cfg = _config(tmp_path, url, "bay-7")
    text = open(cfg).read().replace("connect_timeout_s: 2", "connect_timeout_s: 2\n  retry_s: 0.5")
    open(cfg, "w").write(text)
    port = pg_server.free_port()
    serve = subprocess.Popen([sys.executable, "-m", "station.cli", "--config", cfg, "serve", "--dry-run", "--store",
                              "--fail-every", "0", "--port", str(port)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)

    def plc(first: int, n: int) -> str:
        out = subprocess.run([sys.executable, "-m", "station.plc.master", "--port", str(port), "--cycles", str(n),
                              "--first-job", str(first), "--fail-every", "0", "--dry-run-check", "--quiet"],
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stdout + out.stderr
        return out.stdout

    try:
        assert "station serving" in serve.stdout.readline()
        plc(1, 3)
        assert _count(url, "SELECT COUNT(*) FROM cycles WHERE station = 'bay-7'") == 3
        pg.stop()
        try:
            assert "2 cycles, 0 with problems" in plc(4, 2)  # the PLC's results, with the server away
            con = sqlite3.connect(station_data_dir / "history-outbox.sqlite")
            assert con.execute("SELECT COUNT(*) FROM outbox").fetchone()[0] == 2
            con.close()
        finally:
            pg.start()
        deadline = time.monotonic() + 20
        while _count(url) < 5 and time.monotonic() < deadline:
            time.sleep(0.2)
        with psycopg.connect(url) as c:
            jobs = [r[0] for r in c.execute("SELECT job_id FROM cycles WHERE station = 'bay-7' ORDER BY id")]
        assert jobs == [f"JOB-{i:06d}" for i in range(1, 6)]
    finally:
        serve.terminate()
        out, err = serve.communicate(timeout=30)
    assert serve.returncode == 0 and "Traceback" not in err, err


@pytest.mark.slow
def test_a_real_measurement_cycle_lands_in_the_shared_history(pg, tmp_path):
    """Not a synthetic result: the simulated station measures one car and its cycle (angles,
    job, station tag) is in PostgreSQL, the outbox empty afterwards."""
    from station.cycle import Station
    from tests.station_fixtures import small_station_config, truth_calibration

    if not pg.running():
        pg.start()
    url = pg.create_db(f"shop{next(_DBS)}")
    config = small_station_config(tmp_path, capture__frames_averaged=1, history__url=url)
    truth_calibration(config)
    with Station(config, seed=3, progress=lambda msg: None, workers=0) as station:
        result = station.measure(job_id="JOB-REAL", record=False)
    assert result.valid, result.failure
    with psycopg.connect(url) as c:
        row = c.execute("SELECT station, job_id, valid FROM cycles WHERE cycle_id = %s", (result.cycle_id,)).fetchone()
        angle = c.execute("SELECT value_deg FROM angles a JOIN cycles c ON a.cycle = c.id "
                          "WHERE c.cycle_id = %s AND a.name = 'FL.toe'", (result.cycle_id,)).fetchone()
    assert row == (config.name, "JOB-REAL", True)
    assert angle[0] == pytest.approx(result.wheels["FL"].toe_deg, abs=1e-9)
    with History(url, station=config.name) as h:
        assert h.get(result.cycle_id)["job_id"] == "JOB-REAL"
