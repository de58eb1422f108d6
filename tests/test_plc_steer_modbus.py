"""The steering sweep over Modbus TCP (tests/test_plc_steer.py has its table and registers): the
steer timeout (424), the cycle-timeout accounting, refusals, the PLC simulator, mbpoll and
`station serve` driving dry-run sweeps, and one real sweep on a small simulated station whose
technician the simulation is."""

from __future__ import annotations

import math
import shutil
import threading
import time

import pytest
from pymodbus.client import ModbusTcpClient

from station.errors import SteerNotReached
from station.plc import register_map as rm
from station.plc.background import BackgroundServer
from station.plc.device import PlcDevice
from station.plc.dry_steering import SyntheticSteering, wheel_angles
from station.plc.master import PlcSimulator, dry_run_expectation
from station.plc.master import main as plc_sim_main
from station.plc.runner import CycleRequest, dry_run_runner, synthetic_result
from station.plc.steer_operator import steer_plan
from tests.mbpoll_cli import mbpoll, parse, signed
from tests.plc_steer_common import (ACK, BUSY, CASTER, CLEARED_STEER, COMPENSATED, DONE, FAULT, FRONT, IDLE,
                                     IN_POSITION, MEASURE, STEER)
from tests.serve_process import dry_run_serve, free_port


# --- over Modbus TCP ----------------------------------------------------------------------------
@pytest.fixture
def station():
    """factory(runner=None, **device_kw) -> (background server, client, port)."""
    made = []

    def make(runner=None, **device_kw):
        device_kw.setdefault("heartbeat_s", 0.02)
        bg = BackgroundServer(PlcDevice(runner or dry_run_runner(10, reading_s=0.03), **device_kw))
        port = bg.start_tcp()
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        made.append((bg, client))
        assert client.connect()
        return bg, client, port

    yield make
    for bg, client in made:
        client.close()
        bg.stop()


def block(client):
    """The status and result registers (100..224) and the steering block (225..256): two reads."""
    out = {}
    for lo, hi in (rm.RESULT_BLOCK, rm.STEER_BLOCK):
        r = client.read_holding_registers(lo, count=hi - lo)
        assert not r.isError(), r
        out.update(rm.decode_block(r.registers, lo))
    return out


def steer_status(b: dict) -> dict:
    return {k: b[k] for k in CLEARED_STEER}


