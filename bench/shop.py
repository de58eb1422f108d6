"""The shop benchmark: a shared PostgreSQL history for two stations, a migration, OPC UA handshakes.

    python bench/shop.py                       # all three, the figures of docs/shop.md
    python bench/shop.py --only stations       # or: migrate, opcua
    python bench/shop.py --cycles 100 --migrate-cycles 1000 --opcua-cycles 1000
    python bench/shop.py --only stations --measure --cycles 30   # cycles the simulated station measures

1. **Two stations, one history**: a PostgreSQL server (Debian's binaries, a temporary data folder,
   127.0.0.1, tests/pg_server.py) and two `station serve --dry-run --store` processes, each with
   its own configuration (name bay-1 / bay-2, history.url, history.retry_s 1) and data folder;
   a PLC simulator (`python -m station.plc.master --dry-run-check`) drives each through
   ``--cycles`` cycles at once. Once the server holds a third of the cycles it is stopped
   (``pg_ctl stop -m fast``) for ``--outage-s`` seconds and started again. Then: rows per
   station, duplicates, lost cycles (a job id of the PLC's that is not in the history), cycles
   that waited in an outbox, the outboxes left, the PLC simulators' verdicts.
2. **Migration**: a SQLite history of ``--migrate-cycles`` results (tests/result_builder.py) copied
   with `station history migrate --to URL`, twice (the second must add nothing).
3. **OPC UA**: ``--opcua-cycles`` handshakes (Measure, wait for done/fault, read the result,
   Acknowledge) against `station serve --dry-run --opcua` with asyncua's client, every value
   checked against the dry run's synthetic result of its job; every 10th fails on purpose (401).

The dry run makes synthetic results (station/plc/runner.py): the simulated station renders each
camera image by ray casting (seconds per image here), too slow for hundreds of cycles. With
``--measure`` the two stations are `station serve` on the simulated station instead (half
resolution, one frame per capture, its true cameras as the calibration, no recordings): every
cycle is a real measurement, and ``--cycles`` is sized to the machine.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import yaml  # noqa: E402

from pg_server import TempPostgres, free_port  # noqa: E402

PY = sys.executable


def _env(data_dir: Path | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("STATION_CONFIG", None)
    if data_dir is not None:
        env["STATION_DATA_DIR"] = str(data_dir)
    return env


def _config(folder: Path, name: str, url: str | None, measure: bool = False) -> Path:
    from station.config import DEFAULT_CONFIG
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    if measure:  # the small simulated station: half resolution, single frames, no recordings
        w, h = data["camera_defaults"]["resolution"]
        data["camera_defaults"]["resolution"] = [w // 2, h // 2]
        for cam in data["cameras"].values():
            cam["nominal"]["focal_px"] = cam["nominal"]["focal_px"] / 2
        data["capture"]["frames_averaged"] = 1
        data.setdefault("recording", {})["enabled"] = False
    data["vehicle_specs"] = str(DEFAULT_CONFIG.parent / data.get("vehicle_specs", "vehicles.yaml"))
    data["calibration"]["box"] = str(DEFAULT_CONFIG.parent / data["calibration"].get("box", "box.yaml"))
    data["name"] = name
    if url:
        data["history"] = {"url": url, "retry_s": 1.0, "connect_timeout_s": 2}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _truth_calibration(config: Path, data: Path) -> None:
    """The simulated station's true cameras saved as its calibration in ``data``."""
    from station.config import load_config
    from station_fixtures import truth_calibration
    os.environ["STATION_DATA_DIR"] = str(data)
    try:
        truth_calibration(load_config(config))
    finally:
        os.environ.pop("STATION_DATA_DIR", None)


def _serve(config: Path, data: Path, *extra: str, dry_run: bool = True) -> tuple[subprocess.Popen, str]:
    log = open(data.parent / f"{config.stem}-serve.log", "w")
    proc = subprocess.Popen([PY, "-m", "station.cli", "--config", str(config), "serve",
                             *(["--dry-run"] if dry_run else []), *extra],
                            stdout=subprocess.PIPE, stderr=log, text=True, env=_env(data))
    line = proc.stdout.readline()
    if "station serving" not in line:
        proc.kill()
        raise SystemExit(f"station serve did not start: {line}{Path(log.name).read_text()[-2000:]}")
    return proc, log.name


