"""Before/after report: content, escaping, colours, and a real headless Chromium render."""

import re
import struct
from pathlib import Path

import pytest

from result_builder import make_result, with_spec, with_steering
from station.records.history import History
from station.records.report import build_report, find_chromium, render_with_chromium, safe_filename, write_report
from station.records.report_svg import top_view_svg
from station.records.vehicle_specs import load_vehicle_specs

SPECS = load_vehicle_specs(Path(__file__).resolve().parent.parent / "config" / "vehicles.yaml")
CARAVAN = SPECS["dodge-caravan-2007"]
ODD_JOB = 'VIN <script>alert("x")</script> & Co/../\u00e9\u00df "1"'


def job_results(job_id=ODD_JOB):
    before = with_spec(make_result(1, cycle=1, job_id=job_id,
                                   toe={"FL": 0.40, "FR": -0.20, "RL": 0.02, "RR": 0.0},
                                   camber={"FL": 0.9, "FR": 0.1, "RL": 0.0, "RR": 0.05}), CARAVAN)
    failed = make_result(2, cycle=2, job_id=job_id, valid=False)
    after = with_spec(make_result(3, cycle=3, job_id=job_id,
                                  toe={"FL": 0.05, "FR": 0.06, "RL": 0.01, "RR": 0.0},
                                  camber={"FL": 0.12, "FR": 0.1, "RL": 0.0, "RR": 0.05}), CARAVAN)
    return [before, failed, after]


def test_report_content_and_escaping():
    results = job_results()
    html = build_report(ODD_JOB, results, CARAVAN)
    assert "<script>" not in html and "&lt;script&gt;" in html
    assert "Dodge Caravan 2007" in html
    # before had FL camber 0.90 (out: window -0.30..0.50), after 0.12 (in)
    fl_camber = re.search(r"<tr><td>FL camber</td>(.*?)</tr>", html).group(1)
    assert '<td class="num fail">+0.90&deg;</td>' in fl_camber
    assert '<td class="num pass">+0.12&deg;</td>' in fl_camber
    assert "+0.10&deg; &plusmn; 0.40&deg;" in fl_camber
    assert 'class="verdict pass">PASS' in html
    assert html.count("<svg") == 2 and "Before" in html and "After" in html
    assert "1 cycle(s) of this job failed" in html and "no closed rim contour" in html
    # nothing is fetched from outside: self-contained
    assert not re.search(r"""(src|href)=["']?(https?:)?//""", html)


def test_single_cycle_and_no_spec():
    r = make_result(4, cycle=1, job_id="J1", vehicle_spec=None)
    html = build_report("J1", [r], None)
    assert html.count("<svg") == 1 and "Measured" in html and "NOT CHECKED" in html
    assert "no spec" in html


def test_top_view_rotations_follow_the_sign_conventions():
    values = {"FL.toe": 0.5, "FR.toe": 0.5, "FL.camber": 1.0, "FR.camber": 1.0, "thrust": 0.2}
    svg = top_view_svg(values, {}, "t")
    rots = [float(x) for x in re.findall(r"rotate\(([-0-9.]+)\)", svg)]
    # toe-in: the left wheel turns clockwise (+), the right counter-clockwise (-), 10x exaggerated
    assert rots[0] == pytest.approx(5.0) and rots[2] == pytest.approx(-5.0)
    # camber +: the left glyph's top leans left (-), the right's leans right (+)
    assert rots[1] == pytest.approx(-10.0) and rots[3] == pytest.approx(10.0)
    assert rots[-1] == pytest.approx(2.0)  # thrust to the right: clockwise


def test_safe_filename():
    a, b = safe_filename(ODD_JOB), safe_filename(ODD_JOB + "x")
    assert a != b and "/" not in a and ".." not in a and re.fullmatch(r"[A-Za-z0-9._-]+", a)
    assert safe_filename("WVWZZZ1KZAW000001").startswith("WVWZZZ1KZAW000001-")


