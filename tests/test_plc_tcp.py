"""The PLC server over real Modbus TCP on loopback: handshake, faults, refusals, disconnects,
atomic results, heartbeat, device ids, allow-list and the `station serve` command."""

import math
import random
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from station.plc.master import PlcSimulator, dry_run_expectation
from station.plc.master import main as plc_sim_main
from station.cli import main as cli_main
from station.errors import ImageError
from station.plc import register_map as rm
from station.plc.background import BackgroundServer
from station.plc.device import PlcDevice
from station.plc.runner import CycleRequest, dry_run_runner, synthetic_result
from station.result import Failure, Measurement
from tests.serve_process import dry_run_serve, free_port

ROOT = Path(__file__).resolve().parent.parent
IDLE, BUSY, DONE, FAULT = 0, 1, 2, 3


class GatedRunner:
    """Blocks every cycle until ``gate`` is set; records the requests."""

    def __init__(self):
        self.gate = threading.Event()
        self.calls: list[CycleRequest] = []

    def __call__(self, request):
        self.calls.append(request)
        assert self.gate.wait(10)
        return synthetic_result(request, fail_every=0)


@pytest.fixture
def station():
    """factory(runner=None, server_kw..., device_kw...) -> (background server, client, port)."""
    made = []

    def make(runner=None, *, allowed_clients=(), **device_kw):
        device_kw.setdefault("heartbeat_s", 0.02)
        device = PlcDevice(runner or dry_run_runner(10), **device_kw)
        bg = BackgroundServer(device, allowed_clients=allowed_clients)
        port = bg.start_tcp()
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        made.append((bg, client))
        assert client.connect()
        return bg, client, port

    yield make
    for bg, client in made:
        client.close()
        bg.stop()


def block(client, device_id=1):
    lo, hi = rm.RESULT_BLOCK
    r = client.read_holding_registers(lo, count=hi - lo, device_id=device_id)
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


def trigger(client, job, spec=None, command=1):
    return client.write_registers(0, [command] + rm.ascii_to_regs(job, 16) + rm.ascii_to_regs(spec, 16))


def test_cycles_through_the_handshake_match_the_dry_run(station):
    bg, client, _ = station()
    sim = PlcSimulator(client)
    expect = dry_run_expectation(10)
    reports = [sim.run_cycle(f"JOB-{i:06d}", "spec-a" if i % 2 else None, expect=expect) for i in range(1, 26)]
    assert [r.problems for r in reports] == [[]] * 25
    assert [r.state for r in reports].count("fault") == 2  # jobs 10 and 20 fail on purpose
    assert {r.fault_code for r in reports if r.state == "fault"} == {401}
    assert "no closed rim contour" in reports[9].reason
    s = bg.device.stats
    assert (s["started"], s["done"], s["fault"], s["acknowledged"], s["refused"]) == (25, 23, 2, 25, 0)
    assert block(client)["cycle_counter"] == 25


def test_writes_outside_the_plc_registers_get_exception_2_and_change_nothing(station):
    bg, client, _ = station()
    before = client.read_holding_registers(0, count=40).registers
    for address, values in ((100, [1]), (101, [7]), (120, [1, 2]), (33, [5]), (30, [1, 2, 3, 4, 5]),
                            (300, [1]), (65535, [1])):
        r = client.write_registers(address, values) if len(values) > 1 else client.write_register(address, values[0])
        assert r.isError() and r.exception_code == 2, (address, r)
    assert client.read_holding_registers(0, count=40).registers == before  # no partial write
    assert client.read_holding_registers(300, count=1).exception_code == 2
    assert client.read_holding_registers(200, count=101).exception_code == 2  # runs past the map
    assert client.read_coils(0, count=1).exception_code == 1  # no coils in this map
    assert client.write_coil(0, True).exception_code == 1
    assert client.read_input_registers(100, count=5).registers[0] == IDLE  # FC4 reads the same map
    b = block(client)
    assert (b["state"], b["reject_count"], b["map_version"]) == (IDLE, 0, rm.MAP_VERSION)


