"""`station history`: list, filter and export the stored cycles; `station history migrate`:
upgrade the history's schema in place, or copy a SQLite history into a shared PostgreSQL one."""

from __future__ import annotations

import argparse
import datetime as dt
import sys

from station.config import load_config
from station.records.history import export_csv, is_url, open_history
from station.records.printable import visible


def _when(text: str) -> str:
    try:
        dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a date or time; use YYYY-MM-DD or "
                                         "YYYY-MM-DDTHH:MM[:SS][Z]") from None
    return text


def add_arguments(parser):
    parser.add_argument("action", nargs="?", choices=("migrate",),
                        help="migrate: upgrade the configured history's schema in place; with --to URL, copy "
                             "the SQLite history into that PostgreSQL server (idempotent: run it again to resume)")
    parser.add_argument("--to", metavar="URL", help="migrate: the PostgreSQL history to copy into "
                                                    "(postgresql://user:password@host:port/database)")
    parser.add_argument("--from", dest="source", metavar="PATH",
                        help="migrate --to: the SQLite history to copy (default: the data folder's history.sqlite)")
    parser.add_argument("--station", metavar="NAME",
                        help="migrate --to: tag every copied cycle with this station (default: each cycle's own, "
                             "else the configured name)")
    parser.add_argument("--job", metavar="J", help="only this job id / VIN")
    parser.add_argument("--since", metavar="DATE", type=_when, help="from this date or time (UTC)")
    parser.add_argument("--until", metavar="DATE", type=_when, help="up to this date (whole day) or time (UTC)")
    parser.add_argument("--vehicle", metavar="V", help="only this vehicle spec (e.g. dodge-caravan-2007)")
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--passed", dest="passed", action="store_const", const=True, help="only cycles that passed")
    g.add_argument("--failed", dest="passed", action="store_const", const=False, help="only cycles that failed")
    parser.add_argument("--limit", type=int, metavar="N", help="only the newest N cycles")
    parser.add_argument("--csv", metavar="PATH", help="write the rows as CSV ('-' for standard output)")
    parser.add_argument("--jobs", action="store_true", help="list the jobs instead of the cycles")


def _fmt(v) -> str:
    return "      -" if v is None else f"{v:+7.2f}"


def _migrate(args, config) -> int:
    from station.errors import ConfigError
    from station.records.history import History
    from station.records.history_postgres import redacted

    if args.to is None:
        with open_history(config) as history:  # a writer applies what the schema lacks on opening
            applied = history.migrate()
            print(f"history {history.where}: schema version {history.version()}"
                  + (f" (applied {', '.join(map(str, applied))})" if applied else ", up to date"))
        return 0
    if not is_url(args.to):
        raise ConfigError(f"--to {args.to!r}: expected postgresql://user:password@host:port/database")
    from station.config import SCHEMA
    try:
        SCHEMA["history"].check({"url": args.to}, "history")  # the URL's form, checked as the config's
    except Exception as e:  # noqa: BLE001 - _Bad: one sentence
        raise ConfigError(f"--to {redacted(args.to)}: {e}") from None
    from station.records.history_copy import copy_history

    source = args.source or config.data_path("history.sqlite")
    from pathlib import Path
    if not Path(source).exists():
        raise ConfigError(f"--from {source}: no such history file")
    with History(source, read_only=True) as h:  # refuses a newer or corrupt file before anything is sent
        version = h.version()
    report = copy_history(source, args.to, station=args.station, default_station=config.name,
                          timeout_s=config.history.connect_timeout_s)
    print(f"copied {source} (schema {version}) into {redacted(args.to)}: {report.cycles} cycle(s) read, "
          f"{report.inserted} new, {report.already} already there; the server holds {report.on_server} cycle(s) "
          f"of the copied station(s); {report.seconds:.2f} s")
    return 0


def run(args) -> int:
    config = load_config(args.config)
    if args.action == "migrate":
        return _migrate(args, config)
    if args.to or args.source or args.station:
        from station.errors import ConfigError
        raise ConfigError("--to, --from and --station belong to `station history migrate`")
    with open_history(config, read_only=True) as history:
        if history.shared:
            from station.records.history import OUTBOX_FILE
            from station.records.outbox import Outbox
            outbox_path = config.data_path(OUTBOX_FILE)
            if outbox_path.exists():
                outbox = Outbox(outbox_path)
                waiting = outbox.count()
                outbox.close()
                if waiting:
                    print(f"{waiting} cycle(s) of this station wait in its outbox for the history server "
                          f"({outbox_path}); `station serve` and the next cycle send them", file=sys.stderr)
        if args.jobs:
            print(f"{'job':<24} {'cycles':>6}  last (UTC)")
            for job, n, last in history.job_ids():
                print(f"{visible(job)[:24]:<24} {n:>6}  {visible(str(last))}")
            return 0
        rows = history.query(job=args.job, since=args.since, until=args.until, vehicle=args.vehicle,
                             passed=args.passed, limit=args.limit)
    if args.csv:
        if args.csv == "-":
            export_csv(rows, sys.stdout)
        else:
            n = export_csv(rows, args.csv)
            print(f"{n} cycle(s) written to {args.csv}")
        return 0
    if not rows:
        print("no cycles match")
        return 0
    head = ["time (UTC)", "cycle", "job", "vehicle", "result",
            "FL toe", "FR toe", "RL toe", "RR toe", "FL cmb", "FR cmb", "RL cmb", "RR cmb", "thrust"]
    print(f"{head[0]:<20} {head[1]:<24} {head[2]:<18} {head[3]:<20} {head[4]:<6} " + " ".join(f"{h:>7}" for h in head[5:]))
    for r in rows:
        a = r["angles"]
        verdict = "FAIL*" if not r["valid"] else {True: "pass", False: "FAIL", None: "-"}[r["passed"]]
        vals = [a["FL.toe"], a["FR.toe"], a["RL.toe"], a["RR.toe"],
                a["FL.camber"], a["FR.camber"], a["RL.camber"], a["RR.camber"], a["thrust"]]
        time_utc, cycle, job, vehicle = (visible(str(r[k] or "-"))
                                         for k in ("time_utc", "cycle_id", "job_id", "vehicle_spec"))
        print(f"{time_utc[:19]:<20} {cycle[:24]:<24} {job[:18]:<18} {vehicle[:20]:<20} "
              f"{verdict:<6} " + " ".join(_fmt(v) for v in vals))
    if any(not r["valid"] for r in rows):
        print("FAIL*: the cycle itself failed (no angles); see `station review CYCLE`")
    print(f"{len(rows)} cycle(s); angles in degrees")
    return 0
