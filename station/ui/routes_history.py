"""The History page's requests: the stored jobs and cycles (PLC-triggered ones too: they share
the history), each job's before/after report (station/records/report.py) and its PDF."""

from __future__ import annotations

import anyio
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse
from starlette.routing import Route

from station.errors import ConfigError
from station.records.printable import visible
from station.ui.refused import Refused

# the report is our own self-contained page: inline CSS and SVG, nothing else (as its own meta CSP)
REPORT_CSP = "default-src 'none'; style-src 'unsafe-inline'; img-src data:; frame-ancestors 'none'"


def _history(screen):
    from station.records.history import History

    return History(screen.config.data_path("history.sqlite"), read_only=True)


def _row(r: dict) -> dict:
    failure = (r["result"] or {}).get("failure") or {}
    return {"cycle_id": r["cycle_id"], "time_utc": r["time_utc"], "job_id": visible(r["job_id"] or ""),
            "vehicle": r["vehicle_spec"], "valid": r["valid"], "passed": r["passed"], "angles": r["angles"],
            "failure": failure.get("message"), "steering": bool((r["result"] or {}).get("steering")),
            "runout_compensated": bool((r["result"] or {}).get("runout_compensated"))}


def _read(screen, job: str | None, limit: int) -> dict:
    with _history(screen) as h:
        jobs = [{"job_id": j, "shown": visible(j), "cycles": n, "last_utc": t} for j, n, t in h.job_ids()]
        rows = [_row(r) for r in h.query(job=job, limit=limit)]
    return {"jobs": jobs, "cycles": rows}


async def history(request: Request):
    screen = request.app.state.screen
    job = request.query_params.get("job") or None
    try:
        limit = min(max(int(request.query_params.get("limit", "50")), 1), 1000)
    except ValueError:
        limit = 50
    from station.ui.views import finite
    return JSONResponse(finite(await anyio.to_thread.run_sync(_read, screen, job, limit)))


def _report(screen, job: str):
    """(html, where it is written) of ``job``'s report; Refused (404) for a job with no cycles."""
    from station.records.report import build_report, safe_filename, write_report
    from station.records.vehicle_specs import load_vehicle_specs

    with _history(screen) as h:
        results = h.jobs(job)
    if not results:
        raise Refused(404, f"job {visible(job)!r}: no cycles in the history", "pick a job from the list")
    key = next((r.vehicle_spec for r in reversed(results) if r.vehicle_spec), None)
    spec = None
    if key:
        try:
            spec = load_vehicle_specs(screen.config.vehicle_specs_path).get(key)
        except ConfigError:
            spec = None  # the report then uses the pass/fail stored with the cycles, as `station report`
    html = build_report(job, results, spec)
    path = write_report(html, screen.config.data_path("reports", safe_filename(job) + ".html"))
    return html, path


def _job(request: Request) -> str:
    job = request.query_params.get("job")
    if not job:
        raise Refused(400, "which job? the report needs ?job=JOB", "pick a job from the list")
    return job


async def report(request: Request):
    html, _ = await anyio.to_thread.run_sync(_report, request.app.state.screen, _job(request))
    return HTMLResponse(html, headers={"content-security-policy": REPORT_CSP})


async def report_pdf(request: Request):
    from station.records.report import render_with_chromium

    job = _job(request)
    _, path = await anyio.to_thread.run_sync(_report, request.app.state.screen, job)
    pdf = await anyio.to_thread.run_sync(lambda: render_with_chromium(path, path.with_suffix(".pdf"), kind="pdf"))
    return FileResponse(pdf, media_type="application/pdf", filename=pdf.name)


routes = [
    Route("/api/history", history),
    Route("/history/report", report),
    Route("/history/report.pdf", report_pdf),
]
