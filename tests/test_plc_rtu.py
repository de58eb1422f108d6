"""The PLC server as Modbus RTU over a real serial line: a pseudo-terminal pair made by socat.
Same map and handshake as TCP; plus what only a serial line has: garbage, broken frames,
other devices' requests on the shared line (no answer), and the same tests through the CLI."""

import os
import random
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusException

from station.plc.master import PlcSimulator, dry_run_expectation
from station.plc import register_map as rm
from station.plc.background import BackgroundServer
from station.plc.device import PlcDevice
from station.plc.runner import dry_run_runner

pytestmark = pytest.mark.skipif(shutil.which("socat") is None, reason="socat is not installed (apt-get install socat)")


def crc16(frame: bytes) -> bytes:
    """Modbus RTU CRC (poly 0xA001, init 0xFFFF), low byte first - written here independently."""
    crc = 0xFFFF
    for b in frame:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


def read_request(device_id: int, address: int, count: int) -> bytes:
    body = bytes([device_id, 3, address >> 8, address & 0xFF, count >> 8, count & 0xFF])
    return body + crc16(body)


@pytest.fixture
def pty_pair(tmp_path):
    a, b = tmp_path / "station", tmp_path / "plc"
    proc = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 5
    while not (a.exists() and b.exists()):
        assert time.monotonic() < deadline, "socat made no pty pair"
        time.sleep(0.01)
    yield str(a), str(b)
    proc.terminate()
    proc.wait(5)


@pytest.fixture
def rtu(pty_pair):
    station_side, plc_side = pty_pair
    device = PlcDevice(dry_run_runner(10), device_id=3, heartbeat_s=0.02)
    bg = BackgroundServer(device, rtu_gap_s=0.03)
    bg.start_rtu(station_side, baudrate=19200, parity="N")  # a pty takes no parity
    client = ModbusSerialClient(plc_side, baudrate=19200, parity="N", timeout=0.5, retries=0)
    assert client.connect()
    yield bg, client, plc_side
    client.close()
    bg.stop()


def state(client, device_id=3):
    r = client.read_holding_registers(100, count=1, device_id=device_id)
    assert not r.isError(), r
    return r.registers[0]


def test_cycles_over_rtu_match_the_dry_run(rtu):
    bg, client, _ = rtu
    sim = PlcSimulator(client, device_id=3)
    reports = [sim.run_cycle(f"JOB-{i:06d}", "spec-a", expect=dry_run_expectation(10)) for i in range(5, 13)]
    assert [r.problems for r in reports] == [[]] * 8
    assert [r.state for r in reports].count("fault") == 1 and reports[5].fault_code == 401
    assert bg.device.stats["acknowledged"] == 8


def test_read_only_and_unknown_command_over_rtu(rtu):
    _, client, _ = rtu
    assert client.write_register(104, 1, device_id=3).exception_code == 2
    assert client.write_register(0, 77, device_id=3).exception_code == 3
    assert state(client) == 0


def test_other_device_ids_get_no_answer_on_the_shared_line(rtu):
    bg, client, _ = rtu
    for device_id in (1, 7, 247):
        with pytest.raises(ModbusException):
            r = client.read_holding_registers(100, count=1, device_id=device_id)
            if r.isError():  # pymodbus may return an error object instead of raising
                raise ModbusException(str(r))
    assert bg.server.unknown_ids == 3
    assert state(client) == 0  # and our own id still answers at once


def test_garbage_and_broken_frames_are_survived(rtu):
    bg, client, plc_side = rtu
    rng = random.Random(5)
    fd = os.open(plc_side, os.O_WRONLY | os.O_NOCTTY)
    try:
        good = read_request(3, 100, 1)
        bad_crc = good[:-1] + bytes([good[-1] ^ 0xFF])
        noise = [bytes(rng.getrandbits(8) for _ in range(n)) for n in (1, 7, 40, 600)]
        cases = noise + [bad_crc, good[:5], b"\x03\x10\x00\x00\x00\x01", read_request(3, 100, 1)[:-2]]
        for junk in cases:
            os.write(fd, junk)
            time.sleep(0.06)  # silence longer than the RTU gap: the line is idle again
            # the very next request is answered first time (retries=0): nothing stuck in the buffer
            assert state(client) == 0, junk
    finally:
        os.close(fd)
    time.sleep(0.05)
    sim = PlcSimulator(client, device_id=3)
    assert sim.run_cycle("JOB-000001", expect=dry_run_expectation(10)).problems == []