def wait_state(client, states, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        b = block(client)
        if b["state"] in states:
            return b
        time.sleep(0.005)
    raise AssertionError(f"state {b['state']} never reached {states}")


def trigger(client, job, command=CASTER):
    return client.write_registers(0, [command] + rm.ascii_to_regs(job, 16) + [0] * 16)


def test_dry_run_sweeps_through_the_steer_state_with_the_plc_simulator(station):
    bg, client, _ = station(dry_run_runner(10, delay_s=0.15, reading_s=0.03))  # each capture 0.15 s
    assert block(client)["map_version"] == rm.MAP_VERSION
    seen = []
    sim = PlcSimulator(client, on_steer=seen.append)
    expect = dry_run_expectation(10)
    reports = [sim.run_cycle(f"JOB-{i:06d}", None, CASTER, expect=expect) for i in range(9, 12)]
    assert [r.problems for r in reports] == [[]] * 3
    assert [r.state for r in reports] == ["done", "fault", "done"]
    assert reports[1].fault_code == 422  # job 10 fails on purpose, after its steers
    for r in reports:
        assert [(s.step, s.steps, s.target_deg) for s in r.steers] == [(1, 3, 10.0), (2, 3, -10.0), (3, 3, 0.0)]
        for s in r.steers:
            assert len({x[:2] for x in s.readings}) >= 4, s.readings  # the live angle moved while steering
            assert s.reached and s.readings[-1][:2] == pytest.approx(tuple(wheel_angles(s.target_deg).values()))
            assert s.seconds > 0.1
    want = synthetic_result(CycleRequest("measure_caster", "JOB-000009", None, 0))
    assert reports[0].steering_valid == 1
    assert reports[0].steering["FR"]["sai"] == pytest.approx(want.steering.wheels["FR"].sai_deg, abs=1e-5)
    assert reports[0].steering["FL"]["kingpin_offset_mm"] == pytest.approx(
        want.steering.wheels["FL"].kingpin_offset_m * 1000, abs=1e-4)
    assert len(seen) == 9 and bg.device.stats["steers"] == 9 and bg.device.stats["steer_timeouts"] == 0
    # an ordinary cycle on the same station: no steer, no steering
    plain = sim.run_cycle("JOB-000013", None, MEASURE, expect=expect)
    assert plain.problems == [] and plain.steers == [] and block(client)["steering_valid"] == 0


def test_the_live_registers_follow_the_wheels_and_the_cycle_needs_no_confirmation(station):
    """Raw reads as a PLC makes them: state 5 with the prompt, the live angle moving toward the target,
    no write from the PLC at all, and done with the steering decoded from both blocks."""
    bg, client, _ = station(dry_run_runner(10, reading_s=0.03))
    assert not trigger(client, "JOB-000001").isError()
    prompts, live = set(), []
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        b = block(client)
        if b["state"] == STEER:
            assert b["active_command"] == CASTER and b["result_valid"] == 0 and b["steering_valid"] == 0
            if b["steer_step"]:  # 0: the steer ended between the state read and the steer block's
                prompts.add((b["steer_step"], b["steer_steps"], b["steer_target_i16"]))
            if b["steer_step"] == 1 and b["FL_steer_i16"] is not None:
                live.append((b["steer_readings"], b["FL_steer_i16"], b["FR_steer_i16"]))
        elif b["state"] == DONE:
            break
        else:
            assert b["state"] == BUSY, b["state"]
        time.sleep(0.004)
    assert b["state"] == DONE
    assert prompts == {(1, 3, 10.0), (2, 3, -10.0), (3, 3, 0.0)}
    assert len({n for n, _, _ in live}) >= 4  # several fresh readings seen during steer 1
    assert all(0 < fl <= 10.4 and 0 < fr <= 9.6 and fl >= fr for _, fl, fr in live)  # toward +10, FL inner
    assert max(fl for _, fl, _ in live) - min(fl for _, fl, _ in live) >= 3.0
    assert steer_status(b) == CLEARED_STEER
    want = synthetic_result(CycleRequest("measure_caster", "JOB-000001", None, 0))
    assert b["result_valid"] == 1 and b["steering_valid"] == 1 and b["result_job_id"] == "JOB-000001"
    assert b["FL_caster_f32"] == pytest.approx(want.steering.wheels["FL"].caster_deg, abs=1e-5)
    assert b["FR_included_angle_i16"] == round(want.steering.wheels["FR"].included_angle_deg * 100) / 100
    assert bg.device.stats["refused"] == 0 and bg.device.stats["steers"] == 3


def held_runner(release: threading.Event):
    """A sweep whose wheels stand short of the first target until ``release`` is set, then steer on."""
    def run(request):
        def guide(on_reading):
            wheels = SyntheticSteering(on_reading, reading_s=0.02)

            class Held:
                def steer(self, target):
                    while not release.is_set():
                        on_reading(target, wheel_angles(wheels.mean_deg), False)
                        time.sleep(0.02)
                    wheels.steer(target)
            return Held()

        operator = request.steer_operator(guide)
        for target in steer_plan():
            operator.steer(target)
        return synthetic_result(request, 0)
    return run


def test_in_steer_every_command_is_refused_and_the_sweep_goes_on(station):
    release = threading.Event()
    bg, client, _ = station(held_runner(release))
    assert not trigger(client, "JOB-000001").isError()
    b = wait_state(client, {STEER})
    assert (b["steer_step"], b["steer_target_i16"]) == (1, 10.0)
    refused = 0
    for command in (MEASURE, 2, 3, ACK, COMPENSATED, CASTER, IN_POSITION):
        r = client.write_register(0, command) if command not in (COMPENSATED, CASTER) else trigger(client, "JOB-2",
                                                                                                   command)
        refused += 1
        b = block(client)
        want = (3, 508) if command == IN_POSITION else (6, 501)
        assert r.isError() and (r.exception_code, b["reject_code"]) == want, (command, r)
        assert (b["state"], b["reject_count"], b["steer_step"]) == (STEER, refused, 1), command
    r = client.write_register(0, 8)  # not a command
    assert r.isError() and r.exception_code == 3 and block(client)["reject_code"] == 504
    release.set()  # the technician steers on: the station goes on without a word from the PLC
    b = wait_state(client, {DONE}, timeout=20)
    assert b["result_job_id"] == "JOB-000001" and bg.device.stats["refused"] == refused + 1
    r = trigger(client, "JOB-000002")  # not acknowledged yet
    assert r.isError() and r.exception_code == 3 and block(client)["reject_code"] == 502
    assert not client.write_register(0, ACK).isError() and block(client)["state"] == IDLE


def test_measure_caster_while_busy_gets_the_refusal_every_trigger_gets(station):
    def slow(request):
        time.sleep(0.8)
        return synthetic_result(request, 0)

    bg, client, _ = station(slow)
    for first, second in ((MEASURE, CASTER), (CASTER, MEASURE)):
        assert not trigger(client, "JOB-000001", first).isError()
        r = trigger(client, "JOB-000002", second)
        b = block(client)
        assert r.isError() and r.exception_code == 6 and b["reject_code"] == 501 and b["state"] == BUSY
        wait_state(client, {DONE, FAULT})
        assert not client.write_register(0, ACK).isError()
    # a trigger whose job id is not text: refused before a cycle starts, as for command 1
    r = client.write_registers(0, [CASTER, 0x4101] + [0] * 31)
    assert r.isError() and r.exception_code == 3 and block(client)["reject_code"] == 506
    assert bg.device.stats["started"] == 2


def stalling_runner(share: float, guide_timeout_s: float = 300.0, wheels=FRONT):
    """A sweep whose wheels stop at ``share`` of each target (never reached), reporting ``wheels``."""
    def run(request):
        def guide(on_reading):
            def report(target, angles, reached):
                on_reading(target, {w: a for w, a in angles.items() if w in wheels}, reached)
            return SyntheticSteering(report, reading_s=0.02, reach=share, timeout_s=guide_timeout_s)

        operator = request.steer_operator(guide)
        for target in steer_plan():
            operator.steer(target)
        return synthetic_result(request, 0)
    return run


def test_a_steer_not_reached_in_time_faults_424_with_the_registers_cleared(station):
    bg, client, _ = station(stalling_runner(0.5, wheels=("FL",)), steer_timeout_s=1.5)
    assert not trigger(client, "JOB-000001").isError()
    t0 = time.monotonic()
    b = wait_state(client, {STEER})
    deadline = time.monotonic() + 5
    while b["steer_readings"] < 9 and time.monotonic() < deadline:  # past the ramp: standing short
        b = block(client)
    # the wheels stand at 5 of 10 deg; FR's rim is not seen: no value
    assert (b["state"], b["steer_step"], b["steer_target_i16"], b["FL_steer_i16"], b["FR_steer_i16"],
            b["steer_reached"]) == (STEER, 1, 10.0, 5.2, None, 0)
    b = wait_state(client, {FAULT})
    assert 1.2 < time.monotonic() - t0 < 6
    assert b["fault_code"] == 424 and b["fault_reason"] == "steer 1/3 to +10.0 deg not reached within 1.5 s"
    assert steer_status(b) == CLEARED_STEER and b["result_valid"] == 0 and b["steering_valid"] == 0
    assert math.isnan(b["FL_caster_f32"]) and b["FL_toe_i16"] is None
    assert bg.device.stats["steer_timeouts"] == 1 and bg.device.stats["steers"] == 1
    assert not client.write_register(0, ACK).isError()
    rep = PlcSimulator(client).run_cycle("JOB-000002", None, CASTER)
    assert rep.problems == [] and rep.state == "fault" and rep.fault_code == 424  # the wheels stall again
    bg2, client2, _ = station(steer_timeout_s=1.5)  # the dry run's wheels reach: the same timeout passes
    rep = PlcSimulator(client2).run_cycle("JOB-000002", None, CASTER, expect=dry_run_expectation(10))
    assert rep.problems == [] and rep.state == "done" and bg2.device.stats["steer_timeouts"] == 0


def test_a_guide_giving_up_first_also_leaves_steer_and_faults_424(station):
    """The guide's own timeout (GuidedSteering's timeout_s) before the device's: busy, cleared, 424."""
    bg, client, _ = station(stalling_runner(0.5, guide_timeout_s=0.3), steer_timeout_s=30)
    assert not trigger(client, "JOB-000001").isError()
    t0 = time.monotonic()
    b = wait_state(client, {FAULT})
    assert time.monotonic() - t0 < 5  # not the device's 30 s
    assert b["fault_code"] == 424 and "did not stand at +10 deg" in b["fault_reason"]
    assert steer_status(b) == CLEARED_STEER
    assert bg.device.stats["steer_timeouts"] == 1


def test_the_time_in_steer_is_the_technicians_not_the_cycle_timeouts(station):
    """Three steers of about 0.5 s each against a cycle timeout of 0.4 s: done, not 505, and
    cycle_time_us leaves the steering out. The same time spent busy is a cycle timeout."""
    bg, client, _ = station(dry_run_runner(10, reading_s=0.05), cycle_timeout_s=0.4, steer_timeout_s=5)
    rep = PlcSimulator(client).run_cycle("JOB-000001", None, CASTER)
    assert rep.problems == [] and rep.state == "done", rep
    in_steer = sum(s.seconds for s in rep.steers)
    assert in_steer > 1.0 and rep.total_s > 1.2
    assert rep.measure_s < 0.4  # the captures' stand-ins (3 x 0.05 s) and the handshake, not the steering

    def busy_as_long(request):
        time.sleep(1.2)
        return synthetic_result(request, 0)

    _, client2, _ = station(busy_as_long, cycle_timeout_s=0.4)
    rep = PlcSimulator(client2).run_cycle("JOB-000001", None, CASTER)
    assert rep.state == "fault" and rep.fault_code == 505


def test_a_cycle_abandoned_after_its_timeout_cannot_ask_for_a_steer(station):
    outcome = []

    def slow_runner(request):
        time.sleep(0.6)
        try:
            request.steer_operator(lambda r: SyntheticSteering(r, reading_s=0.01)).steer(10.0)
        except SteerNotReached as e:
            outcome.append(str(e))
            raise
        outcome.append("steered")
        return synthetic_result(request, 0)

    bg, client, _ = station(slow_runner, cycle_timeout_s=0.2, steer_timeout_s=5)
    assert not trigger(client, "JOB-000001").isError()
    assert wait_state(client, {FAULT})["fault_code"] == 505
    deadline = time.monotonic() + 3
    while not outcome and time.monotonic() < deadline:
        time.sleep(0.02)
    assert outcome and "not asked of the PLC" in outcome[0]
    b = block(client)
    assert b["state"] == FAULT and steer_status(b) == CLEARED_STEER and bg.device.stats["steers"] == 0


def test_stopping_the_server_lets_a_cycle_waiting_for_a_steer_go():
    ended = threading.Event()
    errors = []

    def runner(request):
        try:
            request.steer_operator(lambda r: SyntheticSteering(r, reading_s=0.05, reach=0.5)).steer(10.0)
        except SteerNotReached as e:
            errors.append(e)
            raise
        finally:
            ended.set()

    bg = BackgroundServer(PlcDevice(runner, steer_timeout_s=600))
    port = bg.start_tcp()
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    try:
        assert client.connect() and not trigger(client, "JOB-000001").isError()
        wait_state(client, {STEER})
    finally:
        client.close()
        t0 = time.monotonic()
        bg.stop()
    assert ended.wait(3) and time.monotonic() - t0 < 3
    assert errors and errors[0].code == 424


def test_the_plc_simulator_command_line_prints_the_steers_and_the_steering(capsys, station):
    _, _, port = station()
    rc = plc_sim_main(["--port", str(port), "--cycles", "2", "--caster", "--dry-run-check", "--first-job", "9"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "steering sweep (command 7)" in out.splitlines()[0]
    assert out.count("steer 1/3: 10 deg left; live FL/FR: ") == 2
    assert out.count("steer 2/3: 10 deg right") == 2 and out.count("steer 3/3: straight ahead") == 2
    assert "+10.4/+9.6" in out and "-9.6/-10.4" in out  # the live angle at the targets, the inner wheel more
    assert "fault 422" in out and out.count("steering: FL caster ") == 1
    assert "2 cycles, 0 with problems, 6 steers" in out.splitlines()[-1]
    with pytest.raises(SystemExit):  # one or the other
        plc_sim_main(["--port", str(port), "--caster", "--compensate"])


# --- a third-party client and the command -------------------------------------------------------
@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed (apt-get install mbpoll)")
def test_mbpoll_follows_a_steering_sweep(station):
    job = "WVWZZZ1KZAW000017"
    _, _, port = station(dry_run_runner(10, reading_s=0.1))
    target = ["-m", "tcp", "-p", str(port), "-a", "1"]
    assert mbpoll(target + ["-r", "1", "127.0.0.1"], *rm.ascii_to_regs(job, 16)).returncode == 0
    r = mbpoll(target + ["-r", "0", "127.0.0.1"], CASTER)
    assert r.returncode == 0 and "Written 1 references" in r.stdout, r.stdout + r.stderr
    prompts, live = [], {}
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        state = parse(mbpoll(target + ["-r", "100", "127.0.0.1"]).stdout).get(100)
        if state == str(STEER):
            s = parse(mbpoll(target + ["-r", "225", "-c", "7", "127.0.0.1"]).stdout)
            prompt = tuple(signed(s[a]) for a in (225, 226, 227))
            if prompt[0] and prompt not in prompts:
                prompts.append(prompt)
                r = mbpoll(target + ["-r", "0", "127.0.0.1"], ACK)  # not now
                assert r.returncode != 0 and "busy" in r.stderr.lower(), r.stderr
            if prompt[0] and s[228] != "32768":  # step 0: the steer ended between the two reads
                live.setdefault(prompt[0], set()).add(signed(s[228]))
        elif state == str(DONE):
            break
    assert prompts == [(1, 3, 1000), (2, 3, -1000), (3, 3, 0)]
    assert all(len(v) >= 2 for v in live.values()) and set(live) == {1, 2, 3}, live  # the live angle moved
    want = synthetic_result(CycleRequest("measure_caster", job, None, 0), fail_every=10)
    flag = parse(mbpoll(target + ["-r", "232", "127.0.0.1"]).stdout)
    floats = parse(mbpoll(target + ["-r", "233", "-c", "6", "-t", "4:float", "-B", "127.0.0.1"]).stdout)
    ints = parse(mbpoll(target + ["-r", "245", "-c", "12", "127.0.0.1"]).stdout)
    assert flag[232] == "1"
    for i, (w, key) in enumerate((w, k) for w in FRONT for k in ("caster", "sai", "included_angle")):
        value = getattr(want.steering.wheels[w], f"{key}_deg")
        assert float(floats[233 + 2 * i]) == pytest.approx(value, abs=2e-5), (w, key)
        assert signed(ints[245 + i]) == round(value * 100), (w, key)
    for i, w in enumerate(FRONT):
        assert signed(ints[255 + i]) == round(want.steering.wheels[w].kingpin_offset_m * 1000 * 100), w
    status = parse(mbpoll(target + ["-r", "100", "-c", "13", "127.0.0.1"]).stdout)
    assert status[104] == "1" and status[105] == str(CASTER) and status[106] == "501" and status[112] == str(rm.MAP_VERSION)
    assert mbpoll(target + ["-r", "0", "127.0.0.1"], ACK).returncode == 0


def test_station_serve_dry_run_sweeps_with_the_plc_simulator():
    port = free_port()
    with dry_run_serve(port, "--cycles", "2", "--steer-timeout-s", "30", "--cycle-timeout-s", "1",
                       "--log-level", "warning") as serve:
        rc = plc_sim_main(["--port", str(port), "--cycles", "2", "--caster", "--dry-run-check", "--quiet",
                           "--first-job", "11"])
        out, err = serve.communicate(timeout=30)
    assert rc == 0
    assert serve.returncode == 0, err
    # about 1 s of steering per steer against a 1 s cycle timeout: the steering is not the station's time
    assert "served 2 cycles (2 done, 0 fault)" in out and "Traceback" not in err
    assert "6 steers of the front wheels asked, 0 not reached in time" in out


def test_station_serve_refuses_a_bad_steer_timeout(capsys):
    from station.cli import main as cli_main

    assert cli_main(["serve", "--dry-run", "--steer-timeout-s", "0"]) == 2
    err = capsys.readouterr().err
    assert "--steer-timeout-s 0" in err and "Traceback" not in err


# --- the real station ---------------------------------------------------------------------------
@pytest.mark.slow
def test_a_real_steering_sweep_on_the_simulated_station_driven_by_the_plc(tmp_path, station):
    """The PLC triggers command 7 on a small simulated station (half resolution, single frames,
    about 30-60 s here); the simulated technician steers to each target and the station's guide
    follows the front rims live into the registers. Caster and SAI come back near the truth
    (half resolution, one frame: tenths of a degree; vehicle 5 here); a PLC reading the live registers sees the
    wheels at each target when the station goes on."""
    from station.plc.runner import measurement_runner
    from tests.station_fixtures import small_station_config, truth_calibration

    config = small_station_config(tmp_path, capture__frames_averaged=1, recording__enabled=False)
    truth_calibration(config)
    run = measurement_runner(config, seed=5)
    try:
        bg, client, _ = station(run, steer_timeout_s=300, cycle_timeout_s=600)
        rep = PlcSimulator(client, timeout_s=600, poll_s=0.02).run_cycle("JOB-000005", None, CASTER)
        assert rep.problems == [] and rep.state == "done", (rep.problems, rep.fault_code, rep.reason)
        result = bg.device.last_result
        b = block(client)
    finally:
        run.close()
    assert [(s.step, s.steps, s.target_deg) for s in rep.steers] == [(1, 3, 10.0), (2, 3, -10.0), (3, 3, 0.0)]
    assert bg.device.stats["steers"] == 3 and bg.device.stats["steer_timeouts"] == 0
    for s in rep.steers:
        seen = [r for r in s.readings if None not in r[:2]]
        assert seen, s.describe()
        fl, fr, _ = seen[-1]  # the last reading before the station went on: at the target
        assert abs((fl + fr) / 2 - s.target_deg) <= 1.05 and abs(fl - s.target_deg) < 2.5, s.describe()
    assert rep.steers[0].readings[-1][0] > 5 and rep.steers[1].readings[-1][0] < -5  # left, then right
    assert result.valid and result.steering is not None and rep.steering_valid == 1
    assert steer_status(b) == CLEARED_STEER and b["result_job_id"] == "JOB-000005"
    assert rep.measure_s < rep.total_s - sum(s.seconds for s in rep.steers) + 0.5
    truth = result.truth["wheels"]
    for w in FRONT:
        got, s = rep.steering[w], result.steering.wheels[w]
        assert got["caster"] == pytest.approx(s.caster_deg, abs=1e-5) and got["sai"] == pytest.approx(s.sai_deg, abs=1e-5)
        assert got["kingpin_offset_mm"] == pytest.approx(s.kingpin_offset_m * 1000, abs=1e-3)
        assert b[f"{w}_included_angle_i16"] == round(s.included_angle_deg * 100) / 100
        assert got["caster"] == pytest.approx(truth[w]["caster_deg"], abs=0.75), w  # measured -0.39, +0.30
        assert got["sai"] == pytest.approx(truth[w]["sai_deg"], abs=0.5), w  # measured -0.17, +0.06
