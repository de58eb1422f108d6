"""`station ui` without a browser or cameras: routes, login, CSRF, bad input, one step at a time,
a failing step, the live view giving way to a step (Starlette's TestClient, fake stations)."""

from __future__ import annotations

import threading
import time
import warnings

import pytest

warnings.filterwarnings("ignore", message=".*httpx.*")  # Starlette 1.x suggests httpx2; httpx works
from starlette.testclient import TestClient  # noqa: E402

from station.config import load_config  # noqa: E402
from station.errors import ConfigError, RollNotReached  # noqa: E402
from station.ui.app import build_app  # noqa: E402
from station.ui.auth import hash_password, verify_password  # noqa: E402
from station.ui.hardware import Hardware  # noqa: E402
from tests.result_builder import make_result  # noqa: E402

BASE = "http://127.0.0.1:8080"
PASSWORD = "tie-rod-42"


class FakeStation:
    """What a step sees of station.cycle.Station: measure() waits for ``gate`` and returns
    ``outcome`` (a result, or an exception to raise)."""

    def __init__(self, progress, gate: threading.Event, outcome):
        self.progress, self.gate, self.outcome = progress, gate, outcome
        self.context = type("Ctx", (), {"simulation": None})()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def measure(self, *, job_id=None, vehicle_spec=None, **kw):
        self.progress("capturing 8 cameras")
        if not self.gate.wait(20):
            raise TimeoutError("the test never opened the gate")
        if isinstance(self.outcome, BaseException):
            raise self.outcome
        result = self.outcome
        result.job_id, result.vehicle_spec = job_id, vehicle_spec
        return result


@pytest.fixture
def fake(tmp_path):
    """(hardware with a fake station, its gate, a setter of the outcome, the config)."""
    config = load_config()
    gate = threading.Event()
    state = {"outcome": make_result(1, cycle=1)}
    hw = Hardware(config, seed=5, open_station=lambda cfg, seed, progress: FakeStation(progress, gate, state["outcome"]))
    return hw, gate, state, config


def client(config, hw=None, host="127.0.0.1", password_hash=None, tmp=None) -> TestClient:
    app = build_app(config, host=host, hardware=hw, password_hash=password_hash, crash_dir=tmp)
    return TestClient(app, base_url=BASE, raise_server_exceptions=False)


def csrf(c: TestClient) -> dict:
    return {"x-csrf-token": c.get("/api/session").json()["csrf"]}


def test_pages_are_served_with_a_strict_content_security_policy(fake):
    hw, _, _, config = fake
    c = client(config, hw)
    for path in ("/", "/procedure", "/adjust", "/cameras", "/history", "/station"):
        r = c.get(path)
        assert r.status_code == 200 and "<!DOCTYPE html>" in r.text, path
        assert r.headers["content-security-policy"].startswith("default-src 'self'")
        assert "<script>" not in r.text and "style=" not in r.text  # no inline script or style: CSP allows none
        assert 'src="http' not in r.text and 'href="http' not in r.text  # nothing from the internet
    assert c.get("/static/common.js").status_code == 200
    r = c.get("/api/nothing")
    assert r.status_code == 404 and r.json()["error"] == "nothing here: /api/nothing"


def test_vehicle_search_and_job_validation(fake):
    hw, _, _, config = fake
    c = client(config, hw)
    assert [v["key"] for v in c.get("/api/vehicles", params={"q": "caravan 2007"}).json()["vehicles"]] == \
        ["dodge-caravan-2007"]
    assert c.get("/api/vehicles", params={"q": "lamborghini"}).json()["vehicles"] == []
    h = csrf(c)
    r = c.post("/api/job", json={"job_id": "VIN1", "vehicle": "dodge-caravan"}, headers=h)
    assert r.status_code == 400 and "no vehicle specification 'dodge-caravan'" in r.json()["error"]
    assert "did you mean dodge-caravan-2007" in r.json()["error"]
    r = c.post("/api/job", json={"job_id": "  ", "vehicle": None}, headers=h)
    assert r.status_code == 400 and r.json()["error"] == "the job id / VIN is empty"
    r = c.post("/api/job", json={"job_id": "VIN\n1\u202e", "vehicle": None}, headers=h)
    assert r.status_code == 400 and "\\n \\u202e" in r.json()["error"]
    r = c.post("/api/job", content=b"not json", headers={**h, "content-type": "application/json"})
    assert r.status_code == 400 and "not a JSON object" in r.json()["error"]
    assert c.get("/api/job").json()["job"] is None  # nothing bad was kept
    r = c.post("/api/job", json={"job_id": "VIN1", "vehicle": "toyota-echo-2003"}, headers=h)
    assert r.status_code == 200
    body = c.get("/api/job").json()
    assert body["job"] == {"job_id": "VIN1", "vehicle": "toyota-echo-2003"}
    assert body["spec"]["windows"]["FL.toe"] == {"nominal": 0.0, "low": -0.1, "high": 0.1}  # front.toe, per wheel


