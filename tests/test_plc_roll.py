"""Runout compensation over the PLC (issue 32, map version 5): command 5 measures with the car
rolled between the captures; the station asks for each roll in state 4 (roll) with the prompt in
115..118, the PLC confirms with command 6. The table, the registers, the roll timeout, the PLC
simulator, mbpoll and `station serve` driving dry-run cycles, and one real compensated cycle on
a small simulated station whose car the PLC's simulated conveyor moves."""

from __future__ import annotations

import math
import shutil
import threading
import time

import pytest
from pymodbus.client import ModbusTcpClient

from station.errors import MeasurementError, PlcError, RollNotConfirmed
from station.plc import register_map as rm
from station.plc.background import BackgroundServer
from station.plc.device import PlcDevice
from station.plc.handshake import (PLC_EVENTS, REFUSALS, TRANSITIONS, Event, State, event_for_command,
                                   modbus_exception, next_state)
from station.plc.master import PlcSimulator, dry_run_expectation
from station.plc.master import main as plc_sim_main
from station.plc.results import cleared_registers, result_registers, roll_prompt_registers
from station.plc.roll_operator import PlcRollOperator, RollPrompt, roll_plan
from station.plc.runner import CycleRequest, dry_run_runner, synthetic_result
from tests.mbpoll_cli import mbpoll, parse, signed
from tests.serve_process import dry_run_serve, free_port

IDLE, BUSY, DONE, FAULT, ROLL = 0, 1, 2, 3, 4
MEASURE, ACK, COMPENSATED, IN_POSITION = 1, 4, 5, 6
WHEELS = ("FL", "FR", "RL", "RR")
PLAN_MM = [-150, 75, 150, 75, -150]  # station/procedures/runout.py: ROLL_PLAN (0, -1, -0.5, 0.5, 1, 0) x 0.15 m
POSITIONS_MM = [-150, -75, 75, 150, 0]
ROLLS = len(PLAN_MM)


# --- the table ----------------------------------------------------------------------------------
def test_the_plan_the_prompts_announce_is_the_procedures():
    assert [round(d * 1000) for d in roll_plan()] == PLAN_MM
    assert [round(d * 1000) for d in roll_plan(0.1)] == [-100, 50, 100, 50, -100]


def test_compensated_measure_and_in_position_are_the_next_free_commands_and_roll_the_next_state():
    assert event_for_command(5) is Event.MEASURE_COMPENSATED and event_for_command(6) is Event.IN_POSITION
    assert rm.COMMANDS[5] == "measure_compensated" and rm.COMMANDS[6] == "in_position"
    assert rm.STATES[4] == "roll" and State(4) is State.ROLL
    assert rm.MAP_VERSION >= 5  # 6 added the steering sweep (tests/test_plc_steer.py)


def test_roll_state_moves():
    assert next_state(State.IDLE, Event.MEASURE_COMPENSATED) is State.BUSY
    assert next_state(State.BUSY, Event.ROLL_REQUEST) is State.ROLL
    assert next_state(State.ROLL, Event.IN_POSITION) is State.BUSY
    assert next_state(State.ROLL, Event.ROLL_TIMEOUT) is State.BUSY  # then the cycle faults 415
    assert next_state(State.ROLL, Event.CYCLE_FAILED) is State.FAULT


@pytest.mark.parametrize("event", [e for e in PLC_EVENTS if e is not Event.IN_POSITION])
def test_in_roll_every_other_command_is_refused_as_busy(event):
    with pytest.raises(PlcError) as info:
        next_state(State.ROLL, event)
    assert info.value.code == 501 and modbus_exception(info.value) == 6
    assert "waits for the car to be rolled" in str(info.value)


@pytest.mark.parametrize("state", [State.IDLE, State.BUSY, State.DONE, State.FAULT])
def test_in_position_without_a_roll_prompt_is_refused_with_508(state):
    with pytest.raises(PlcError) as info:
        next_state(state, Event.IN_POSITION)
    assert info.value.code == 508 and modbus_exception(info.value) == 3
    assert state.name.lower() in str(info.value)


def test_the_table_is_complete_and_the_station_events_outside_their_state_are_internal():
    for s in State:
        for e in Event:
            assert ((s, e) in TRANSITIONS) != ((s, e) in REFUSALS), (s, e)
    for s in (State.IDLE, State.DONE, State.FAULT, State.ROLL):  # an abandoned cycle asking for a roll
        assert REFUSALS[(s, Event.ROLL_REQUEST)][0].code == 507
    for s in (State.IDLE, State.BUSY, State.DONE, State.FAULT):  # a timer after the answer
        assert REFUSALS[(s, Event.ROLL_TIMEOUT)][0].code == 507
    assert REFUSALS[(State.ROLL, Event.CYCLE_OK)][0].code == 507


