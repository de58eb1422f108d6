"""The procedure's runout compensation and steering sweep driven from the Procedure page in a
real browser (headless Chromium over its DevTools protocol, tests/cdp.py), against a `station ui`
on the small simulated station, whose technician rolls the car and steers when the guides ask.

The runout step shows each rim's runout and the spin axes' toe (the history's values); the
steering step's caster and SAI appear as the history keeps them; their progress lines arrive in
the order the station wrote them; the Adjust page then shows the sweep's caster and SAI with its
time, says when a front wheel's camber moved since the sweep, and runs the sweep again on a
button. Single frames, no recording (as the PLC's steering test): the runout step takes about
2-3 minutes of rendering here, the sweep about 15 s. Screenshots go to tests/artifacts/ui/.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import pytest

from tests.cdp import find_chromium
from tests.station_fixtures import small_station_config, truth_calibration
from tests.ui_server import UiServer

ROOT = Path(__file__).resolve().parents[1]
ARTIFACTS = Path(os.environ.get("STATION_TEST_ARTIFACTS") or ROOT / "tests" / "artifacts") / "ui"
SEED = 5           # a vehicle whose sweep the small station follows (vehicle 11's front rims slip past its limit)
JOB = "BROWSER-VIN-STEPS"
VEHICLE = "dodge-caravan-2007"

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed (setup.sh installs it)")]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """(base URL, config) of `station ui` on the small simulated station, single frames."""
    tmp = tmp_path_factory.mktemp("ui-steps")
    config = small_station_config(tmp, capture__frames_averaged=1, recording__enabled=False)
    truth_calibration(config)
    ui = UiServer(config, tmp, SEED, adjust_steps=3)
    yield ui.base, config
    ui.close()


@pytest.fixture(scope="module")
def page():
    from tests.cdp import Browser

    b = Browser()
    yield b.page()
    b.close()


def _stored(config, job: str) -> list[dict]:
    from station.records.history import History

    with History(config.data_path("history.sqlite"), read_only=True) as h:
        return sorted(h.query(job=job), key=lambda r: r["time_utc"])


def _run_step(page, base: str, key: str, timeout: float) -> list[str]:
    """Start step ``key`` from the Procedure page and wait for its outcome; the log's lines."""
    page.goto(base + "/procedure")
    page.wait(f"document.querySelector('#job-line').textContent.includes('{JOB}')")
    page.wait(f"!document.querySelector('button[data-key={key}]').disabled")
    page.click(f"button[data-key={key}]")
    page.wait(f"document.querySelector('#step-{key} .state').textContent === 'running'", timeout=10)
    page.wait(f"['done', 'failed', 'error'].includes(document.querySelector('#step-{key} .state').textContent)",
              timeout=timeout)
    page.wait("document.querySelector('#outcome').textContent !== ''", timeout=10)
    assert page.console_errors() == []
    return page.js("[...document.querySelectorAll('#log .line')].map(d => d.textContent)")


def test_runout_compensation_from_the_procedure_page_shows_each_rims_runout(server, page):
    base, config = server
    page.goto(base + "/")
    page.wait("document.querySelectorAll('#vehicle-list div').length >= 3")
    page.type("#vehicle-search", "caravan")
    page.wait("document.querySelectorAll('#vehicle-list div').length === 1")
    page.click("#vehicle-list div")
    page.wait("document.querySelector('#vehicle-chosen').textContent === 'Dodge Caravan 2007'")
    page.type("#job-id", JOB)
    page.click("#save-job")
    text = page.wait("!document.querySelector('#message').classList.contains('hidden') && "
                     "document.querySelector('#message').textContent")
    assert text.startswith(f"Job {JOB} started"), text

    t0 = time.monotonic()
    lines = _run_step(page, base, "runout", timeout=600)
    seconds = time.monotonic() - t0
    assert page.text("#outcome") == "Runout compensation: done.", page.text("#outcome")
    # the guide's lines, streamed in the order the station wrote them: back, forward, back to the start
    asks = [x for x in lines if x.startswith("roll the car")]
    assert len(asks) >= 3 and "back" in asks[0] and "forward" in asks[1], asks
    assert lines[0] == "Runout compensation: opening the cameras" and lines[-1] == "Runout compensation: done"
    stored = _stored(config, JOB)
    assert len(stored) == 1 and stored[0]["valid"] and stored[0]["result"]["runout_compensated"]
    wheels = stored[0]["result"]["wheels"]
    shown = page.js("Object.fromEntries([...document.querySelectorAll('#result-table tr[data-wheel]')].map(r => "
                    "[r.dataset.wheel, [Number(r.children[1].dataset.value), Number(r.querySelector('.runout').dataset.value),"
                    " r.querySelector('.runout').textContent]]))")
    assert sorted(shown) == ["FL", "FR", "RL", "RR"]
    for w, (toe, runout, text) in shown.items():
        assert toe == pytest.approx(stored[0]["angles"][f"{w}.toe"], abs=1e-12)
        assert runout == pytest.approx(wheels[w]["runout_deg"], abs=1e-12) and 0 < runout < 2
        assert text == f"{runout:.3f}°"
    assert "spin axes (runout compensated)" in page.text("#result-card")
    page.screenshot(ARTIFACTS / "procedure-runout.png")
    print(f"runout step: {seconds:.0f} s")