def _stop(proc: subprocess.Popen) -> str:
    proc.terminate()
    try:
        out, _ = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out


def _table(head: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


# --- 1. two stations, one history ------------------------------------------------------------------
def stations(pg: TempPostgres, work: Path, cycles: int, outage_s: float, delay_s: float,
             measure: bool = False) -> None:
    import psycopg
    url = pg.create_db("shop")
    procs, masters, logs = [], [], {}
    for k in (1, 2):
        name, data = f"bay-{k}", work / f"bay-{k}-data"
        data.mkdir()
        port = free_port()
        config = _config(work, name, url, measure)
        if measure:
            _truth_calibration(config, data)
            proc, log = _serve(config, data, "--port", str(port), dry_run=False)
            check = ["--timeout", "10"]
        else:
            proc, log = _serve(config, data, "--store", "--fail-every", "0", "--port", str(port),
                               "--delay-s", str(delay_s))
            check = ["--fail-every", "0", "--dry-run-check"]
        procs.append(proc)
        logs[name] = log
        masters.append((name, subprocess.Popen(
            [PY, "-m", "station.plc.master", "--port", str(port), "--cycles", str(cycles), *check,
             "--quiet", "--job-prefix", f"BAY{k}-"], stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, env=_env())))
    t0 = time.perf_counter()
    outage = {}

    def count() -> int:
        try:
            with psycopg.connect(url, connect_timeout=2) as c:
                return c.execute("SELECT COUNT(*) FROM cycles").fetchone()[0]
        except psycopg.Error:  # the server away, or no cycle stored yet (the schema comes with the first)
            return -1

    def cut():  # stop the server once a third of the cycles are in, start it again after outage_s
        while count() < 2 * cycles // 3:  # a third of both stations' cycles
            time.sleep(0.05)
        outage["rows_before"] = count()
        outage["at_s"] = time.perf_counter() - t0
        pg.stop()
        time.sleep(outage_s)
        pg.start()
        outage["back_s"] = time.perf_counter() - t0
        from station.records.history import normalize_time
        import datetime as dt
        outage["back_utc"] = normalize_time(dt.datetime.now(dt.timezone.utc))

    cutter = threading.Thread(target=cut)
    cutter.start()
    verdicts = {name: m.communicate(timeout=3600)[0].strip().splitlines()[-1] for name, m in masters}
    cutter.join()
    wall = time.perf_counter() - t0
    # the outboxes drain by the stations' own resend (history.retry_s) once the server is back
    deadline = time.monotonic() + 60
    left = {}
    while time.monotonic() < deadline:
        left = {}
        for k in (1, 2):
            box = work / f"bay-{k}-data" / "history-outbox.sqlite"
            import sqlite3
            con = sqlite3.connect(box)
            left[f"bay-{k}"] = con.execute("SELECT COUNT(*) FROM outbox").fetchone()[0]
            con.close()
        if not any(left.values()):
            break
        time.sleep(0.5)
    for p in procs:
        _stop(p)
    with psycopg.connect(url) as c:
        rows = {}
        for name, k in (("bay-1", 1), ("bay-2", 2)):
            n, distinct, jobs = c.execute(
                "SELECT COUNT(*), COUNT(DISTINCT cycle_id), COUNT(DISTINCT job_id) FROM cycles WHERE station = %s",
                (name,)).fetchone()
            stored = {r[0] for r in c.execute("SELECT job_id FROM cycles WHERE station = %s", (name,))}
            lost = [j for j in (f"BAY{k}-{i:06d}" for i in range(1, cycles + 1)) if j not in stored]
            angles = c.execute("SELECT COUNT(*) FROM angles a JOIN cycles c ON a.cycle = c.id WHERE c.station = %s",
                               (name,)).fetchone()[0]
            waited = Path(logs[name]).read_text().count("kept in the outbox")
            after = c.execute("SELECT COUNT(*) FROM cycles WHERE station = %s AND time_utc > %s",
                              (name, outage.get("back_utc", "9"))).fetchone()[0]
            rows[name] = [name, cycles, n, n - distinct, len(lost), angles, waited, after, left.get(name, "?"),
                          verdicts[name]]
        total = c.execute("SELECT COUNT(*) FROM cycles").fetchone()[0]
    kind = "measured by the simulated station" if measure else "dry-run results"
    print(f"\n## Two stations, one PostgreSQL history ({cycles} cycles each, {kind}, server stopped "
          f"{outage.get('at_s', 0):.1f}-{outage.get('back_s', 0):.1f} s into the run, "
          f"{outage.get('rows_before', '?')} rows in it then; wall {wall:.1f} s)\n")
    print(_table(["station", "PLC cycles", "rows", "duplicates", "lost", "angle rows", "waited in outbox",
                  "measured after the restart", "outbox left", "PLC simulator"], list(rows.values())))
    print(f"\nrows in the shared history: {total} (expected {2 * cycles})")


# --- 2. migration ----------------------------------------------------------------------------------
def migrate(pg: TempPostgres, work: Path, n: int) -> None:
    import psycopg
    from result_builder import make_result
    from station.records.history import History
    url = pg.create_db("migrated")
    data = work / "old-station"
    data.mkdir()
    t = time.perf_counter()
    with History(data / "history.sqlite") as h:
        for i in range(1, n + 1):
            h.store(make_result(i, cycle=i, job_id=f"JOB-{i // 2:05d}", valid=i % 50 != 0,
                                time_utc=f"2026-{1 + i // 400:02d}-{1 + (i // 20) % 28:02d}T"
                                         f"{8 + (i % 10):02d}:{i % 60:02d}:{(i * 7) % 60:02d}.000Z"))
    made = time.perf_counter() - t
    cfg = _config(work, "old-station", None)
    rows = []
    for run in (1, 2):
        t = time.perf_counter()
        out = subprocess.run([PY, "-m", "station.cli", "--config", str(cfg), "history", "migrate", "--to", url],
                             capture_output=True, text=True, env=_env(data))
        wall = time.perf_counter() - t
        if out.returncode:
            raise SystemExit(out.stderr)
        with psycopg.connect(url) as c:
            cyc = c.execute("SELECT COUNT(*), COUNT(DISTINCT cycle_id) FROM cycles").fetchone()
            ang = c.execute("SELECT COUNT(*) FROM angles").fetchone()[0]
        line = out.stdout.strip().splitlines()[-1]
        inside = line.rsplit(";", 1)[-1].strip()
        rows.append([run, n, line.split("read, ")[1].split(",")[0], cyc[0], cyc[0] - cyc[1], ang, inside,
                     f"{wall:.2f}"])
    print(f"\n## Migration of a {n}-cycle SQLite history into PostgreSQL (made in {made:.1f} s)\n")
    print(_table(["run", "cycles in SQLite", "inserted", "rows on server", "duplicates", "angle rows",
                  "copy time (in the command)", "command wall s"], rows))


# --- 3. OPC UA handshakes --------------------------------------------------------------------------
def opcua(work: Path, n: int) -> None:
    import logging
    from asyncua import Client, ua

    logging.getLogger("asyncua").setLevel(logging.ERROR)  # its client warns of the session timeout it was given

    from station.plc import register_map as rm
    from station.plc.runner import CycleRequest, synthetic_result

    data = work / "opcua-data"
    data.mkdir()
    port = free_port()
    proc, log = _serve(_config(work, "opcua-bay", None), data, "--port", str(free_port()), "--opcua",
                       "--opcua-port", str(port), "--log-level", "error")
    f32 = lambda x: struct.unpack(">f", struct.pack(">f", x))[0]  # noqa: E731
    names = ["state", "result_valid", "fault_code", "result_job_id", "cycle_counter"] + \
        [f"{a.replace('.', '_')}_f32" for a in rm.ANGLES]

    async def run():
        client = Client(f"opc.tcp://127.0.0.1:{port}/station", timeout=10)
        await client.connect()
        ns = await client.get_namespace_index("urn:wheel-alignment-station:plc")
        obj = client.get_node(ua.NodeId("Station", ns))
        nodes = [client.get_node(ua.NodeId(x, ns)) for x in names]
        state = nodes[0]
        measure, ack = ua.QualifiedName("Measure", ns), ua.QualifiedName("Acknowledge", ns)
        times, ok, wrong, lost, faults = [], 0, 0, 0, 0
        counter0 = await nodes[4].read_value()
        try:
            for i in range(1, n + 1):
                job = f"OPC-{i:06d}"
                t = time.perf_counter()
                if await obj.call_method(measure, job, "") != [0, "accepted"]:
                    lost += 1
                    continue
                deadline = time.monotonic() + 10
                while (s := await state.read_value()) not in (2, 3) and time.monotonic() < deadline:
                    pass
                v = dict(zip(names, await client.read_values(nodes)))
                good = await obj.call_method(ack) == [0, "accepted"]
                times.append(time.perf_counter() - t)
                if s not in (2, 3):
                    lost += 1
                    continue
                if i % 10 == 0:
                    right = s == 3 and v["fault_code"] == 401 and v["result_valid"] == 0
                    faults += right
                else:
                    exp = synthetic_result(CycleRequest("measure", job, None, i))
                    right = s == 2 and v["result_valid"] == 1 and v["result_job_id"] == job and all(
                        v[f"{a.replace('.', '_')}_f32"] == f32(exp.angle(a)) for a in rm.ANGLES)
                if right and good:
                    ok += 1
                else:
                    wrong += 1
            counter = await nodes[4].read_value()
        finally:
            await client.disconnect()
        return times, ok, wrong, lost, faults, (counter - counter0) & 0xFFFF

    t0 = time.perf_counter()
    times, ok, wrong, lost, faults, counted = asyncio.run(run())
    wall = time.perf_counter() - t0
    out = _stop(proc)
    ms = sorted(x * 1000 for x in times)
    p99 = ms[min(len(ms) - 1, math.ceil(0.99 * len(ms)) - 1)]
    print(f"\n## OPC UA handshake, {n} cycles (asyncua client; Measure, poll state, read 16 values, Acknowledge)\n")
    print(_table(["cycles", "correct", "of them faults on purpose (401)", "wrong", "lost", "cycle_counter moved",
                  "handshake median ms", "p99 ms", "max ms", "wall s"],
                 [[n, ok, faults, wrong, lost, counted, f"{statistics.median(ms):.2f}", f"{p99:.2f}",
                   f"{ms[-1]:.2f}", f"{wall:.1f}"]]))
    print(f"\nstation serve: {out.strip().splitlines()[-1] if out.strip() else '(nothing printed)'}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", choices=("stations", "migrate", "opcua"))
    ap.add_argument("--cycles", type=int, default=100, help="cycles per station (two stations)")
    ap.add_argument("--outage-s", type=float, default=1.0, help="how long the server is down mid-run")
    ap.add_argument("--delay-s", type=float, default=0.05,
                    help="each dry-run cycle's stand-in measurement time, so cycles run before, during and after "
                         "the outage")
    ap.add_argument("--measure", action="store_true",
                    help="the stations measure every cycle on the simulated station (slow: size --cycles)")
    ap.add_argument("--migrate-cycles", type=int, default=1000)
    ap.add_argument("--opcua-cycles", type=int, default=1000)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="station-shop-bench-"))
    pg = None
    try:
        if args.only in (None, "stations", "migrate"):
            pg = TempPostgres()
            pg.start()
        if args.only in (None, "stations"):
            stations(pg, work, args.cycles, args.outage_s, args.delay_s, args.measure)
        if args.only in (None, "migrate"):
            migrate(pg, work, args.migrate_cycles)
        if args.only in (None, "opcua"):
            opcua(work, args.opcua_cycles)
    finally:
        if pg is not None:
            pg.destroy()
        import shutil
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