def test_plc_closing_the_line_mid_handshake_loses_no_result(rtu, pty_pair):
    bg, client, plc_side = rtu
    regs = [1] + rm.ascii_to_regs("JOB-000021", 16)
    assert not client.write_registers(0, regs, device_id=3).isError()
    client.close()
    time.sleep(0.2)
    again = ModbusSerialClient(plc_side, baudrate=19200, parity="N", timeout=0.5, retries=0)
    try:
        assert again.connect()
        b = rm.decode_block(again.read_holding_registers(100, count=108, device_id=3).registers)
        assert (b["state"], b["result_job_id"], b["result_valid"]) == (2, "JOB-000021", 1)
        assert not again.write_register(0, 4, device_id=3).isError()
        assert PlcSimulator(again, device_id=3).run_cycle("JOB-000022").problems == []
    finally:
        again.close()


def test_station_serve_rtu_with_the_plc_simulator(pty_pair):
    station_side, plc_side = pty_pair
    root = Path(__file__).resolve().parent.parent
    py = sys.executable
    serve = subprocess.Popen([py, "-m", "station.cli", "serve", "--dry-run", "--rtu", station_side, "--parity",
                              "N", "--cycles", "3", "--log-level", "warning"],
                             cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = serve.stdout.readline()
        assert "Modbus RTU" in line, line + serve.stderr.read()
        sim = subprocess.run([py, "-m", "station.plc.master", "--rtu", plc_side, "--parity", "N", "--cycles", "3",
                              "--dry-run-check"], cwd=root, capture_output=True, text=True, timeout=60)
        out, err = serve.communicate(timeout=20)
    finally:
        if serve.poll() is None:
            serve.kill()
    assert sim.returncode == 0, sim.stdout + sim.stderr
    assert "3 cycles, 0 with problems" in sim.stdout
    assert serve.returncode == 0 and "served 3 cycles" in out, err


def test_broadcast_trigger_is_not_executed(rtu):
    bg, client, plc_side = rtu
    fd = os.open(plc_side, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, read_request(3, 100, 1))  # the raw frame path works: our id answers
        answer = b""
        deadline = time.monotonic() + 2
        while len(answer) < 7 and time.monotonic() < deadline:
            if select.select([fd], [], [], 0.1)[0]:
                answer += os.read(fd, 64)
        assert answer == bytes([3, 3, 2, 0, 0]) + crc16(bytes([3, 3, 2, 0, 0]))
        time.sleep(0.06)
        body = bytes([0, 6, 0, 0, 0, 1])  # broadcast: write command 1 (measure)
        os.write(fd, body + crc16(body))
        time.sleep(0.1)
        assert not select.select([fd], [], [], 0)[0]  # and no answer to a broadcast
    finally:
        os.close(fd)
    assert state(client) == 0 and bg.device.stats["started"] == 0


def _exchange(fd, body: bytes, want: int) -> bytes:
    os.write(fd, body + crc16(body))
    answer = b""
    deadline = time.monotonic() + 2
    while len(answer) < want and time.monotonic() < deadline:
        if select.select([fd], [], [], 0.1)[0]:
            answer += os.read(fd, 256)
    time.sleep(0.06)  # line silence before the next frame
    return answer


def test_rtu_answers_the_same_functions_as_tcp(rtu):
    """Report server id names the station; functions 22 and 23 are refused with exception 1
    and write nothing; a malformed read gets exception 3 with its own function code (docs/plc.md,
    "Function codes")."""
    bg, client, plc_side = rtu
    fd = os.open(plc_side, os.O_RDWR | os.O_NOCTTY)
    try:
        ident = _exchange(fd, bytes([3, 17]), 60)
        mask = _exchange(fd, bytes([3, 22, 0, 0, 0, 0, 0, 1]), 5)  # command := 1
        rw = _exchange(fd, bytes([3, 23, 0, 100, 0, 1, 0, 0, 0, 1, 2, 0, 1]), 5)  # write 1 into 0
        count0 = _exchange(fd, bytes([3, 3, 0, 100, 0, 0]), 5)
    finally:
        os.close(fd)
    assert ident[:2] == bytes([3, 17]) and ident[-2:] == crc16(ident[:-2])
    assert ident[3:5] == bytes([3, 0xFF]) and b"wheel alignment station" in ident and b"Pymodbus" not in ident
    assert mask == bytes([3, 0x96, 1]) + crc16(bytes([3, 0x96, 1]))
    assert rw == bytes([3, 0x97, 1]) + crc16(bytes([3, 0x97, 1]))
    assert count0 == bytes([3, 0x83, 3]) + crc16(bytes([3, 0x83, 3]))  # not "80 01"
    assert state(client) == 0 and bg.device.stats["started"] == 0
    assert client.read_holding_registers(0, count=1, device_id=3).registers == [0]