def test_the_steering_sweep_from_the_procedure_page_shows_caster_and_sai(server, page):
    base, config = server
    t0 = time.monotonic()
    lines = _run_step(page, base, "steering", timeout=300)
    seconds = time.monotonic() - t0
    assert page.text("#outcome") == "Steering sweep (caster, SAI): done.", page.text("#outcome")
    asks = [x for x in lines if x.startswith("steer ")]
    assert asks == ["steer left to 10 deg, then hold the steering wheel still",
                    "steer right to 10 deg, then hold the steering wheel still",
                    "steer straight ahead, then hold the steering wheel still"]
    assert sum(x.endswith("hold still: capturing") for x in lines) == 3
    sweep = _stored(config, JOB)[-1]
    assert sweep["valid"] and sweep["result"]["steering"]
    shown = page.js("Object.fromEntries([...document.querySelectorAll('#steering-table tr[data-wheel]')].map(r => "
                    "[r.dataset.wheel, [...r.querySelectorAll('td.num')].map(td => Number(td.dataset.value))]))")
    assert sorted(shown) == ["FL", "FR"]
    for w, (caster, sai, included) in shown.items():
        s = sweep["result"]["steering"]["wheels"][w]
        assert caster == pytest.approx(s["caster_deg"], abs=1e-12) and sai == pytest.approx(s["sai_deg"], abs=1e-12)
        assert included == pytest.approx(s["included_angle_deg"], abs=1e-12)
        assert 0 < caster < 10 and 5 < sai < 20
    page.screenshot(ARTIFACTS / "procedure-steering.png")
    print(f"steering step: {seconds:.0f} s")


def test_the_adjust_page_shows_the_sweeps_caster_with_its_time_and_runs_it_again(server, page):
    base, config = server
    sweep = _stored(config, JOB)[-1]
    page.goto(base + "/adjust")
    page.wait(f"document.querySelector('#sweep-line').dataset.cycle === '{sweep['cycle_id']}'")
    line = page.text("#sweep-line")
    assert line.startswith("From the steering sweep at ") and "Re-run the sweep after adjusting caster." in line
    for w in ("FL", "FR"):
        s = sweep["result"]["steering"]["wheels"][w]
        assert float(page.js(f"document.querySelector('#g-{w}-caster').dataset.value")) == pytest.approx(s["caster_deg"])
        assert float(page.js(f"document.querySelector('#g-{w}-sai').dataset.value")) == pytest.approx(s["sai_deg"])
        window = page.js(f"document.querySelector('#g-{w}-caster').className")
        assert window in ("gauge ok", "gauge out")  # the Dodge's caster window gives a verdict
    # the page's rule: a live camber more than 3 sigma (at least 0.05 deg) from the sweep's says so
    wheels = sweep["result"]["wheels"]
    limit = {w: max(0.05, 3 * math.hypot(0.01, wheels[w]["camber_std_deg"])) for w in ("FL", "FR")}
    moved = round(limit["FL"] + 0.2, 2)
    rc = bool(sweep["result"].get("runout_compensated"))
    notes, cls = page.js(f"(() => {{ const n = casterNotes({{runout_compensated: {str(rc).lower()}, wheels: {{"
                         f"FL: {{live: true, camber: {{value: {wheels['FL']['camber_deg'] + moved}, std: 0.01}}}}, "
                         f"FR: {{live: true, camber: {{value: {wheels['FR']['camber_deg'] + 0.01}, std: 0.01}}}}}}}}); "
                         "return [n, document.querySelector('#caster-FL .note').className]; })()")
    assert notes["FL"].startswith(f"camber has moved +{moved:.2f}° since the sweep") and "run the sweep again" in notes["FL"]
    assert notes["FR"].startswith("camber as at the sweep (+0.01°)")
    assert cls == "note out-text"  # in red
    page.screenshot(ARTIFACTS / "adjust-caster.png")
    # the button runs the sweep again (the live view pauses meanwhile); the card then shows the new one
    page.click("#rerun-sweep")
    page.wait("document.querySelector('#sweep-message').textContent.startsWith('The steering sweep runs')", timeout=10)
    page.wait(f"document.querySelector('#sweep-line').dataset.cycle !== '{sweep['cycle_id']}'", timeout=400)
    newer = _stored(config, JOB)[-1]
    assert newer["cycle_id"] != sweep["cycle_id"] and page.js("document.querySelector('#sweep-line').dataset.cycle") == \
        newer["cycle_id"]
    assert float(page.js("document.querySelector('#g-FL-caster').dataset.value")) == pytest.approx(
        newer["result"]["steering"]["wheels"]["FL"]["caster_deg"])
    assert page.console_errors() == []
