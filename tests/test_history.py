"""SQLite history: store/query/filter/CSV, and the faults (corrupt, locked, read-only, killed)."""

import csv
import io
import json
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from result_builder import make_result
from station.errors import StorageError
from station.records.history import History, export_csv
from station.result import ANGLE_NAMES

TESTS = Path(__file__).resolve().parent


@pytest.fixture
def hist(tmp_path):
    h = History(tmp_path / "history.sqlite")
    yield h
    h.close()


def _fill(h):
    h.store(make_result(1, cycle=1, job_id="JOB-A", time_utc="2026-11-20T08:00:00Z", verdicts={"overall": False}))
    h.store(make_result(2, cycle=2, job_id="JOB-A", time_utc="2026-11-20T08:05:00Z", verdicts={"overall": True}))
    h.store(make_result(3, cycle=3, job_id="JOB-B", vehicle_spec="toyota-echo-2003",
                        time_utc="2026-11-21T23:59:59.5Z", verdicts={"overall": True}))
    h.store(make_result(4, cycle=4, job_id=None, vehicle_spec=None, time_utc="2026-11-22T00:00:00Z"))
    h.store(make_result(5, cycle=5, job_id="JOB-A", valid=False, time_utc="2026-11-20T07:00:00+01:00"))


def test_store_and_read_back_every_field(hist):
    r = make_result(7, cycle=7, recording="/var/recordings/x.rrd", verdicts={"overall": True, "FL.toe": True})
    rowid = hist.store(r)
    rows = hist.query()
    assert len(rows) == 1 and rows[0]["id"] == rowid
    row = rows[0]
    assert row["result"] == json.loads(json.dumps(r.to_json()))
    assert row["passed"] is True and row["valid"] is True
    assert row["calibration_id"] == r.calibration_id and row["software_version"] == "0.1.0"
    assert row["recording"] == "/var/recordings/x.rrd"
    assert row["angles"]["FL.toe"] == pytest.approx(r.wheels["FL"].toe_deg)
    assert row["angles"]["thrust"] == pytest.approx(r.thrust_deg)
    assert row["angles"]["rear.total_toe"] == pytest.approx(r.axles["rear"].total_toe_deg)
    # the raw tables: 11 angle rows, pass stored per angle where present
    con = sqlite3.connect(hist.path)
    assert con.execute("SELECT COUNT(*) FROM angles").fetchone()[0] == len(ANGLE_NAMES)
    assert con.execute("SELECT passed FROM angles WHERE name='FL.toe'").fetchone()[0] == 1
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_filters_and_time_order(hist):
    _fill(hist)
    assert [r["cycle_id"][-4:] for r in hist.query()] == ["0005", "0001", "0002", "0003", "0004"]
    assert [r["cycle_id"][-1] for r in hist.query(job="JOB-A")] == ["5", "1", "2"]
    assert [r["cycle_id"][-1] for r in hist.query(since="2026-11-21")] == ["3", "4"]
    # a bare date as --until includes that whole day (23:59:59.5 is in)
    assert [r["cycle_id"][-1] for r in hist.query(until="2026-11-21", since="2026-11-21")] == ["3"]
    assert [r["cycle_id"][-1] for r in hist.query(vehicle="toyota-echo-2003")] == ["3"]
    assert [r["cycle_id"][-1] for r in hist.query(passed=False)] == ["1"]
    assert [r["cycle_id"][-1] for r in hist.query(passed=True, job="JOB-A")] == ["2"]
    assert [r["cycle_id"][-1] for r in hist.query(limit=2)] == ["3", "4"]
    # the +01:00 time was normalised to UTC (06:00Z), so it sorts first
    assert hist.query(job="JOB-A")[0]["time_utc"] == "2026-11-20T06:00:00.000Z"
    assert [r["cycle_id"][-1] for r in hist.jobs("JOB-A") and hist.query(job="JOB-A")] == ["5", "1", "2"]
    assert [r.cycle_id for r in hist.jobs("JOB-A")][-1].endswith("0002")
    assert hist.jobs("nobody") == []
    invalid = hist.query(job="JOB-A")[0]
    assert invalid["valid"] is False and all(v is None for v in invalid["angles"].values())