def test_changes_need_the_csrf_token_and_the_own_origin(fake):
    hw, _, _, config = fake
    c = client(config, hw)
    body = {"job_id": "VIN1", "vehicle": None}
    r = c.post("/api/job", json=body)
    assert r.status_code == 403 and "CSRF token" in r.json()["error"]
    r = c.post("/api/job", json=body, headers={"x-csrf-token": "forged"})
    assert r.status_code == 403
    h = csrf(c)
    r = c.post("/api/job", json=body, headers={**h, "origin": "http://evil.example"})
    assert r.status_code == 403 and "another site (http://evil.example)" in r.json()["error"]
    other = client(config, hw)  # another browser's session has another token
    assert other.post("/api/job", json=body, headers=h).status_code == 403
    assert c.post("/api/job", json=body, headers={**h, "origin": BASE}).status_code == 200
    cookie = c.get("/api/session").headers.get("set-cookie") or ""
    fresh = client(config, hw).get("/api/session").headers["set-cookie"]
    assert "HttpOnly" in fresh and "SameSite=Strict" in fresh and cookie == ""  # one cookie per session
    r = TestClient(build_app(config, hardware=hw), base_url="http://rebound.example:8080").get("/")
    assert r.status_code == 400 and "127.0.0.1 and localhost only" in r.json()["error"]  # DNS rebinding


def test_password_hash_round_trip():
    stored = hash_password(PASSWORD, iterations=1000)
    assert stored.startswith("pbkdf2_sha256$1000$") and PASSWORD not in stored
    assert verify_password(PASSWORD, stored) and not verify_password("tie-rod-43", stored)
    assert hash_password(PASSWORD, iterations=1000) != stored  # salted


