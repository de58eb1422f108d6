"""The printable before/after report of a job (self-contained HTML: inline CSS and SVG).

"Before" is the first valid cycle of the job in the history, "after" the last (the technician
measures, adjusts, measures again). Each angle is shown against the vehicle's spec with colours;
a top-view drawing (station/records/report_svg.py) shows the four wheels' toe and camber. Everything
that comes from a user (job id, VIN, names, warnings) is HTML-escaped, its control characters
written as escapes (station/records/printable.py). ``render_with_chromium``
prints the HTML to PDF or PNG with a headless Chromium (Debian's ``chromium``).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import tempfile
from html import escape
from pathlib import Path

from station.records.atomic_file import write_text_atomic
from station.records.printable import visible
from station.errors import StorageError
from station.records.report_svg import top_view_svg
from station.records.vehicle_specs import VehicleSpec, angle_value, evaluate
from station.result import ANGLE_NAMES, STEERING_ANGLE_NAMES, Measurement

_LABELS = {"toe": "toe", "camber": "camber", "total_toe": "total toe", "caster": "caster", "sai": "SAI",
           "included_angle": "included angle"}
_CSS = """
@page { size: A4; margin: 14mm; }
body { font-family: "DejaVu Sans", Arial, sans-serif; font-size: 10.5pt; color: #222; margin: 0; }
h1 { font-size: 16pt; margin: 0 0 4pt 0; } h2 { font-size: 12pt; margin: 12pt 0 4pt 0; }
table { border-collapse: collapse; width: 100%; } td, th { border: 1px solid #bbb; padding: 3pt 5pt; }
th { background: #f0f0f0; text-align: left; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
.meta td { border: none; padding: 1pt 8pt 1pt 0; } .meta td:first-child { color: #666; }
.pass { background: #d7f0dd; color: #1b8a3a; } .fail { background: #fbd9d9; color: #c62828; font-weight: bold; }
.none { background: #eee; color: #666; }
.verdict { font-size: 14pt; font-weight: bold; padding: 4pt 8pt; display: inline-block; border-radius: 4pt; }
.drawings { display: flex; gap: 12pt; justify-content: center; page-break-inside: avoid; }
.topview text { font-family: "DejaVu Sans", Arial, sans-serif; font-size: 11px; }
.topview .small { font-size: 9px; fill: #555; } .topview .svg-title { font-size: 13px; font-weight: bold; }
.topview .wheel { font-weight: bold; }
@media screen { body { margin: 14px; } }
.warn { color: #8a5a00; } .foot { color: #777; font-size: 8.5pt; margin-top: 10pt; }
"""


def _runout_section(before: Measurement, after: Measurement, same: bool) -> str:
    """Whether toe and camber are of the spin axes or the rim planes, and each rim's runout
    (of the latest compensated cycle shown)."""
    shown = (("", after),) if same else (("before", before), ("after", after))
    said = "; ".join(f"{which + ': ' if which else ''}"
                     + ("spin axes (runout compensated)" if r.runout_compensated else "rim planes (runout not compensated)")
                     for which, r in shown)
    source = next((r for _, r in reversed(shown) if r.runout_compensated and r.valid), None)
    if source is None:
        return f"<p>Toe and camber are of the {said}.</p>"
    rows = "".join(f"<tr><td>{w}</td>" + "".join(f'<td class="num">{v}</td>' for v in (
        f"{r.runout_deg:.3f}", f"{r.runout_phase_deg:.0f}", f"{r.runout_mm:.2f}")) + "</tr>"
        for w, r in source.wheels.items() if r.runout_deg is not None)
    return (f"<p>Toe and camber are of the {said}.</p><h2>Rim runout</h2><table><tr><th>wheel</th>"
            "<th>runout (deg)</th><th>direction on the rim (deg)</th><th>lip wobble (mm)</th></tr>"
            f"{rows}</table>")


def _steering_section(results: list[Measurement], spec: VehicleSpec | None) -> tuple[str, bool | None]:
    """The steering sweep's table (the job's first and last valid sweeps: before and after a
    caster adjustment), and its verdict (None: no sweep, or no figure to judge)."""
    sweeps = [r for r in results if r.valid and r.steering is not None]
    if not sweeps:
        return "", None
    first, last = sweeps[0], sweeps[-1]
    same = first is last
    vf, vl = _verdicts(first, spec, STEERING_ANGLE_NAMES), _verdicts(last, spec, STEERING_ANGLE_NAMES)
    rows = []
    for name in STEERING_ANGLE_NAMES:
        wheel, kind = name.split(".")
        s = spec.angles.get(name) if spec else None
        limits = (f"{s.nominal_deg:+.2f}&deg; &plusmn; {s.tolerance_deg:.2f}&deg;") if s else "&mdash;"
        cls, word = _status(vl.get(name))
        rows.append(f"<tr><td>{wheel} {_LABELS[kind]}</td><td>{limits}</td>"
                    + ("" if same else _cell(first.angle(name), vf.get(name)))
                    + f'{_cell(last.angle(name), vl.get(name))}<td class="{cls}">{word}</td></tr>')
    st = last.steering
    extra = [("kingpin offset at the runway (mm, + inboard)",
              {w: f"{r.kingpin_offset_m * 1000:+.1f}" for w, r in st.wheels.items()}),
             ("caster by the shops' 1.5x camber-change rule (deg)",
              {w: f"{r.caster_classic_deg:+.2f}" for w, r in st.wheels.items()}),
             ("steered left / right (deg)",
              {w: f"{r.steer_left_deg:+.1f} / {r.steer_right_deg:+.1f}" for w, r in st.wheels.items()})]
    details = "".join(f"<tr><td>{label}</td>" + "".join(f'<td class="num">{v.get(w, "&mdash;")}</td>'
                                                       for w in ("FL", "FR")) + "</tr>" for label, v in extra)
    turns = "".join(
        f"<li>{side} turn: inner wheel {_text(t['inner_wheel'])} at {t['inner_deg']:.1f}&deg;, outer wheel at "
        f"{t['outer_deg']:.1f}&deg; (toe-out on turns {t['inner_deg'] - t['outer_deg']:+.1f}&deg;)</li>"
        for side, t in st.toe_out_on_turns.items())
    note = ("" if last.runout_compensated else
            '<p class="warn">The included angle takes the rim plane\'s camber: runout was not compensated.</p>')
    checked = [vl.get(n) for n in STEERING_ANGLE_NAMES if vl.get(n) is not None]
    verdict = None if not checked else all(checked)
    html = (f"<h2>Steering geometry (steered {st.sweep_deg:g}&deg; each way)</h2>"
            f"<table class=\"angles\"><tr><th>angle</th><th>specification</th>{'' if same else '<th>before</th>'}"
            f"<th>{'measured' if same else 'after'}</th><th>status</th></tr>{''.join(rows)}</table>"
            f"<table><tr><th></th><th>FL</th><th>FR</th></tr>{details}</table>"
            + (f"<ul>{turns}</ul>" if turns else
               "<p>Toe-out on turns: the sweep did not reach 20&deg; (steer 20&deg; each way to measure it).</p>")
            + note)
    return html, verdict


def safe_filename(job_id: str) -> str:
    """A file name for a job id with any characters: readable part + a short hash (no collisions)."""
    readable = re.sub(r"[^A-Za-z0-9-]+", "_", job_id).strip("_-")[:60] or "job"
    return f"{readable}-{hashlib.sha1(job_id.encode()).hexdigest()[:8]}"


def _text(value) -> str:
    """Any text for the HTML: control characters escaped (visible), then HTML-escaped."""
    return escape(visible(str(value)))


def _status(v: bool | None) -> tuple[str, str]:
    return {True: ("pass", "in tolerance"), False: ("fail", "OUT"), None: ("none", "no spec")}[v]


def _values(result: Measurement) -> dict:
    return {name: angle_value(result, name) for name in ANGLE_NAMES}


def _verdicts(result: Measurement, spec: VehicleSpec | None, names: tuple = ANGLE_NAMES) -> dict:
    if spec is not None:
        return evaluate(result, spec)
    stored = result.verdicts or {}
    return {name: stored.get(name) for name in names} | {"overall": stored.get("overall")}


def _cell(v: float | None, ok: bool | None) -> str:
    if v is None:
        return '<td class="num none">&mdash;</td>'
    cls = _status(ok)[0]
    return f'<td class="num {cls}">{v:+.2f}&deg;</td>'


def build_report(job_id: str, results: list[Measurement], spec: VehicleSpec | None = None) -> str:
    """The HTML report of a job from its results in time order (at least one)."""
    if not results:
        raise StorageError(f"job {job_id!r}: no cycles in the history", hint="`station history` lists the jobs")
    valid = [r for r in results if r.valid]
    before = valid[0] if valid else results[0]
    after = valid[-1] if valid else results[-1]
    same = before is after
    vb, va = _verdicts(before, spec), _verdicts(after, spec)
    xb, xa = _values(before), _values(after)
    e = _text
    vehicle = spec.name if spec else (after.vehicle_spec or "no vehicle spec")
    steering, steering_ok = _steering_section(results, spec)
    overall = False if steering_ok is False and va.get("overall") is not None else va.get("overall")
    vcls, vtext = {True: ("pass", "PASS"), False: ("fail", "FAIL"), None: ("none", "NOT CHECKED")}[overall]

    rows = []
    for name in ANGLE_NAMES:
        where, kind = name.split(".") if "." in name else ("", name)
        label = f"{where} {_LABELS.get(kind, kind)}".strip()
        s = spec.angles.get(name) if spec else None
        limits = (f"{s.nominal_deg:+.2f}&deg; &plusmn; {s.tolerance_deg:.2f}&deg; "
                  f"({s.low_deg:+.2f} &hellip; {s.high_deg:+.2f})") if s else "&mdash;"
        cls, word = _status(va.get(name))
        rows.append(f"<tr><td>{e(label)}</td><td>{limits}</td>"
                    + ("" if same else _cell(xb[name], vb.get(name)))
                    + f'{_cell(xa[name], va.get(name))}<td class="{cls}">{word}</td></tr>')

    def meta(r: Measurement) -> str:
        return f"{e(str(r.time_utc or ''))} &middot; cycle {e(str(r.cycle_id or ''))}"

    warnings = []  # (which cycle, text), each text once
    for which, r in ((("before", before), ("after", after)) if not same else (("", after),)):
        for w in r.warnings:
            if str(w) not in {t for _, t in warnings}:
                warnings.append((which, str(w)))
    failed = [r for r in results if not r.valid]
    drawings = ("" if same else top_view_svg(xb, vb, "Before")) + top_view_svg(xa, va, "After" if not same else "Measured")
    cycles = "".join(
        f"<tr><td>{e(str(r.cycle_id))}</td><td>{e(str(r.time_utc))}</td>"
        f"<td>{'valid' if r.valid else 'failed: ' + e(str(r.failure.message if r.failure else ''))}</td></tr>"
        for r in results)
    html = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; style-src 'unsafe-inline'; img-src data:">
<title>Wheel alignment report &ndash; {e(job_id)}</title><style>{_CSS}</style></head>
<body>
<h1>Wheel alignment report</h1>
<table class="meta">
<tr><td>Job / VIN</td><td><b>{e(job_id)}</b></td></tr>
<tr><td>Vehicle</td><td>{e(vehicle)}</td></tr>
<tr><td>{'Measured' if same else 'Before'}</td><td>{meta(before)}</td></tr>
{'' if same else f'<tr><td>After</td><td>{meta(after)}</td></tr>'}
<tr><td>Station</td><td>{e(str(after.station or ''))} &middot; calibration {e(str(after.calibration_id or ''))}
 &middot; software {e(str(after.software_version or ''))}</td></tr>
</table>
<p>Result{'' if same else ' after adjustment'}: <span class="verdict {vcls}">{vtext}</span></p>
<h2>Angles (degrees)</h2>
<table class="angles"><tr><th>angle</th><th>specification</th>{'' if same else '<th>before</th>'}
<th>{'measured' if same else 'after'}</th><th>status</th></tr>
{''.join(rows)}</table>
<p class="foot">Toe: + is toe-in. Camber: + is the top of the wheel leaning out. Thrust: + is the thrust
line to the right. Front toe is measured against the geometric centreline. Colours:
<span class="pass">&nbsp;in tolerance&nbsp;</span> <span class="fail">&nbsp;out of tolerance&nbsp;</span>
<span class="none">&nbsp;no figure in the spec&nbsp;</span>.</p>
{_runout_section(before, after, same)}
{steering}
<h2>Top view</h2>
<div class="drawings">{drawings}</div>
{'<h2>Warnings</h2><ul>' + ''.join(f'<li class="warn">{e(which + ": ") if which else ""}{e(w)}</li>' for which, w in warnings) + '</ul>' if warnings else ''}
<h2>Cycles of this job</h2>
<table><tr><th>cycle</th><th>time (UTC)</th><th>state</th></tr>{cycles}</table>
{f'<p class="warn">{len(failed)} cycle(s) of this job failed and are not used above.</p>' if failed else ''}
<p class="foot">{e(spec.source) if spec else ''}</p>
</body></html>
"""
    return html


def write_report(html: str, path: str | os.PathLike) -> Path:
    """Write atomically (temp file + rename). OSError -> StorageError."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, html)
    except OSError as err:
        raise StorageError(f"{path}: cannot write the report: {err.strerror or err}",
                           hint="choose a writable folder with --out") from err
    return path


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        exe = shutil.which(name)
        if exe:
            return exe
    return "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None


def render_with_chromium(html_path: str | os.PathLike, out_path: str | os.PathLike, *, kind: str = "pdf",
                         timeout_s: float = 90.0, window: tuple[int, int] = (1000, 1400)) -> Path:
    """Print an HTML file to PDF (``kind="pdf"``) or a PNG screenshot with headless Chromium."""
    exe = find_chromium()
    if exe is None:
        raise StorageError("cannot make a PDF: Chromium is not installed",
                           hint="apt-get install chromium, or print the HTML report from any browser")
    html_path, out_path = Path(html_path).resolve(), Path(out_path).resolve()
    with tempfile.TemporaryDirectory(prefix="station-chromium-") as profile:
        args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--disable-dev-shm-usage", f"--user-data-dir={profile}"]
        if kind == "pdf":
            args += ["--no-pdf-header-footer", f"--print-to-pdf={out_path}"]
        elif kind == "png":
            args += [f"--window-size={window[0]},{window[1]}", f"--screenshot={out_path}"]
        else:
            raise ValueError(f"kind must be 'pdf' or 'png', not {kind!r}")
        try:
            proc = subprocess.run(args + [html_path.as_uri()], capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise StorageError(f"Chromium did not finish the {kind.upper()} within {timeout_s:g} s") from None
    if proc.returncode != 0 or not out_path.exists() or out_path.stat().st_size == 0:
        raise StorageError(f"Chromium could not render {html_path} to {kind.upper()} "
                           f"(exit {proc.returncode}): {proc.stderr.strip()[-300:]}")
    return out_path