# --- the registers ------------------------------------------------------------------------------
V4_ADDRESSES = {"command": 0, "job_id": 1, "vehicle_spec": 17, "state": 100, "fault_code": 101, "heartbeat": 102,
                "cycle_counter": 103, "result_valid": 104, "active_command": 105, "reject_code": 106,
                "reject_count": 107, "pass_bits": 108, "judged_bits": 109, "cycle_time_us": 110,
                "map_version": 112, "warning_bits": 113, "station_warning_bits": 114, "FL_toe_f32": 120,
                "thrust_f32": 140, "FL_toe_i16": 142, "thrust_i16": 152, "result_job_id": 160,
                "fault_reason": 176}


def test_map_version_5_moves_nothing_and_still_fits_one_read():
    for name, address in V4_ADDRESSES.items():
        assert rm.FIELDS[name].address == address, name
    assert rm.RESULT_BLOCK == (100, 225) and rm.RESULT_BLOCK[1] - rm.RESULT_BLOCK[0] == 125
    later = {"uncertain_reasons"}  # map version 8's, in the status registers' last free one
    new = {f.name: f.address for f in rm.STATION_FIELDS
           if (208 <= f.address < 225 or 115 <= f.address < 120) and f.name not in later}
    assert {a for a in new.values()} == {115, 116, 117, 118, 208, *range(209, 217, 2), *range(217, 225)}
    assert all(f.end <= 120 for f in rm.STATION_FIELDS if f.name.startswith("roll_"))  # polled with the status
    assert rm.FIELDS["uncertain_reasons"].address == 119 and rm.STATUS_END == 120


def test_the_roll_prompt_is_signed_millimetres():
    regs = roll_prompt_registers(2, 3, -150, -150)
    assert regs[117] == [0xFF6A] and regs[118] == [0xFF6A] and regs[115] == [2] and regs[116] == [3]
    block = [0] * 20
    for address, values in roll_prompt_registers(3, 3, 300, 150).items():
        block[address - 100] = values[0]
    decoded = rm.decode_block(block, 100)
    assert (decoded["roll_step"], decoded["roll_steps"], decoded["roll_distance_mm"], decoded["roll_position_mm"]) \
        == (3, 3, 300, 150)
    assert all(v == [0] for v in roll_prompt_registers().values())
    assert RollPrompt(1, 3, -0.15, -0.15).describe() == "roll 1/3: back 150 mm (to -150 mm)"
    assert RollPrompt(3, 3, -0.15, 0.0).describe() == "roll 3/3: back 150 mm (to the start)"


def _decoded(values: dict[int, list[int]]) -> dict:
    regs = [0] * (rm.RESULT_BLOCK[1] - rm.RESULT_BLOCK[0])
    for address, v in values.items():
        regs[address - rm.RESULT_BLOCK[0]:address - rm.RESULT_BLOCK[0] + len(v)] = v
    return rm.decode_block(regs)


def test_a_compensated_result_writes_its_runout_and_says_so():
    result = synthetic_result(CycleRequest("measure_compensated", "JOB-000007", None, 1))
    assert result.runout_compensated
    b = _decoded(result_registers(result, "JOB-000007"))
    assert b["runout_compensated"] == 1
    for w in WHEELS:
        deg, mm = result.wheels[w].runout_deg, result.wheels[w].runout_mm
        assert 0 <= deg <= 0.3 and mm == pytest.approx(432 * math.tan(math.radians(deg)), abs=2e-3)
        assert b[f"{w}_runout_f32"] == pytest.approx(deg, abs=1e-6)
        assert b[f"{w}_runout_i16"] == pytest.approx(round(deg * 100) / 100, abs=1e-9)
        assert b[f"{w}_runout_mm_i16"] == pytest.approx(round(mm * 100) / 100, abs=1e-9)
    raw = result_registers(result, "JOB-000007")
    assert raw[rm.FIELDS["FL_runout_mm_i16"].address] == [round(result.wheels["FL"].runout_mm * 100)]


