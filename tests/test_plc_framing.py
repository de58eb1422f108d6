"""Modbus TCP framing on the wire: pipelined requests (several outstanding on one connection),
requests split across or packed into TCP segments, garbage, malformed and unknown requests and
their exception responses, the functions the station implements. Raw sockets (tests/plc_wire.py)
send what a library client never would; every answer is checked byte by byte."""

import socket
import struct
import threading
import time

import pytest
from pymodbus.client import ModbusTcpClient

from station.plc import register_map as rm
from station.plc.background import BackgroundServer
from station.plc.device import PlcDevice
from station.plc.runner import dry_run_runner, synthetic_result
from tests.plc_wire import closed_by_server, connect, frame, read_pdu, receive, trigger_pdu, write_pdu

IDLE, BUSY, DONE = 0, 1, 2


@pytest.fixture
def served():
    """(background server, port) with the dry-run runner."""
    made = []

    def make(runner=None, heartbeat_s=0.02, **server_kw):
        bg = BackgroundServer(PlcDevice(runner or dry_run_runner(0), heartbeat_s=heartbeat_s), **server_kw)
        made.append(bg)
        return bg, bg.start_tcp()

    yield make
    for bg in made:
        bg.stop()


def answered_registers(pdu: bytes) -> list[int]:
    assert pdu[0] in (3, 4) and pdu[1] == len(pdu) - 2, pdu.hex()
    return list(struct.unpack(f">{pdu[1] // 2}H", pdu[2:]))


def test_pipelined_reads_in_one_segment_are_each_answered_in_order(served):
    bg, port = served(heartbeat_s=1000)  # the registers stand still: every answer can be checked
    requests = [(tid, 100 + tid % 20, 1 + tid % 7) for tid in range(1, 301)]  # (tid, address, count)
    with connect(port) as s:
        s.sendall(b"".join(frame(tid, read_pdu(a, n)) for tid, a, n in requests))
        answers, closed = receive(s, len(requests))
    assert not closed
    assert [tid for tid, _, _ in answers] == [tid for tid, _, _ in requests]
    memory = bg.call(lambda: bg.device.registers(100, 30))
    for (tid, address, count), (_, unit, pdu) in zip(requests, answers):
        assert unit == 1 and answered_registers(pdu) == memory[address - 100:address - 100 + count], tid


def test_two_reads_sent_back_to_back_get_two_answers_with_their_own_ids(served):
    _, port = served()
    for i in range(50):
        with connect(port) as s:
            s.sendall(frame(1, read_pdu(100, 1)))
            s.sendall(frame(2, read_pdu(102, 2)))
            answers, _ = receive(s, 2, timeout=2)
        assert [(tid, len(answered_registers(pdu))) for tid, _, pdu in answers] == [(1, 1), (2, 2)], i


def test_requests_split_into_single_bytes_are_answered(served):
    _, port = served()
    data = frame(7, read_pdu(100, 3)) + frame(8, read_pdu(0, 1, fc=4))
    with connect(port) as s:
        for b in data:
            s.sendall(bytes([b]))
            time.sleep(0.001)
        answers, _ = receive(s, 2)
    assert [(tid, len(answered_registers(pdu))) for tid, _, pdu in answers] == [(7, 3), (8, 1)]


def test_a_trigger_followed_at_once_by_a_read_runs_once_and_the_read_sees_it(served):
    gate = threading.Event()

    def gated(request):
        gate.wait(10)
        return synthetic_result(request, 0)

    bg, port = served(gated)
    with connect(port) as s:
        s.sendall(frame(1, trigger_pdu("JOB-000001")) + frame(2, read_pdu(rm.FIELDS["state"].address, 1)))
        answers, _ = receive(s, 2)
    gate.set()
    assert [tid for tid, _, _ in answers] == [1, 2]
    assert answers[0][2] == write_pdu(0, [0] * 33)[:5]  # FC16 echo: address 0, 33 registers
    assert answered_registers(answers[1][2]) == [BUSY]
    assert bg.device.stats["started"] == 1