def test_unknown_command_value_gets_exception_3_and_reject_code(station):
    _, client, _ = station()
    r = client.write_register(0, 9)
    assert r.isError() and r.exception_code == 3
    b = block(client)
    assert (b["state"], b["reject_code"], b["reject_count"]) == (IDLE, 504, 1)
    assert client.write_register(0, 0).isError() is False  # 0 clears the mailbox: allowed
    assert PlcSimulator(client).run_cycle("JOB-000001").problems == []


def test_trigger_while_busy_is_refused_and_the_running_result_is_kept(station):
    runner = GatedRunner()
    bg, client, _ = station(runner)
    assert not trigger(client, "JOB-000001", "spec-a").isError()
    b = wait_state(client, {BUSY})
    assert b["result_valid"] == 0 and math.isnan(b["FL_toe_f32"]) and b["FL_toe_i16"] is None
    for command in (1, 2, 3, 4):
        r = trigger(client, "JOB-000002", command=command)
        assert r.isError() and r.exception_code == 6, command  # server device busy
    assert block(client)["reject_code"] == 501
    runner.gate.set()
    b = wait_state(client, {DONE})
    assert len(runner.calls) == 1  # not queued
    assert b["result_job_id"] == "JOB-000001" and b["reject_count"] == 4
    want = synthetic_result(CycleRequest("measure", "JOB-000001", "spec-a", 1), 0)
    assert b["RR_toe_f32"] == pytest.approx(want.wheels["RR"].toe_deg, abs=1e-6)
    r = trigger(client, "JOB-000003")  # done but not acknowledged: the result would be lost
    assert r.isError() and r.exception_code == 3 and block(client)["reject_code"] == 502
    assert block(client)["result_job_id"] == "JOB-000001"
    assert not client.write_register(0, 4).isError()
    assert block(client)["state"] == IDLE


def test_client_disconnecting_mid_handshake_loses_no_result(station):
    runner = GatedRunner()
    bg, client, port = station(runner)
    assert not trigger(client, "JOB-000042").isError()
    client.close()
    runner.gate.set()
    time.sleep(0.1)
    again = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    try:
        assert again.connect()
        b = wait_state(again, {DONE})
        assert b["result_job_id"] == "JOB-000042" and b["result_valid"] == 1
        assert not again.write_register(0, 4).isError()
        assert PlcSimulator(again).run_cycle("JOB-000043").problems == []
    finally:
        again.close()


def test_failed_cycles_set_code_and_reason_and_the_next_command_works(station):
    def runner(request):
        n = int(request.job_id[-1])
        if n == 1:
            raise ImageError("FL cam3: frame is all black")
        if n == 2:
            raise ValueError("bug in the pipeline")
        if n == 3:
            return Measurement(station="test", failure=Failure(401, "RR cam7: no closed rim contour"))
        if n == 4:
            bad = synthetic_result(request, 0)
            bad.thrust_deg = None
            return bad
        return synthetic_result(request, 0)

    bg, client, _ = station(runner)
    sim = PlcSimulator(client)
    want = {1: (402, "frame is all black"), 2: (1, "internal error: ValueError"), 3: (401, "no closed rim"),
            4: (400, "thrust_deg")}
    for n, (code, text) in want.items():
        assert not trigger(client, f"JOB-00000{n}").isError()
        b = wait_state(client, {DONE, FAULT})
        assert (b["state"], b["fault_code"], b["result_valid"]) == (FAULT, code, 0), n
        assert text in b["fault_reason"]
        assert not client.write_register(0, 3 if n % 2 else 4).isError()  # reset fault or acknowledge
        b = block(client)
        assert (b["state"], b["fault_code"], b["fault_reason"]) == (IDLE, 0, "")
        rep = sim.run_cycle("JOB-000005")  # the next command works
        assert rep.problems == [] and rep.state == "done"
    assert bg.device.stats["fault"] == 4