def test_duplicate_cycle_is_a_clear_error_and_stores_nothing(hist):
    hist.store(make_result(1, cycle=1))
    with pytest.raises(StorageError, match="already in the history"):
        hist.store(make_result(2, cycle=1))
    assert len(hist.query()) == 1
    assert sqlite3.connect(hist.path).execute("SELECT COUNT(*) FROM angles").fetchone()[0] == len(ANGLE_NAMES)


def test_csv_export_and_formula_injection(hist, tmp_path):
    hist.store(make_result(1, cycle=1, job_id='=HYPERLINK("http://x")'))
    hist.store(make_result(2, cycle=2, job_id='VIN,with "quotes"\nand newline'))
    rows = hist.query()
    out = tmp_path / "h.csv"
    assert export_csv(rows, out) == 2
    parsed = list(csv.DictReader(out.open()))
    assert parsed[0]["job_id"] == "'=HYPERLINK(\"http://x\")"
    assert parsed[1]["job_id"] == 'VIN,with "quotes"\\nand newline'  # control characters escaped: one line a cycle
    assert len(out.read_text().splitlines()) == 3
    assert float(parsed[0]["FL.toe"]) == pytest.approx(rows[0]["angles"]["FL.toe"], abs=1e-4)
    assert list(parsed[0]) [:6] == ["cycle_id", "time_utc", "job_id", "vehicle_spec", "valid", "passed"]
    buf = io.StringIO()
    export_csv(rows, buf)
    assert buf.getvalue() == out.read_text()
    with pytest.raises(StorageError, match="cannot write the CSV"):
        export_csv(rows, tmp_path / "no" / "such" / "dir.csv")


def test_corrupt_database_is_a_clear_error(tmp_path):
    p = tmp_path / "history.sqlite"
    p.write_bytes(b"this is not a database" * 200)
    with pytest.raises(StorageError, match="corrupt") as e:
        History(p)
    assert "move the file aside" in e.value.hint
    assert p.read_bytes().startswith(b"this is not")  # untouched


def test_damaged_pages_are_reported_not_crashed(tmp_path):
    p = tmp_path / "history.sqlite"
    with History(p) as h:
        for i in range(40):
            h.store(make_result(i, cycle=i + 1))
    con = sqlite3.connect(p)
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.close()
    data = bytearray(p.read_bytes())
    page = 4096
    data[3 * page:6 * page] = os.urandom(3 * page)  # smash b-tree pages (not the header)
    p.write_bytes(bytes(data))
    with pytest.raises(StorageError) as e:
        with History(p) as h:
            h.query()
            assert h.check() == "ok"
    assert e.value.code == 600


def test_locked_database_is_a_clear_error(tmp_path):
    p = tmp_path / "history.sqlite"
    History(p).close()
    holder = sqlite3.connect(p, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")  # another program holds the write lock
    h = History(p, timeout_s=0.2)
    t0 = time.monotonic()
    with pytest.raises(StorageError, match="locked by another program") as e:
        h.store(make_result(1))
    assert time.monotonic() - t0 < 3
    assert "close the program" in e.value.hint
    holder.execute("ROLLBACK")
    h.store(make_result(1))  # the lock gone, the same result stores
    assert len(h.query()) == 1


def test_read_only_folder(tmp_path):
    if os.geteuid() == 0:
        ro = tmp_path / "file-not-dir"
        ro.write_text("x")
        p = ro / "history.sqlite"  # a folder that cannot exist: the same failure for root
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        p = ro / "history.sqlite"
    with pytest.raises(StorageError, match="cannot open the history"):
        History(p)


KILLER = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {tests!r})
    from result_builder import make_result
    from station.records.history import History
    h = History(sys.argv[1])
    # slow SQLite down inside each transaction so the kill lands mid-write
    h._conn.set_progress_handler(lambda: time.sleep(0.0005) or 0, 50)
    i = int(sys.argv[2])
    print("ready", flush=True)
    while True:
        i += 1
        print("begin", i, flush=True)
        h.store(make_result(i, cycle=i, time_utc=None))
        print("done", i, flush=True)