def test_report_from_history_via_cli(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("STATION_DATA_DIR", str(tmp_path))
    with History(tmp_path / "history.sqlite") as h:
        for r in job_results():
            h.store(r)
    from station.cli import main
    out = tmp_path / "r.html"
    assert main(["report", ODD_JOB, "--out", str(out)]) == 0
    html = out.read_text()
    assert "+0.90&deg;" in html and "+0.12&deg;" in html
    assert main(["report", "no-such-job"]) == 2
    assert "no cycles" in capsys.readouterr().err


def _png_size(path):
    data = Path(path).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


@pytest.mark.skipif(find_chromium() is None, reason="Chromium is not installed (apt-get install chromium)")
def test_chromium_renders_pdf_and_png(tmp_path):
    html_path = write_report(build_report(ODD_JOB, job_results(), CARAVAN), tmp_path / "report.html")
    pdf = render_with_chromium(html_path, tmp_path / "report.pdf", kind="pdf")
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF-") and len(data) > 20_000
    assert 1 <= len(re.findall(rb"/Type\s*/Page[^s]", data)) <= 3  # an A4 sheet or two, not zero
    png = render_with_chromium(html_path, tmp_path / "report.png", kind="png")
    w, h = _png_size(png)
    assert (w, h) == (1000, 1400) and png.stat().st_size > 30_000
    # the page is not blank: the PNG holds many distinct colours (green/red cells, drawings)
    import cv2
    img = cv2.imread(str(png))
    assert img is not None
    reds = ((img[:, :, 2] > 180) & (img[:, :, 1] < 120) & (img[:, :, 0] < 120)).sum()
    greens = ((img[:, :, 1] > 110) & (img[:, :, 2] < 80) & (img[:, :, 0] < 100)).sum()
    assert reds > 200 and greens > 200


def test_off_scale_angles_are_clamped_and_dashed():
    svg = top_view_svg({"FL.toe": 80.0, "FR.toe": 0.1, "RL.camber": -30.0}, {}, "t")
    rots = [float(x) for x in re.findall(r"rotate\(([-0-9.]+)\)", svg)]
    assert max(abs(r) for r in rots) == pytest.approx(25.0)
    assert svg.count('stroke-dasharray="5 3"') == 1 and svg.count('stroke-dasharray="4 2"') == 1
    assert "toe +80.00\u00b0" in svg  # the true number is still printed


def test_warnings_listed_once_with_their_cycle():
    results = job_results()
    results[0].warnings = ["pair FR drift", "glare on cam3"]
    results[-1].warnings = ["pair FR drift"]
    html = build_report("J", results, CARAVAN)
    assert html.count("pair FR drift") == 1 and "before: glare on cam3" in html


def test_the_report_says_whether_toe_and_camber_are_compensated_and_prints_the_runout():
    before, _, after = job_results("J-RUNOUT")
    after.runout_compensated = True
    for k, w in enumerate(("FL", "FR", "RL", "RR")):
        r = after.wheels[w]
        r.runout_deg, r.runout_phase_deg, r.runout_mm = 0.05 * (k + 1), 90.0 * k, 0.4 * (k + 1)
    html = build_report("J-RUNOUT", [before, after], None)
    assert "before: rim planes (runout not compensated); after: spin axes (runout compensated)" in html
    rr = re.search(r"<tr><td>RR</td>(.*?)</tr>", html.split("Rim runout")[1]).group(1)
    assert rr == '<td class="num">0.200</td><td class="num">270</td><td class="num">1.60</td>'
    plain = build_report("J-RUNOUT", [before], None)
    assert "Toe and camber are of the rim planes (runout not compensated)" in plain and "Rim runout" not in plain


def test_the_steering_sweep_has_its_table_verdict_and_toe_out_on_turns():
    echo = SPECS["toyota-echo-2003"]  # caster 2.00 +/- 0.75, SAI 10.08 +/- 0.75
    camber = {"FL": -0.6, "FR": -0.5, "RL": -0.9, "RR": -0.9}
    toe = {"FL": 0.0, "FR": 0.0, "RL": 0.17, "RR": 0.17}
    before = make_result(1, cycle=1, job_id="J-ST", toe=toe, camber=camber)
    sweep = with_steering(make_result(2, cycle=2, job_id="J-ST", toe=toe, camber=camber),
                          {"FL": 3.10, "FR": 2.20}, {"FL": 10.0, "FR": 10.2})
    after = make_result(3, cycle=3, job_id="J-ST", toe=toe, camber=camber)
    html = build_report("J-ST", [before, sweep, after], echo)
    section = html.split("Steering geometry (steered 20&deg; each way)")[1]
    fl = re.search(r"<tr><td>FL caster</td>(.*?)</tr>", section).group(1)
    assert '<td class="num fail">+3.10&deg;</td>' in fl and "+2.00&deg; &plusmn; 0.75&deg;" in fl
    fr_sai = re.search(r"<tr><td>FR SAI</td>(.*?)</tr>", section).group(1)
    assert '<td class="num pass">+10.20&deg;</td>' in fr_sai
    assert re.search(r"<tr><td>FL included angle</td>.*?no spec", section)
    assert "inner wheel FL at 20.0&deg;, outer wheel at 18.6&deg; (toe-out on turns +1.4&deg;)" in section
    assert "runout was not compensated" in section
    assert 'class="verdict fail">FAIL' in html  # toe and camber pass; FL caster does not
    sweep.steering.wheels["FL"].caster_deg = 2.5
    assert 'class="verdict pass">PASS' in build_report("J-ST", [before, sweep, after], echo)
    short = with_steering(make_result(2, cycle=2, job_id="J-ST"), {"FL": 3, "FR": 3}, {"FL": 9, "FR": 9}, 10.0)
    assert "did not reach 20&deg;" in build_report("J-ST", [short], None)
    assert "Steering geometry" not in build_report("J-ST", [before, after], echo)