def test_a_read_followed_at_once_by_a_trigger_runs_the_trigger_once(served):
    bg, port = served()
    with connect(port) as s:
        s.sendall(frame(1, read_pdu(rm.FIELDS["state"].address, 1)) + frame(2, trigger_pdu("JOB-000001")))
        answers, _ = receive(s, 2)
        time.sleep(0.2)
    assert [tid for tid, _, _ in answers] == [1, 2]
    assert answered_registers(answers[0][2]) == [IDLE] and answers[1][2][0] == 16
    assert bg.device.stats["started"] == 1


def test_trigger_and_acknowledge_pairs_without_waiting_are_each_answered_once(served):
    """300 trigger + acknowledge pairs in one burst: 600 answers in order; every trigger the
    station accepted started exactly one cycle, every accepted acknowledge ended one."""
    bg, port = served()
    n = 300
    with connect(port) as s:
        s.sendall(b"".join(frame(2 * i + 1, trigger_pdu(f"JOB-{i:06d}")) + frame(2 * i + 2, write_pdu(0, [4]))
                           for i in range(n)))
        answers, _ = receive(s, 2 * n)
    assert [tid for tid, _, _ in answers] == list(range(1, 2 * n + 1))
    triggers_ok = sum(pdu[0] == 16 for tid, _, pdu in answers if tid % 2)
    acks_ok = sum(pdu[0] == 6 for tid, _, pdu in answers if not tid % 2)
    refused = [pdu for _, _, pdu in answers if pdu[0] & 0x80]
    assert all(pdu[1] in (3, 6) for pdu in refused)  # handshake refusals only
    assert triggers_ok >= 1
    stats = bg.device.stats
    assert (stats["started"], stats["acknowledged"], stats["refused"]) == (triggers_ok, acks_ok, len(refused))


def test_ten_thousand_pipelined_requests_on_one_connection(served):
    _, port = served()
    n = 10_000
    with connect(port, timeout=30) as s:
        sender = threading.Thread(target=s.sendall, args=(b"".join(
            frame(i % 65536, read_pdu(100 + i % 8, 1 + i % 3)) for i in range(n)),))
        sender.start()  # the server stops reading while its answers are not read: send in a thread
        answers, closed = receive(s, n, timeout=10)
        sender.join(10)
    assert not closed and len(answers) == n
    assert [tid for tid, _, _ in answers] == [i % 65536 for i in range(n)]
    assert [len(answered_registers(pdu)) for _, _, pdu in answers] == [1 + i % 3 for i in range(n)]


@pytest.mark.parametrize("garbage", [
    frame(3, read_pdu(100, 1), protocol=0x1234),
    frame(3, read_pdu(100, 1), length=0),
    frame(3, read_pdu(100, 1), length=1),
    frame(3, read_pdu(100, 1), length=255),
    frame(3, read_pdu(100, 1), length=0xFFFF),
    bytes(range(200, 256)) * 3,
], ids=["protocol id", "length 0", "length 1", "length 255", "length 65535", "random bytes"])
def test_garbage_closes_the_connection_after_answering_what_came_before(served, garbage):
    bg, port = served()
    with connect(port) as s:
        s.sendall(frame(1, read_pdu(100, 1)) + garbage + frame(2, read_pdu(100, 1)))
        answers, closed = receive(s, 2, timeout=2)
    assert [tid for tid, _, _ in answers] == [1] and closed
    with connect(port) as s:  # a new connection is served at once
        s.sendall(frame(9, read_pdu(100, 1)))
        assert [tid for tid, _, _ in receive(s, 1)[0]] == [9]
    assert bg.server.counters.bad_frames == 1


def test_garbage_is_logged_once_per_burst(served, caplog):
    _, port = served()
    for _ in range(20):
        with connect(port) as s:
            s.sendall(frame(1, read_pdu(100, 1), protocol=7))
            assert closed_by_server(s)
    lines = [r.getMessage() for r in caplog.records if "not a Modbus TCP frame" in r.getMessage()]
    assert len(lines) == 1 and "protocol id 7" in lines[0]