def test_a_result_without_compensation_reads_rim_planes_and_no_runout():
    for b in (_decoded(result_registers(synthetic_result(CycleRequest("measure", "JOB-000007", None, 1)), "J")),
              _decoded(cleared_registers())):
        assert b["runout_compensated"] == 0
        for w in WHEELS:
            assert math.isnan(b[f"{w}_runout_f32"]) and b[f"{w}_runout_i16"] is None and b[f"{w}_runout_mm_i16"] is None


def test_a_compensated_result_without_a_wheels_runout_is_malformed():
    result = synthetic_result(CycleRequest("measure_compensated", "JOB-000007", None, 1))
    result.wheels["RL"].runout_mm = None
    with pytest.raises(MeasurementError, match="wheels.RL.runout_mm"):
        result_registers(result, "JOB-000007")
    result.wheels["RL"].runout_mm, result.wheels["FR"].runout_deg = 1.0, math.inf
    with pytest.raises(MeasurementError, match="wheels.FR.runout_deg"):
        result_registers(result, "JOB-000007")


def test_the_dry_run_fails_a_compensated_job_on_purpose_as_a_slipped_wheel():
    from station.errors import WheelSlipped

    with pytest.raises(WheelSlipped) as info:
        synthetic_result(CycleRequest("measure_compensated", "JOB-000020", None, 1), fail_every=10)
    assert info.value.code == 412


# --- the operator -------------------------------------------------------------------------------
class RecordingGate:
    def __init__(self):
        self.prompts = []

    def roll(self, prompt):
        self.prompts.append(prompt)


class RecordingSimulation:
    def __init__(self):
        self.rolled = []

    def roll_car(self, d):
        self.rolled.append(d)


def test_the_operator_numbers_the_rolls_adds_up_the_position_and_moves_the_simulated_car():
    gate, sim = RecordingGate(), RecordingSimulation()
    op = PlcRollOperator(gate, ROLLS, sim)
    for d in roll_plan():
        op.roll_car(d)
    assert [(p.step, p.steps, p.distance_mm, p.position_mm) for p in gate.prompts] == \
        [(k + 1, ROLLS, d, x) for k, (d, x) in enumerate(zip(PLAN_MM, POSITIONS_MM))]
    assert sim.rolled == pytest.approx([d / 1000 for d in PLAN_MM])


def test_the_simulated_car_is_not_moved_when_the_plc_does_not_confirm():
    class Refusing:
        def roll(self, prompt):
            raise RollNotConfirmed("no")

    sim = RecordingSimulation()
    with pytest.raises(RollNotConfirmed):
        PlcRollOperator(Refusing(), 3, sim).roll_car(-0.15)
    assert sim.rolled == []
    with pytest.raises(PlcError, match="no roll gate"):
        CycleRequest("measure_compensated", "J", None, 1).roll_operator()


# --- over Modbus TCP ----------------------------------------------------------------------------
@pytest.fixture
def station():
    """factory(runner=None, **device_kw) -> (background server, client, port)."""
    made = []

    def make(runner=None, **device_kw):
        device_kw.setdefault("heartbeat_s", 0.02)
        bg = BackgroundServer(PlcDevice(runner or dry_run_runner(10), **device_kw))
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
    lo, hi = rm.RESULT_BLOCK
    r = client.read_holding_registers(lo, count=hi - lo)
    assert not r.isError(), r
    return rm.decode_block(r.registers, lo)