def test_beyond_loopback_a_password_is_required(fake, tmp_path):
    hw, _, _, config = fake
    with pytest.raises(ConfigError, match="open to the network at 0.0.0.0 without a password"):
        build_app(config, host="0.0.0.0", hardware=hw)
    with pytest.raises(ConfigError, match="ui.password_hash: not a password hash"):
        build_app(config, host="0.0.0.0", hardware=hw, password_hash="secret")
    c = client(config, hw, host="0.0.0.0", password_hash=hash_password(PASSWORD, iterations=1000))
    r = c.get("/", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/login"
    assert c.get("/login").status_code == 200
    assert c.get("/api/job").status_code == 401 and c.get("/api/session").status_code == 401
    t0 = time.monotonic()
    r = c.post("/login", json={"password": "wrong"})
    assert r.status_code == 401 and r.json()["error"] == "wrong password" and time.monotonic() - t0 >= 0.9
    assert c.post("/login", json=["not", "a", "form"]).status_code == 401
    r = c.post("/login", json={"password": PASSWORD})
    assert r.status_code == 200 and "HttpOnly" in r.headers["set-cookie"]
    assert c.get("/api/job").status_code == 200
    assert c.post("/api/job", json={"job_id": "J", "vehicle": None}).status_code == 403  # still needs the token
    assert c.post("/api/job", json={"job_id": "J", "vehicle": None}, headers=csrf(c)).status_code == 200
    c.post("/logout", headers=csrf(c))
    assert c.get("/api/job").status_code == 401


def _wait_state(c, key, states=("done", "failed", "error"), timeout=20.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        steps = {s["key"]: s for s in c.get("/api/steps").json()["steps"]}
        last = steps[key]["last"]
        if last and last["state"] in states:
            return last
        time.sleep(0.05)
    raise TimeoutError(key)


def test_one_step_at_a_time_and_a_closed_page_loses_nothing(fake):
    hw, gate, _, config = fake
    c = client(config, hw)
    h = csrf(c)
    r = c.post("/api/steps/measurement/start", headers=h)
    assert r.status_code == 400 and "no job yet" in r.json()["error"]
    c.post("/api/job", json={"job_id": "VIN7", "vehicle": "dodge-caravan-2007"}, headers=h)
    r = c.post("/api/steps/nonsense/start", headers=h)
    assert r.status_code == 404 and "there is no step 'nonsense'" in r.json()["error"]
    r = c.post("/api/steps/measurement/start", headers=h)
    assert r.status_code == 202 and r.json()["state"] == "running"
    r = c.post("/api/steps/runout/start", headers=h)
    assert r.status_code == 409 and "'Measurement' is running" in r.json()["error"]
    r = c.post("/api/job", json={"job_id": "OTHER", "vehicle": None}, headers=h)
    assert r.status_code == 409  # the job cannot change under a running step
    c.close()  # the page is gone; the step goes on
    gate.set()
    runner = c.app.state.screen.runner
    runner.wait(20)
    last = runner.last["measurement"].view()
    assert last["state"] == "done" and last["job_id"] == "VIN7"
    assert last["summary"]["valid"] and last["summary"]["wheels"]["FL"]["toe"]["window"]["low"] == pytest.approx(-0.05)
    assert "capturing 8 cameras" in last["lines"]
    c2 = TestClient(c.app, base_url=BASE)  # a page opened later sees the outcome
    assert _wait_state(c2, "measurement")["state"] == "done"


def test_a_failing_step_shows_the_message_and_the_station_keeps_running(fake, tmp_path):
    hw, gate, state, config = fake
    c = client(config, hw, tmp=tmp_path)
    h = csrf(c)
    c.post("/api/job", json={"job_id": "VIN8", "vehicle": None}, headers=h)
    gate.set()
    state["outcome"] = RollNotReached("the car did not stand -15 cm from where it started within 300 s",
                                      hint="roll the car as the bar shows")
    c.app.state.screen.hardware.open_station = lambda cfg, seed, progress: FakeStation(progress, gate, state["outcome"])
    c.post("/api/steps/measurement/start", headers=h)
    last = _wait_state(c, "measurement")
    assert last["state"] == "failed" and last["code"] == 425 and "did not stand" in last["message"]
    assert last["hint"] == "roll the car as the bar shows"
    state["outcome"] = ZeroDivisionError("a bug")
    c.app.state.screen.hardware.open_station = lambda cfg, seed, progress: FakeStation(progress, gate, state["outcome"])
    c.post("/api/steps/measurement/start", headers=h)
    last = _wait_state(c, "measurement")
    assert last["state"] == "error" and "ZeroDivisionError: a bug" in last["message"]
    assert str(tmp_path) in last["hint"] and list(tmp_path.glob("crash-ui-*.log"))
    state["outcome"] = make_result(2, cycle=2, valid=False)  # an invalid cycle: its failure and hint
    c.app.state.screen.hardware.open_station = lambda cfg, seed, progress: FakeStation(progress, gate, state["outcome"])
    assert c.post("/api/steps/measurement/start", headers=h).status_code == 202
    last = _wait_state(c, "measurement")
    assert last["state"] == "failed" and last["message"] == "RR cam7: no closed rim contour" and last["code"] == 401


def test_history_of_a_job_that_does_not_exist(fake):
    hw, _, _, config = fake
    c = client(config, hw)
    assert c.get("/api/history").json() == {"jobs": [], "cycles": []}
    r = c.get("/history/report", params={"job": "NOPE"})
    assert r.status_code == 404 and r.json()["error"] == "job 'NOPE': no cycles in the history"
    assert c.get("/history/report").status_code == 400
    r = c.get("/api/station").json()
    assert r["plc"]["configured"] == f"tcp {config.plc.host}:{config.plc.port}" and r["plc"]["message"]
    assert r["calibration"]["ok"] is False and r["calibration"]["message"]  # no calibration in this data dir
    assert c.get("/api/cameras/cam1.png").status_code == 404
    assert c.get("/api/live/stream", params={"axle": "middle"}).status_code == 400


def test_the_angle_format_comes_from_the_configuration(fake, tmp_path):
    import yaml

    from station.config import DEFAULT_CONFIG

    hw, _, _, config = fake
    assert config.ui.angle_format == "decimal"
    assert client(config, hw).get("/api/session").json()["angle_format"] == "decimal"
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    for value, error in (("dms", None), ("minutes", "ui.angle_format: expected one of decimal, dms, got 'minutes'")):
        data.setdefault("ui", {})["angle_format"] = value
        path = tmp_path / "station.yaml"
        path.write_text(yaml.safe_dump(data))
        if error is None:
            dms = load_config(path)
            assert dms.ui.angle_format == "dms"
            assert client(dms, Hardware(dms, seed=5)).get("/api/session").json()["angle_format"] == "dms"
        else:
            with pytest.raises(ConfigError, match=error.replace(".", r"\.")):
                load_config(path)
    page = client(config, hw).get("/static/adjust.js").text
    assert "Station.mm(a.mm)" in page  # the toe's mm beside its degrees


def _closed_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_station_page_looks_at_a_plc_server_from_outside(tmp_path, monkeypatch):
    """`station serve` as another process: the page reads state, heartbeat and map version over
    Modbus TCP (read-only), and says so plainly when nothing listens or something else does."""
    import socket

    from station.plc import register_map as rm
    from station.plc.background import BackgroundServer
    from station.plc.device import PlcDevice
    from station.plc.runner import dry_run_runner
    from station.ui.plc_probe import probe
    from pymodbus.client import ModbusTcpClient

    from tests.station_fixtures import small_station_config

    def no_write(*a, **kw):
        raise AssertionError("the screen wrote to the PLC server")

    for name in ("write_register", "write_registers", "readwrite_registers", "write_coil", "write_coils"):
        monkeypatch.setattr(ModbusTcpClient, name, no_write)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with BackgroundServer(PlcDevice(dry_run_runner(10))) as bg:
        port = bg.start_tcp()
        config = small_station_config(tmp_path / "a", plc__port=port)
        plc = client(config, Hardware(config, seed=5)).get("/api/station").json()["plc"]
        assert plc["message"] == f"PLC server at 127.0.0.1:{port}: state idle, heartbeat advancing"
        assert plc["listening"] is True and plc["state"] == "idle" and plc["heartbeat_advancing"] is True
        assert plc["map_version"] == rm.MAP_VERSION and plc["configured"] == f"tcp 127.0.0.1:{port}"
        assert probe("0.0.0.0", port)["state"] == "idle"  # a server bound to every address, reached on loopback
        stopped = probe("127.0.0.1", port, device_id=7)   # not this station's unit id: refused, said so
        assert stopped["listening"] is True and stopped["state"] is None and "refused" in stopped["message"]

    closed = _closed_port()
    config = small_station_config(tmp_path / "b", plc__port=closed)
    t0 = time.monotonic()
    plc = client(config, Hardware(config, seed=5)).get("/api/station").json()["plc"]
    assert plc["message"] == f"no PLC server listening at 127.0.0.1:{closed}" and plc["listening"] is False
    assert time.monotonic() - t0 < 5

    with socket.socket() as mute:  # something else listens there: accepts, never answers
        mute.bind(("127.0.0.1", 0))
        mute.listen()
        t0 = time.monotonic()
        other = probe("127.0.0.1", mute.getsockname()[1])
        assert other["listening"] is True and other["state"] is None
        assert "not answering as the station's PLC server" in other["message"] and time.monotonic() - t0 < 3


def test_the_adjust_page_gets_the_newest_valid_steering_sweep_of_the_job(fake):
    """Caster is not followed live: the Adjust page shows the job's newest valid sweep from the
    history, with its time and each front wheel's camber at the sweep (to see it move since)."""
    from station.records.history import History
    from tests.result_builder import with_steering

    hw, _, _, config = fake
    c = client(config, hw)
    h = csrf(c)
    assert c.get("/api/adjust/steering").json()["message"] == "no job yet: enter it on the Job page"
    c.post("/api/job", json={"job_id": "VIN-C", "vehicle": "dodge-caravan-2007"}, headers=h)
    r = c.get("/api/adjust/steering").json()  # no history at all yet
    assert r["sweep"] is None and r["message"].startswith("no steering sweep in job VIN-C yet")
    older = with_steering(make_result(1, cycle=1, job_id="VIN-C"), {"FL": 3.1, "FR": 3.3}, {"FL": 12.0, "FR": 12.2})
    newer = with_steering(make_result(2, cycle=2, job_id="VIN-C"), {"FL": 4.4, "FR": 3.5}, {"FL": 12.9, "FR": 12.1})
    failed = make_result(3, cycle=3, job_id="VIN-C", valid=False)  # an invalid cycle's sweep is not shown
    failed.steering = with_steering(make_result(3, cycle=3), {"FL": 9.0, "FR": 9.0}, {"FL": 9.0, "FR": 9.0}).steering
    other_job = with_steering(make_result(4, cycle=4, job_id="OTHER"), {"FL": 8.0, "FR": 8.0}, {"FL": 8.0, "FR": 8.0})
    plain = make_result(5, cycle=5, job_id="VIN-C")  # a later measurement without a sweep
    with History(config.data_path("history.sqlite")) as hist:
        for result in (older, newer, failed, other_job, plain):
            hist.store(result)
    r = c.get("/api/adjust/steering").json()
    sweep = r["sweep"]
    assert r["message"] is None and sweep["cycle_id"] == newer.cycle_id and sweep["time_utc"] == newer.time_utc
    fl = sweep["wheels"]["FL"]
    assert fl["caster"]["value"] == pytest.approx(4.4) and fl["sai"]["value"] == pytest.approx(12.9)
    assert fl["caster"]["std"] == pytest.approx(0.02) and fl["caster"]["window"] is not None
    assert fl["caster"]["ok"] == (fl["caster"]["window"]["low"] <= 4.4 <= fl["caster"]["window"]["high"])
    assert fl["camber_at_sweep"]["value"] == pytest.approx(newer.wheels["FL"].camber_deg)
    assert set(sweep["wheels"]) == {"FL", "FR"}