def test_calibration_check_reports_done_without_angles_or_a_calibration_fault(station):
    outcomes = iter([Measurement(station="test", valid=True),
                     Measurement(station="test", failure=Failure(301, "cam5 moved by 0.8 px"))])
    _, client, _ = station(lambda request: next(outcomes))
    assert not trigger(client, "", command=2).isError()
    b = wait_state(client, {DONE, FAULT})
    assert (b["state"], b["result_valid"], b["active_command"]) == (DONE, 1, 2)
    assert all(v is None for v in rm.angles_from_block(b, "f32").values())
    assert not client.write_register(0, 4).isError()
    assert not trigger(client, "", command=2).isError()
    b = wait_state(client, {DONE, FAULT})
    assert (b["state"], b["fault_code"], b["fault_reason"]) == (FAULT, 301, "cam5 moved by 0.8 px")


def test_cycle_timeout_faults_and_a_late_result_is_ignored(station):
    def slow(request):
        time.sleep(0.6)
        return synthetic_result(request, 0)

    bg, client, _ = station(slow, cycle_timeout_s=0.15)
    assert not trigger(client, "JOB-000001").isError()
    b = wait_state(client, {FAULT})
    assert b["fault_code"] == 505 and "timed out" in b["fault_reason"]
    assert not client.write_register(0, 4).isError()
    time.sleep(0.7)  # the late result arrives: it must not publish anything
    b = block(client)
    assert (b["state"], b["result_valid"], b["cycle_counter"]) == (IDLE, 0, 1)


def test_heartbeat_and_serving_continue_during_a_cycle(station):
    runner = GatedRunner()
    _, client, _ = station(runner)
    assert not trigger(client, "JOB-000001").isError()
    hb0 = wait_state(client, {BUSY})["heartbeat"]
    t0 = time.perf_counter()
    reads = 0
    while time.perf_counter() - t0 < 0.3:
        block(client)
        reads += 1
    hb1 = block(client)["heartbeat"]
    assert hb1 - hb0 >= 5, (hb0, hb1)  # 20 ms period, 300 ms busy
    assert reads > 20  # Modbus requests are answered while the measurement blocks
    runner.gate.set()
    wait_state(client, {DONE})


def test_results_are_never_visible_half_written(station):
    """A second client reads the whole block as fast as it can during 40 cycles: every read shows
    either no result or one complete result whose every register belongs to the same job."""
    bg, client, port = station(dry_run_runner(fail_every=7))
    stop = threading.Event()
    seen = {"reads": 0, "busy": 0, "bad": []}

    def hammer():
        reader = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        reader.connect()
        while not stop.is_set():
            b = block(reader)
            seen["reads"] += 1
            if b["state"] == BUSY:
                seen["busy"] += 1
                if b["result_valid"] or b["result_job_id"] or not math.isnan(b["thrust_f32"]):
                    seen["bad"].append(("busy with a result", b["result_job_id"]))
            elif b["result_valid"]:
                want = synthetic_result(CycleRequest("measure", b["result_job_id"], None, 0), 0)
                got = rm.angles_from_block(b, "f32")
                for name in rm.ANGLES:
                    w = want.angle(name)
                    if abs(got[name] - w) > 1e-5:
                        seen["bad"].append((b["result_job_id"], name, got[name], w))
        reader.close()

    t = threading.Thread(target=hammer)
    t.start()
    try:
        sim = PlcSimulator(client)
        reports = [sim.run_cycle(f"JOB-{i:06d}", expect=dry_run_expectation(7)) for i in range(1, 41)]
    finally:
        stop.set()
        t.join(10)
    assert [r.problems for r in reports] == [[]] * 40
    assert seen["bad"] == [] and seen["reads"] > 40


def test_unknown_device_id_gets_exception_0x0b_and_tcp_self_ids_answer(station):
    _, client, _ = station()
    r = client.read_holding_registers(100, count=1, device_id=7)
    assert r.isError() and r.exception_code == 0x0B
    r = client.write_register(0, 1, device_id=9)
    assert r.isError() and r.exception_code == 0x0B
    assert block(client)["state"] == IDLE  # the foreign write did nothing
    for device_id in (0, 255, 1):
        assert client.read_holding_registers(100, count=1, device_id=device_id).registers == [IDLE]