""")


def test_killed_mid_write_leaves_whole_cycles_only(tmp_path):
    p = tmp_path / "history.sqlite"
    History(p).close()
    script = tmp_path / "writer.py"
    script.write_text(KILLER.format(tests=str(TESTS)))
    start, stored, mid_write = 0, 0, 0
    for delay in (0.35, 0.6, 0.85):
        proc = subprocess.Popen([sys.executable, str(script), str(p), str(start)], stdout=subprocess.PIPE)
        assert proc.stdout.readline().strip() == b"ready"
        time.sleep(delay)
        os.kill(proc.pid, signal.SIGKILL)
        out = proc.communicate()[0].decode().split()
        mid_write += out[-2] == "begin"  # killed inside store()
        with History(p) as h:
            assert h.check() == "ok"
            rows = h.query()
        con = sqlite3.connect(p)
        counts = dict(con.execute("SELECT cycle, COUNT(*) FROM angles GROUP BY cycle").fetchall())
        con.close()
        assert len(rows) > stored  # the writer got somewhere
        assert all(counts.get(r["id"]) == len(ANGLE_NAMES) for r in rows), "a cycle was half-stored"
        assert set(counts) == {r["id"] for r in rows}
        stored, start = len(rows), start + 1000  # fresh cycle ids for the next writer
    assert mid_write >= 1, "no kill landed inside a transaction: the test proved nothing"


# --- the `station history` command ----------------------------------------------------------------
def _cli(args, monkeypatch, tmp_path):
    from station.cli import main
    monkeypatch.setenv("STATION_DATA_DIR", str(tmp_path))
    return main(args)


def test_cli_lists_filters_and_exports(tmp_path, monkeypatch, capsys):
    with History(tmp_path / "history.sqlite") as h:
        _fill(h)
    assert _cli(["history"], monkeypatch, tmp_path) == 0
    out = capsys.readouterr().out
    assert "5 cycle(s)" in out and "FAIL*" in out and "JOB-B" in out
    assert _cli(["history", "--job", "JOB-A", "--passed"], monkeypatch, tmp_path) == 0
    out = capsys.readouterr().out
    assert "1 cycle(s)" in out and "-0002" in out
    assert _cli(["history", "--failed"], monkeypatch, tmp_path) == 0
    assert "-0001" in capsys.readouterr().out
    assert _cli(["history", "--since", "2026-11-23"], monkeypatch, tmp_path) == 0
    assert "no cycles match" in capsys.readouterr().out
    csv_path = tmp_path / "out.csv"
    assert _cli(["history", "--vehicle", "toyota-echo-2003", "--csv", str(csv_path)], monkeypatch, tmp_path) == 0
    rows = list(csv.DictReader(csv_path.open()))
    assert [r["job_id"] for r in rows] == ["JOB-B"]
    assert _cli(["history", "--jobs"], monkeypatch, tmp_path) == 0
    assert "JOB-A" in capsys.readouterr().out


def test_cli_bad_input_and_corrupt_db(tmp_path, monkeypatch, capsys):
    with pytest.raises(SystemExit) as e:
        _cli(["history", "--since", "yesterday"], monkeypatch, tmp_path)
    assert e.value.code == 2 and "not a date" in capsys.readouterr().err
    (tmp_path / "history.sqlite").write_bytes(b"garbage" * 1000)
    assert _cli(["history"], monkeypatch, tmp_path) == 2
    err = capsys.readouterr().err
    assert "error 600" in err and "corrupt" in err and "Traceback" not in err


def test_threads_share_one_history(hist):
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(4) as pool:
        ids = list(pool.map(lambda i: hist.store(make_result(i, cycle=i + 1)), range(40)))
        reads = list(pool.map(lambda _: len(hist.query()), range(8)))
    assert sorted(ids) == list(range(1, 41)) and all(0 <= n <= 40 for n in reads)
    assert len(hist.query()) == 40 and hist.check() == "ok"


def test_numpy_and_nan_values_store_cleanly(hist):
    import numpy as np
    r = make_result(1, cycle=1)
    r.wheels["FL"].toe_deg = np.float32(0.25)
    r.wheels["FL"].toe_std_deg = float("nan")
    r.wheels["FR"].center_station_m = np.array([0.78, 1.35, 0.33])
    r.verdicts = {"overall": np.bool_(True)}
    hist.store(r)
    row = hist.query()[0]
    assert row["angles"]["FL.toe"] == pytest.approx(0.25)
    assert row["result"]["wheels"]["FL"]["toe_std_deg"] is None  # strict JSON: NaN -> null
    assert row["result"]["wheels"]["FR"]["center_station_m"] == pytest.approx([0.78, 1.35, 0.33])
    assert row["passed"] is True


FULL_DISK = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, {tests!r})
    from result_builder import make_result
    from station.errors import StorageError
    from station.records.history import History
    d = sys.argv[1]
    out = {{"stored": 0, "error": None}}
    h = History(d + "/history.sqlite")
    try:
        for i in range(100000):
            r = make_result(i, cycle=i + 1, warnings=["x" * 2000])  # fill the disk faster
            h.store(r)
            out["stored"] += 1
    except StorageError as e:
        out["error"] = str(e)
    h.close()
    with History(d + "/history.sqlite") as h2:
        out["check"] = h2.check()
        out["rows"] = len(h2.query())
    print(json.dumps(out))
""")