@pytest.mark.parametrize("pdu, answer", [
    (read_pdu(100, 0), "8303"),  # count 0
    (read_pdu(100, 126), "8303"),  # count beyond 125
    (read_pdu(100, 0, fc=4), "8403"),
    (bytes([3, 0, 100]), "8303"),  # cut short
    (bytes([6, 0, 0]), "8603"),
    (bytes([16, 0, 0, 0, 2, 4, 0, 1]), "9003"),  # byte count 4, 2 bytes of data
    (bytes([16, 0, 0, 0, 2, 3, 0, 1, 0]), "9003"),  # byte count not 2 x count
    (bytes([16, 0, 0, 0, 0, 0]), "9003"),  # count 0
    (bytes([16]), "9003"),
    (bytes([17, 0]), "9103"),
    (bytes([15, 0, 0]), "8f01"),  # coils: not in this map
    (bytes([22, 0, 0, 0xFF, 0xFF, 0, 0]), "9601"),  # mask write: not implemented
    (bytes([23, 0, 0]), "9701"),  # read/write multiple: not implemented
    (bytes([8, 0, 0, 0x12, 0x34]), "8801"),  # diagnostics
    (bytes([43, 14, 1, 0]), "ab01"),  # device identification
    (bytes([99]), "e301"),
    (bytes([127, 1, 2]), "ff01"),
    (bytes([0]), "8001"),
    (bytes([128]), "8001"),  # an exception code in a request: exception 1, the code unchanged
    (bytes([0x83, 0, 100, 0, 1]), "8301"),
], ids=["fc3 count 0", "fc3 count 126", "fc4 count 0", "fc3 short", "fc6 short", "fc16 data short",
        "fc16 byte count", "fc16 count 0", "fc16 alone", "fc17 with data", "fc15 coils", "fc22", "fc23",
        "fc8", "fc43", "fc99", "fc127", "fc0", "fc128", "fc131"])
def test_malformed_and_unknown_requests_get_the_request_code_plus_0x80(served, pdu, answer):
    bg, port = served()
    with connect(port) as s:
        s.sendall(frame(41, pdu) + frame(42, read_pdu(100, 1)))
        answers, closed = receive(s, 2)
    assert not closed
    assert [(tid, got.hex()) for tid, _, got in answers][:1] == [(41, answer)]
    assert answers[1][0] == 42 and answered_registers(answers[1][2]) == [IDLE]  # still served
    assert bg.device.stats["started"] == 0


def test_report_server_id_names_the_station(served):
    _, port = served()
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    try:
        assert client.connect()
        with connect(port) as s:
            s.sendall(frame(5, bytes([17])))
            (tid, _, pdu), = receive(s, 1)[0]
    finally:
        client.close()
    assert pdu[0] == 17 and pdu[1] == len(pdu) - 2
    assert pdu[2:4] == bytes([1, 0xFF])  # server id = device id, run indicator on
    text = pdu[4:].decode("ascii")
    assert "wheel alignment station" in text and f"map {rm.MAP_VERSION}" in text
    assert "Pymodbus" not in text


def test_writes_by_functions_22_and_23_change_nothing(served):
    bg, port = served()
    with connect(port) as s:
        s.sendall(frame(1, bytes([22, 0, 0, 0, 0, 0, 1])) +  # mask write: command := 1
                  frame(2, bytes([23, 0, 100, 0, 1, 0, 0, 0, 1, 2, 0, 1])))  # write 1 into 0, read 100
        answers, _ = receive(s, 2)
    assert [pdu.hex() for _, _, pdu in answers] == ["9601", "9701"]
    assert bg.device.stats["started"] == 0 and bg.call(lambda: bg.device.registers(0, 1)) == [0]


def test_a_client_that_reads_its_answers_late_gets_them_all(served):
    """40,000 requests sent while the client reads nothing for a second: the station stops
    reading the connection when the answers back up, and every answer arrives once the client
    reads, in order."""
    _, port = served()
    n = 40_000
    with connect(port, timeout=30) as s:
        sender = threading.Thread(target=s.sendall, args=(b"".join(frame(i % 65536, read_pdu(100, 20))
                                                                   for i in range(n)),), daemon=True)
        sender.start()
        time.sleep(1.0)
        answers, closed = receive(s, n, timeout=10)
        sender.join(10)
    assert not closed and [tid for tid, _, _ in answers] == [i % 65536 for i in range(n)]


def test_the_function_code_table_in_the_docs_is_generated_from_the_code():
    from station.plc.docs import DOC, render

    doc = DOC.read_text()
    assert render(doc) == doc, "docs/plc.md is stale: python -m station.plc.docs"