def wait_state(client, states, timeout=5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        b = block(client)
        if b["state"] in states:
            return b
        time.sleep(0.005)
    raise AssertionError(f"state {b['state']} never reached {states}")


def wait_roll(client, step, timeout=5.0):
    """The status once the station asks for roll ``step``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        b = block(client)
        if b["state"] == ROLL and b["roll_step"] == step:
            return b
        assert b["state"] in (BUSY, ROLL), b["state"]
        time.sleep(0.005)
    raise AssertionError(f"roll {step} never asked for")


def trigger(client, job, command=COMPENSATED):
    return client.write_registers(0, [command] + rm.ascii_to_regs(job, 16) + [0] * 16)


def test_compensated_dry_run_cycles_through_the_roll_handshake_with_the_plc_simulator(station):
    bg, client, _ = station()
    seen = []
    sim = PlcSimulator(client, conveyor_s=0.01, on_roll=seen.append)
    expect = dry_run_expectation(10)
    reports = [sim.run_cycle(f"JOB-{i:06d}", None, COMPENSATED, expect=expect) for i in range(8, 13)]
    assert [r.problems for r in reports] == [[]] * 5
    assert [r.state for r in reports] == ["done", "done", "fault", "done", "done"]
    assert reports[2].fault_code == 412  # job 10 fails on purpose, after its rolls
    for r in reports:
        assert [s.distance_mm for s in r.rolls] == PLAN_MM
        assert [s.position_mm for s in r.rolls] == POSITIONS_MM
    assert reports[0].compensated == 1 and all(reports[0].runout[w][0] is not None for w in WHEELS)
    assert len(seen) == 5 * ROLLS and bg.device.stats["rolls"] == 5 * ROLLS
    # an ordinary cycle on the same station: no rolls, rim planes, no runout
    plain = sim.run_cycle("JOB-000013", None, MEASURE, expect=expect)
    assert plain.problems == [] and plain.rolls == [] and plain.compensated == 0


def test_in_roll_only_in_position_is_taken(station):
    bg, client, _ = station()
    assert not trigger(client, "JOB-000001").isError()
    b = wait_state(client, {ROLL})
    assert (b["active_command"], b["roll_step"], b["roll_steps"], b["roll_distance_mm"], b["roll_position_mm"]) \
        == (COMPENSATED, 1, ROLLS, -150, -150)
    assert b["result_valid"] == 0
    refused = 0
    for command in (MEASURE, 2, 3, ACK, COMPENSATED):
        r = client.write_register(0, command) if command != COMPENSATED else trigger(client, "JOB-000002")
        assert r.isError() and r.exception_code == 6, (command, r)
        refused += 1
        b = block(client)
        assert (b["state"], b["reject_code"], b["reject_count"], b["roll_step"]) == (ROLL, 501, refused, 1)
    for step, distance, position in zip(range(2, ROLLS + 1), PLAN_MM[1:], POSITIONS_MM[1:]):
        assert not client.write_register(0, IN_POSITION).isError()
        b = wait_roll(client, step)
        assert (b["roll_steps"], b["roll_distance_mm"], b["roll_position_mm"]) == (ROLLS, distance, position)
    assert not client.write_register(0, IN_POSITION).isError()
    b = wait_state(client, {DONE})
    assert (b["roll_step"], b["roll_steps"], b["roll_distance_mm"], b["roll_position_mm"]) == (0, 0, 0, 0)
    assert b["runout_compensated"] == 1 and b["result_job_id"] == "JOB-000001"
    r = client.write_register(0, IN_POSITION)  # a 6 written once too often
    assert r.isError() and r.exception_code == 3 and block(client)["reject_code"] == 508
    assert not client.write_register(0, ACK).isError()
    assert bg.device.stats["done"] == 1 and bg.device.stats["refused"] == 6


def test_a_roll_not_confirmed_in_time_faults_415_and_the_station_goes_on(station):
    bg, client, _ = station(roll_timeout_s=0.4)
    assert not trigger(client, "JOB-000001").isError()
    b = wait_state(client, {ROLL})
    assert b["roll_step"] == 1
    t0 = time.monotonic()
    b = wait_state(client, {FAULT}, timeout=5)
    assert 0.2 < time.monotonic() - t0 < 3
    assert b["fault_code"] == 415 and b["fault_reason"] == f"roll 1/{ROLLS} not confirmed by the PLC within 0.4 s"
    assert (b["roll_step"], b["roll_distance_mm"], b["result_valid"]) == (0, 0, 0)
    r = client.write_register(0, IN_POSITION)  # too late
    assert r.isError() and block(client)["reject_code"] == 508
    assert bg.device.stats["roll_timeouts"] == 1
    assert not client.write_register(0, ACK).isError()
    rep = PlcSimulator(client).run_cycle("JOB-000002", None, COMPENSATED, expect=dry_run_expectation(10))
    assert rep.problems == [] and rep.state == "done" and len(rep.rolls) == ROLLS


def test_the_time_in_roll_is_the_plcs_not_the_cycle_timeouts(station):
    """Five rolls of 0.3 s against a cycle timeout of 0.5 s: the cycle is done, not 505, and its
    cycle_time_us leaves the rolls out."""
    bg, client, _ = station(cycle_timeout_s=0.5, roll_timeout_s=5)
    rep = PlcSimulator(client, conveyor_s=0.3).run_cycle("JOB-000001", None, COMPENSATED)
    assert rep.problems == [] and rep.state == "done", rep
    assert rep.measure_s < 0.5 and rep.total_s > 0.9


def test_a_cycle_abandoned_after_its_timeout_cannot_ask_for_a_roll(station):
    """The cycle timeout faults a cycle whose thread goes on; when that thread later asks for a
    roll it is refused at once (it must not take the next cycle's place or hang)."""
    outcome = []

    def slow_runner(request):
        time.sleep(0.6)
        try:
            request.roll_operator().roll_car(-0.15)
        except RollNotConfirmed as e:
            outcome.append(str(e))
            raise
        outcome.append("rolled")
        return synthetic_result(request, 0)

    bg, client, _ = station(slow_runner, cycle_timeout_s=0.2, roll_timeout_s=5)
    assert not trigger(client, "JOB-000001").isError()
    b = wait_state(client, {FAULT})
    assert b["fault_code"] == 505
    deadline = time.monotonic() + 3
    while not outcome and time.monotonic() < deadline:
        time.sleep(0.02)
    assert outcome and "not asked of the PLC" in outcome[0]
    assert block(client)["state"] == FAULT and bg.device.stats["rolls"] == 0


def test_stopping_the_server_lets_a_cycle_waiting_for_a_roll_go():
    ended = threading.Event()
    errors = []

    def runner(request):
        try:
            request.roll_operator().roll_car(-0.15)
        except RollNotConfirmed as e:
            errors.append(e)
            raise
        finally:
            ended.set()

    bg = BackgroundServer(PlcDevice(runner, roll_timeout_s=600))
    port = bg.start_tcp()
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    try:
        assert client.connect() and not trigger(client, "JOB-000001").isError()
        wait_state(client, {ROLL})
    finally:
        client.close()
        t0 = time.monotonic()
        bg.stop()
    assert ended.wait(3) and time.monotonic() - t0 < 3
    assert errors and errors[0].code == 415


def test_the_plc_simulator_command_line_rolls_and_reports_each_step(capsys, station):
    _, _, port = station()
    rc = plc_sim_main(["--port", str(port), "--cycles", "2", "--compensate", "--dry-run-check", "--first-job", "9",
                       "--conveyor-s", "0.01"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "runout compensation (command 5)" in out.splitlines()[0]
    assert out.count("roll 1/5: back 150 mm (to -150 mm)") == 2
    assert out.count("roll 2/5: forward 75 mm (to -75 mm)") == 2
    assert out.count("roll 4/5: forward 75 mm (to +150 mm)") == 2
    assert out.count("roll 5/5: back 150 mm (to the start)") == 2
    assert "fault 412" in out and "runout compensated: FL " in out
    assert "2 cycles, 0 with problems, 10 rolls of the car" in out.splitlines()[-1]
    with pytest.raises(SystemExit):  # argparse: a clear message, exit status 2
        plc_sim_main(["--port", str(port), "--compensate", "--conveyor-s", "-1"])


# --- a third-party client and the command -------------------------------------------------------
@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed (apt-get install mbpoll)")
def test_mbpoll_drives_a_compensated_cycle(station):
    job = "WVWZZZ1KZAW000017"
    _, _, port = station()
    target = ["-m", "tcp", "-p", str(port), "-a", "1"]
    assert mbpoll(target + ["-r", "1", "127.0.0.1"], *rm.ascii_to_regs(job, 16)).returncode == 0
    r = mbpoll(target + ["-r", "0", "127.0.0.1"], COMPENSATED)
    assert r.returncode == 0 and "Written 1 references" in r.stdout, r.stdout + r.stderr
    prompts = []
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        status = parse(mbpoll(target + ["-r", "100", "-c", "19", "127.0.0.1"]).stdout)
        if status.get(100) == str(ROLL):
            prompts.append(tuple(signed(status[a]) for a in (115, 116, 117, 118)))
            r = mbpoll(target + ["-r", "0", "127.0.0.1"], ACK)  # not now
            assert r.returncode != 0 and "busy" in r.stderr.lower(), r.stderr
            assert mbpoll(target + ["-r", "0", "127.0.0.1"], IN_POSITION).returncode == 0
        elif status.get(100) == str(DONE):
            break
        time.sleep(0.02)
    assert prompts == [(k + 1, ROLLS, d, x) for k, (d, x) in enumerate(zip(PLAN_MM, POSITIONS_MM))]
    assert status[104] == "1" and status[105] == str(COMPENSATED) and status[106] == "501"
    want = synthetic_result(CycleRequest("measure_compensated", job, None, 0), fail_every=10)
    flag = parse(mbpoll(target + ["-r", "208", "127.0.0.1"]).stdout)
    floats = parse(mbpoll(target + ["-r", "209", "-c", "4", "-t", "4:float", "-B", "127.0.0.1"]).stdout)
    ints = parse(mbpoll(target + ["-r", "217", "-c", "8", "127.0.0.1"]).stdout)
    assert flag[208] == "1"
    for i, w in enumerate(WHEELS):
        assert float(floats[209 + 2 * i]) == pytest.approx(want.wheels[w].runout_deg, abs=2e-6), w
        assert signed(ints[217 + i]) == round(want.wheels[w].runout_deg * 100), w
        assert signed(ints[221 + i]) == round(want.wheels[w].runout_mm * 100), w
    angles = parse(mbpoll(target + ["-r", "120", "-c", "2", "-t", "4:float", "-B", "127.0.0.1"]).stdout)
    assert float(angles[120]) == pytest.approx(want.wheels["FL"].toe_deg, abs=2e-6)
    r = mbpoll(target + ["-r", "0", "127.0.0.1"], IN_POSITION)  # no roll asked for now
    assert r.returncode != 0 and "Illegal data value" in r.stderr
    assert mbpoll(target + ["-r", "0", "127.0.0.1"], ACK).returncode == 0
    assert parse(mbpoll(target + ["-r", "100", "127.0.0.1"]).stdout)[100] == str(IDLE)


def test_station_serve_dry_run_rolls_with_the_plc_simulator_and_times_out_a_roll():
    port = free_port()
    with dry_run_serve(port, "--cycles", "3", "--roll-timeout-s", "0.5", "--log-level", "warning") as serve:
        rc = plc_sim_main(["--port", str(port), "--cycles", "2", "--compensate", "--dry-run-check", "--quiet",
                           "--conveyor-s", "0.05"])
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        assert client.connect()
        try:  # a PLC that never confirms: fault 415 after 0.5 s
            assert not trigger(client, "JOB-000003").isError()
            b = wait_state(client, {FAULT}, timeout=10)
            assert b["fault_code"] == 415 and "not confirmed by the PLC within 0.5 s" in b["fault_reason"]
            assert not client.write_register(0, ACK).isError()
        finally:
            client.close()
        out, err = serve.communicate(timeout=20)
    assert rc == 0
    assert serve.returncode == 0, err
    assert "served 3 cycles (2 done, 1 fault)" in out and "Traceback" not in err
    assert "11 rolls of the car asked of the PLC, 1 not confirmed in time" in out


def test_station_serve_refuses_a_bad_roll_timeout(capsys):
    from station.cli import main as cli_main

    assert cli_main(["serve", "--dry-run", "--roll-timeout-s", "0"]) == 2
    err = capsys.readouterr().err
    assert "--roll-timeout-s 0" in err and "Traceback" not in err


# --- the real station ---------------------------------------------------------------------------
@pytest.mark.slow
def test_a_real_compensated_cycle_on_the_simulated_station_driven_by_the_plc(tmp_path, station):
    """The PLC triggers command 5 on a small simulated station (half resolution, single frames,
    about 15 s here); the PLC simulator confirms each roll and the station's simulated conveyor
    moves the car. Had the car not moved, the procedure would refuse the cycle (411, a roll too
    short): a valid compensated result shows it rolled, back where it started at the last capture."""
    from station.plc.runner import measurement_runner
    from tests.station_fixtures import small_station_config, truth_calibration

    config = small_station_config(tmp_path, capture__frames_averaged=1, recording__enabled=False)
    truth_calibration(config)
    run = measurement_runner(config)
    try:
        bg, client, _ = station(run, roll_timeout_s=300, cycle_timeout_s=600)
        rep = PlcSimulator(client, timeout_s=600, poll_s=0.05).run_cycle("JOB-000005", None, COMPENSATED)
        assert rep.problems == [] and rep.state == "done", (rep.problems, rep.fault_code, rep.reason)
        assert [s.distance_mm for s in rep.rolls] == PLAN_MM
        result = bg.device.last_result
    finally:
        run.close()
    assert result.valid and result.runout_compensated and rep.compensated == 1
    assert result.truth is not None and result.truth["wheels"]["FL"].get("runout_deg") is not None
    for w in WHEELS:
        deg, mm = rep.runout[w]
        assert deg == pytest.approx(result.wheels[w].runout_deg, abs=1e-6) and 0 <= deg < 0.6, w
        assert mm == pytest.approx(round(result.wheels[w].runout_mm * 100) / 100, abs=1e-9), w
        assert deg == pytest.approx(result.truth["wheels"][w]["runout_deg"], abs=0.2), w  # half resolution, one frame
        assert rep.angles[f"{w}.toe"] == pytest.approx(result.truth["wheels"][w]["toe_deg"], abs=0.3), w