def test_allow_list_refuses_other_clients(station):
    bg, client, port = station(allowed_clients=["127.0.0.2", "10.0.0.0/8"])
    try:  # 127.0.0.1 is not allowed: disconnected at once
        refused = client.read_holding_registers(100, count=1).isError()
    except (ModbusException, OSError):
        refused = True
    assert refused
    assert bg.server.refused_clients >= 1
    allowed = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0, source_address=("127.0.0.2", 0))
    try:
        assert allowed.connect()
        assert PlcSimulator(allowed).run_cycle("JOB-000001").problems == []
    finally:
        allowed.close()


def test_garbage_on_a_tcp_connection_does_not_disturb_the_station(station):
    bg, client, port = station()
    rng = random.Random(3)
    junk = [bytes(rng.getrandbits(8) for _ in range(n)) for n in (1, 7, 300, 2000)]
    junk.append(bytes.fromhex("0001 0000 ffff 01 03 0064 0001"))  # MBAP length 65535
    junk.append(bytes.fromhex("0001 0001 0006 01 03 0064"))  # cut short, then closed
    for data in junk:
        with socket.create_connection(("127.0.0.1", port), timeout=2) as raw:
            raw.sendall(data)
            raw.settimeout(0.2)
            try:
                raw.recv(512)
            except (TimeoutError, ConnectionResetError):
                pass
    assert PlcSimulator(client).run_cycle("JOB-000001", expect=dry_run_expectation(10)).problems == []
    sock = next(iter(bg.server.server.active_connections.values())).transport.get_extra_info("socket")
    assert sock.getsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE) == 1


def test_bad_job_id_bytes_are_refused(station):
    _, client, _ = station()
    r = client.write_registers(0, [1, 0x4101] + [0] * 15)
    assert r.isError() and r.exception_code == 3
    b = block(client)
    assert (b["state"], b["reject_code"]) == (IDLE, 506)


def test_mailbox_reads_back_zero_and_job_registers_keep_the_text(station):
    runner = GatedRunner()
    _, client, _ = station(runner)
    assert not trigger(client, "VIN-ABC", "spec-b").isError()
    wait_state(client, {BUSY})
    regs = client.read_holding_registers(0, count=33).registers
    assert regs[0] == 0
    assert rm.regs_to_ascii(regs[1:17]) == "VIN-ABC" and rm.regs_to_ascii(regs[17:33]) == "spec-b"
    assert runner.calls[0].job_id == "VIN-ABC" and runner.calls[0].vehicle_spec == "spec-b"
    runner.gate.set()
    wait_state(client, {DONE})


def test_station_serve_command_with_the_plc_simulator():
    port = free_port()
    with dry_run_serve(port, "--cycles", "4", "--log-level", "warning") as serve:
        rc = plc_sim_main(["--port", str(port), "--cycles", "4", "--dry-run-check", "--first-job", "8",
                           "--spec", "x"])
        out, err = serve.communicate(timeout=20)
    assert rc == 0
    assert serve.returncode == 0, err
    assert "served 4 cycles (3 done, 1 fault)" in out  # job 10 fails on purpose


def test_station_serve_reports_bad_setups_without_traceback(capsys, tmp_path):
    base = (ROOT / "config" / "station.yaml").read_text()
    for change, message in ((("transport: tcp ", "transport: rtu "), "plc.serial_port is null"),
                            (("allowed_clients: []", "allowed_clients: [bogus]"), "'bogus' is not an IP")):
        assert change[0] in base
        cfg = tmp_path / "station.yaml"
        cfg.write_text(base.replace(*change))
        for name in ("box.yaml", "vehicles.yaml"):
            if (ROOT / "config" / name).exists():
                (tmp_path / name).write_text((ROOT / "config" / name).read_text())
        assert cli_main(["--config", str(cfg), "serve", "--dry-run"]) == 2
        assert message in capsys.readouterr().err
    assert cli_main(["serve", "--dry-run", "--rtu", "/nonexistent/tty"]) == 2
    err = capsys.readouterr().err
    assert "cannot open serial line /nonexistent/tty" in err and "Traceback" not in err
    assert cli_main(["serve", "--dry-run", "--device-id", "300"]) == 2
    assert "1..247" in capsys.readouterr().err
    with socket.socket() as busy:  # the port is taken
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        assert cli_main(["serve", "--dry-run", "--port", str(busy.getsockname()[1])]) == 2
    assert "cannot open tcp 127.0.0.1" in capsys.readouterr().err