def test_full_disk_is_a_clear_error_and_keeps_earlier_cycles(tmp_path):
    import json as _json
    import shutil
    if shutil.which("unshare") is None:
        pytest.skip("unshare is not installed")
    script = tmp_path / "fill.py"
    script.write_text(FULL_DISK.format(tests=str(TESTS)))
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    p = subprocess.run(["unshare", "-m", "sh", "-c",
                        f"mount -t tmpfs -o size=512k tmpfs {mnt} && {sys.executable} {script} {mnt}"],
                       capture_output=True, text=True, timeout=120)
    if p.returncode != 0 and "mount" in p.stderr:
        pytest.skip(f"cannot make a private mount here: {p.stderr.strip()[:200]}")
    assert p.returncode == 0, p.stderr
    out = _json.loads(p.stdout.strip().splitlines()[-1])
    assert out["stored"] > 10 and out["error"] and "full" in out["error"]
    assert out["check"] == "ok" and out["rows"] == out["stored"]  # nothing half-stored, nothing lost


# --- reading a history on a read-only disk ----------------------------------------------------------
WRITER = textwrap.dedent("""
    import os, sys
    sys.path.insert(0, {tests!r})
    from result_builder import make_result
    from station.records.history import History
    h = History(sys.argv[1] + "/history.sqlite")
    for i in range(1, 4):
        h.store(make_result(i, cycle=i, job_id=f"JOB-{{i}}"))
    if sys.argv[2] == "killed":
        os._exit(0)  # no close: the cycles stay in the -wal file (and its -shm index)
    h.close()
""")


def _history_on_read_only_mount(tmp_path, state: str):
    """`station history` on a read-only bind mount of a history left ``state``: (exit status,
    output, the folder's files before, after)."""
    import shutil
    if shutil.which("unshare") is None:
        pytest.skip("unshare is not installed")
    data = tmp_path / "data"
    data.mkdir()
    writer = tmp_path / "writer.py"
    writer.write_text(WRITER.format(tests=str(TESTS)))
    subprocess.run([sys.executable, str(writer), str(data), "closed" if state == "closed" else "killed"], check=True)
    if state == "killed, index lost":
        (data / "history.sqlite-shm").unlink()  # as a copy without the -shm file
    before = sorted(p.name for p in data.iterdir())
    cmd = (f"mount --bind {data} {data} && mount -o remount,bind,ro {data} && "
           f"{sys.executable} -m station.cli history --jobs && {sys.executable} -m station.cli history")
    p = subprocess.run(["unshare", "-m", "sh", "-c", cmd], capture_output=True, text=True, timeout=120,
                       cwd=TESTS.parent, env={**os.environ, "STATION_DATA_DIR": str(data), "HOME": str(tmp_path)})
    if p.returncode != 0 and ("mount" in p.stderr or "unshare" in p.stderr):
        pytest.skip(f"cannot make a private mount here: {p.stderr.strip()[:200]}")
    return p, before, sorted(q.name for q in data.iterdir())


@pytest.mark.parametrize("state", ["closed", "killed", "killed, index lost"])
def test_cli_reads_a_history_on_a_read_only_disk(tmp_path, state):
    p, before, after = _history_on_read_only_mount(tmp_path, state)
    assert p.returncode == 0, p.stderr
    assert "3 cycle(s)" in p.stdout and all(f"JOB-{i}" in p.stdout for i in (1, 2, 3))
    assert after == before  # nothing created, nothing removed


def test_cli_reading_a_missing_history_creates_nothing(tmp_path, monkeypatch, capsys):
    assert _cli(["history"], monkeypatch, tmp_path) == 0
    assert "no cycles match" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []
