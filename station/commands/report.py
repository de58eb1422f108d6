"""`station report JOB`: the printable before/after report of a job."""

from __future__ import annotations

from station.config import load_config
from station.errors import ConfigError, StorageError
from station.records.history import open_history
from station.records.printable import visible
from station.records.report import build_report, render_with_chromium, safe_filename, write_report
from station.records.vehicle_specs import load_vehicle_specs


def add_arguments(parser):
    parser.add_argument("job", metavar="JOB", help="the job id / VIN (as stored with the cycles)")
    parser.add_argument("--out", metavar="PATH", help="the HTML file (default: <data_dir>/reports/<job>.html)")
    parser.add_argument("--pdf", action="store_true", help="also print it to PDF beside the HTML (needs Chromium)")


def run(args) -> int:
    config = load_config(args.config)
    with open_history(config, read_only=True) as history:
        results = history.jobs(args.job)
        if not results:
            known = [visible(j) for j, _, _ in history.job_ids()[:5]]
            raise StorageError(f"job {args.job!r}: no cycles in the history",
                               hint="the newest jobs are: " + ", ".join(known) if known
                               else "no job has been measured yet")
    spec = None
    key = next((r.vehicle_spec for r in reversed(results) if r.vehicle_spec), None)
    if key:
        try:
            spec = load_vehicle_specs(config.vehicle_specs_path).get(key)
        except ConfigError as e:
            print(f"warning: {e}; the report uses the pass/fail stored with the cycles")
        if spec is None:
            print(f"warning: vehicle spec {key!r} is no longer in {config.vehicle_specs_path}; "
                  "the report uses the pass/fail stored with the cycles")
    out = args.out or config.data_path("reports", safe_filename(args.job) + ".html")
    path = write_report(build_report(args.job, results, spec), out)
    print(f"report: {path}")
    if args.pdf:
        pdf = render_with_chromium(path, path.with_suffix(".pdf"), kind="pdf")
        print(f"pdf:    {pdf}")
    return 0