def test_serve_on_an_uncalibrated_station_faults_the_cycle_and_keeps_serving(tmp_path):
    """A real `station serve` (no dry run) with no calibration file: the PLC's trigger ends in
    fault 300 with the reason, and the server keeps answering."""
    from tests.station_fixtures import small_station_config

    cfg = small_station_config(tmp_path)
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "station.cli", "--config", str(cfg.path), "serve",
                             "--port", str(port), "--cycles", "1"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        client = ModbusTcpClient("127.0.0.1", port=port)
        deadline = time.monotonic() + 30
        while not client.connect():
            assert time.monotonic() < deadline, "server did not start"
            time.sleep(0.2)
        client.write_register(rm.COMMAND, rm.COMMAND_CODES["measure"], device_id=1)
        deadline = time.monotonic() + 60
        while True:
            regs = client.read_holding_registers(rm.FIELDS["fault_code"].address, count=1, device_id=1).registers
            if regs[0]:
                break
            assert time.monotonic() < deadline, "no fault reported"
            time.sleep(0.1)
        assert regs[0] == 300
        assert client.read_holding_registers(rm.FIELDS["state"].address, count=1, device_id=1).registers[0] == rm.STATE_CODES["fault"]
        client.close()
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_refused_cycle_says_which_wheels_and_why_in_the_warning_registers(station):
    """A cycle refused for uncertain wheels (404) sets their warning_bits and, per wheel, the
    reason code in uncertain_reasons, so that a line can show what to do; the next cycle clears them."""
    from station.result import WarningFlag

    def runner(request):
        if request.job_id.endswith("1"):
            return Measurement(station="test", failure=Failure(404, "FL, RR less certain than the 0.06 deg limit",
                                                               "Shorten cam3's exposure.", "FL,RR"),
                               warning_flags=[WarningFlag("uncertain", "FL", reason="white_lip"),
                                              WarningFlag("uncertain", "RR", reason="uneven_edge"),
                                              WarningFlag("exposure", "FL", camera="cam3")])
        return synthetic_result(request, 0)

    _, client, _ = station(runner)
    assert not trigger(client, "JOB-000001").isError()
    b = wait_state(client, {DONE, FAULT})
    assert (b["state"], b["fault_code"], b["result_valid"]) == (FAULT, 404, 0)
    assert b["warning_bits"] == 1 << 0 | 1 << 3                                # FL and RR uncertain
    codes = rm.UNCERTAIN_REASON_CODES
    assert b["uncertain_reasons"] == codes["white_lip"] | codes["uneven_edge"] << 12
    assert b["station_warning_bits"] == 1 << rm.ANY_WARNING_BIT | 1 << 1     # any, and a lip at the white
    assert rm.uncertain_reasons_of(b["uncertain_reasons"]) == {"FL": "white_lip", "RR": "uneven_edge"}
    assert not client.write_register(0, 3).isError()                          # reset the fault
    assert not trigger(client, "JOB-000002").isError()
    b = wait_state(client, {DONE, FAULT})
    assert (b["state"], b["warning_bits"] & 0xF, b["uncertain_reasons"]) == (DONE, 0, 0)


def test_every_uncertain_reason_has_a_plc_code():
    from station.stated_uncertainty import UNCERTAIN_REASONS

    assert set(rm.UNCERTAIN_REASON_CODES) == set(UNCERTAIN_REASONS)
    assert sorted(rm.UNCERTAIN_REASON_CODES.values()) == list(range(1, len(UNCERTAIN_REASONS) + 1))
    assert max(rm.UNCERTAIN_REASON_CODES.values()) < 1 << rm.UNCERTAIN_REASON_BITS
