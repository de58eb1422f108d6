"""Fault bench, Modbus TCP section (bench/faults.py): what `station serve --dry-run` does with
pipelined and back-to-back requests, garbage, malformed and unknown requests, connection floods
and a read-only client's writes, and a soak of 10,000 pipelined requests on one connection.

    .venv/bin/python bench/faults.py --only plc              # every row, its default tries
    .venv/bin/python bench/faults_plc.py --tries 20           # this section alone

Every server is `station serve --dry-run` in its own process on a free loopback port, with a
configuration in a temporary folder: the bench's main one (plc.max_connections 8,
plc.idle_timeout_s 2), one whose clients on 127.0.0.1 may only read, and one allowed 32 open
files. Requests are raw frames (tests/plc_wire.py); every answer is checked byte by byte:
``correct`` as docs/plc.md specifies, ``lost`` a request that got no answer (or a handshake
that did not complete), ``wrong`` anything else (another request's transaction id, other data,
a connection left open that must close, a cycle run twice). ``procs left`` / ``MiB left``:
server processes still running after SIGTERM (and their memory).
"""

from __future__ import annotations

import random
import resource
import select
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.faults import FaultRow  # noqa: E402
from station.plc import register_map as rm  # noqa: E402
from tests.plc_wire import (closed_by_server, connect, frame, read_pdu, receive, trigger_pdu,  # noqa: E402
                            write_pdu)

STATE, COUNTER, REJECTS, VERSION = (rm.FIELDS[n].address for n in ("state", "cycle_counter", "reject_count",
                                                                     "map_version"))
IDLE, BUSY, DONE, FAULT = 0, 1, 2, 3
MAX_CONNECTIONS, IDLE_TIMEOUT_S = 8, 2.0


# --- servers --------------------------------------------------------------------------------------
class Server:
    """`station serve --dry-run` with ``plc`` keys, in its own process."""

    def __init__(self, folder: Path, nofile: int | None = None, **plc):
        data = yaml.safe_load((ROOT / "config" / "station.yaml").read_text())
        data["plc"].update(plc)
        data["data_dir"] = str(folder / "var")
        data["vehicle_specs"] = str(ROOT / "config" / data.get("vehicle_specs", "vehicles.yaml"))
        data["calibration"]["box"] = str(ROOT / "config" / data["calibration"].get("box", "box.yaml"))
        folder.mkdir(parents=True, exist_ok=True)
        config = folder / "station.yaml"
        config.write_text(yaml.safe_dump(data))
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        limit = (lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))) if nofile else None
        self.log_path = folder / "serve.log"  # a file, not a pipe: a full pipe would stop the server
        with open(self.log_path, "w") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "station.cli", "--config", str(config), "serve", "--dry-run",
                 "--port", str(self.port), "--log-level", "warning"],
                cwd=ROOT, stdout=subprocess.PIPE, stderr=log, text=True, preexec_fn=limit)
        line = self.proc.stdout.readline()
        if f":{self.port}" not in line:
            raise SystemExit(f"station serve did not start: {line}{self.log_path.read_text()}")
        self.log = ""

    def stop(self) -> tuple[int, float]:
        """SIGTERM; returns (processes left, MiB left) and keeps the server's log."""
        self.proc.terminate()
        try:
            self.proc.communicate(timeout=10)
            left = (0, 0.0)
        except subprocess.TimeoutExpired:
            left = (1, _rss_mib(self.proc.pid))
            self.proc.kill()
            self.proc.communicate(timeout=10)
        self.log = self.log_path.read_text()
        return left


def _rss_mib(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _registers(port: int, address: int, count: int) -> list[int]:
    with connect(port) as s:
        s.sendall(frame(1, read_pdu(address, count)))
        (_tid, _unit, pdu), = receive(s, 1)[0]
    return list(struct.unpack(f">{count}H", pdu[2:]))


def _settle(port: int) -> None:
    """Wait for the running cycle to end and acknowledge it: the station is idle again."""
    deadline = time.monotonic() + 10
    while (state := _registers(port, STATE, 1)[0]) == BUSY and time.monotonic() < deadline:
        time.sleep(0.002)
    if state in (DONE, FAULT):
        with connect(port) as s:
            s.sendall(frame(1, write_pdu(0, [4])))
            receive(s, 1)


def _spin(seconds: float) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


# --- outcomes -------------------------------------------------------------------------------------
def _judge(row: FaultRow, sent: list[tuple[int, bytes]], answers, extra_ok: bool = True) -> None:
    """One try: ``sent`` (tid, the expected answer PDU, or None for "any answer, checked by the
    caller in ``extra_ok``") against ``answers``. Wrong: an answer with another transaction id or
    other contents, one too many, or a failed check of the caller; else lost: an answer missing."""
    got = [(tid, pdu) for tid, _unit, pdu in answers]
    wrong = len(got) > len(sent) or any(
        tid != want_tid or (expected is not None and pdu != expected)
        for (tid, pdu), (want_tid, expected) in zip(got, sent))
    if wrong or (len(got) == len(sent) and not extra_ok):
        row.wrong += 1
    elif len(got) < len(sent):
        row.lost += 1
    else:
        row.correct += 1


def _read_answer(port: int, address: int, count: int) -> bytes:
    regs = _registers(port, address, count)
    return bytes([3, 2 * count]) + struct.pack(f">{count}H", *regs)


def _row_two_reads_apart(port: int, tries: int) -> FaultRow:
    row = FaultRow("2 reads on one connection, 0.05-0.5 ms apart", tries)
    want = (_read_answer(port, VERSION, 1), _read_answer(port, STATE, 1))
    rng = random.Random(1)
    for _ in range(tries):
        with connect(port) as s:
            s.sendall(frame(1, read_pdu(VERSION, 1)))
            _spin(rng.uniform(50e-6, 500e-6))
            s.sendall(frame(2, read_pdu(STATE, 1)))
            answers, _ = receive(s, 2, timeout=2)
        _judge(row, [(1, want[0]), (2, want[1])], answers)
    return row


def _row_two_reads_one_segment(port: int, tries: int) -> FaultRow:
    row = FaultRow("2 reads in one TCP segment", tries)
    want = (_read_answer(port, VERSION, 1), _read_answer(port, STATE, 1))
    for _ in range(tries):
        with connect(port) as s:
            s.sendall(frame(1, read_pdu(VERSION, 1)) + frame(2, read_pdu(STATE, 1)))
            answers, _ = receive(s, 2, timeout=2)
        _judge(row, [(1, want[0]), (2, want[1])], answers)
    return row


def _row_fifty_in_one_segment(port: int, tries: int) -> FaultRow:
    """Reads (3, 4), writes of the job id registers (6, 16) and report server id, 50 in one send."""
    row = FaultRow("50 mixed requests in one TCP segment", tries)
    version = _read_answer(port, VERSION, 1)
    for n in range(tries):
        sent, data = [], b""
        for tid in range(1, 51):
            kind = tid % 5
            if kind == 0:
                pdu, want = read_pdu(VERSION, 1), version
            elif kind == 1:
                pdu, want = read_pdu(VERSION, 1, fc=4), bytes([4]) + version[1:]
            elif kind == 2:
                pdu = write_pdu(1, [0x4A00 + n % 256])
                want = pdu
            elif kind == 3:
                pdu = write_pdu(1, [0x4A4F, 0x4200 + tid])
                want = pdu[:5]
            else:
                pdu, want = bytes([17]), None
            sent.append((tid, want))
            data += frame(tid, pdu)
        with connect(port) as s:
            s.sendall(data)
            answers, _ = receive(s, 50, timeout=3)
        _judge(row, sent, answers, extra_ok=all(p[0] == 17 for t, _, p in answers if t % 5 == 4))
    return row


def _row_trigger_and_read(port: int, tries: int, trigger_first: bool) -> FaultRow:
    what = "a trigger, a read 0.2 ms later" if trigger_first else "a read, a trigger 0.2 ms later"
    row = FaultRow(what, tries)
    for n in range(tries):
        _settle(port)
        counter0, rejects0 = _registers(port, COUNTER, 1)[0], _registers(port, REJECTS, 1)[0]
        trigger = trigger_pdu(f"JOB-{n + 1:06d}")
        pdus = [trigger, read_pdu(STATE, 1)] if trigger_first else [read_pdu(STATE, 1), trigger]
        with connect(port) as s:
            s.sendall(frame(1, pdus[0]))
            _spin(0.0002)
            s.sendall(frame(2, pdus[1]))
            answers, _ = receive(s, 2, timeout=2)
        _settle(port)
        counter1, rejects1 = _registers(port, COUNTER, 1)[0], _registers(port, REJECTS, 1)[0]
        read_answer = {tid: pdu for tid, _u, pdu in answers}.get(2 if trigger_first else 1, b"")
        once = (counter1 - counter0) % 65536 == 1 and rejects1 == rejects0  # the trigger ran exactly once
        sees_it = read_answer[:2] == b"\x03\x02" and (read_answer[-1] != IDLE if trigger_first
                                                      else read_answer[-1] == IDLE)
        echo = trigger[:5]  # function 16's answer: address and count
        expected = [(1, echo), (2, None)] if trigger_first else [(1, None), (2, echo)]
        _judge(row, expected, answers, extra_ok=once and sees_it)
    return row


def _row_trigger_ack_burst(port: int, tries: int, pairs: int = 300) -> FaultRow:
    """``pairs`` trigger + acknowledge pairs in one burst: 2 x pairs answers in order; each
    accepted trigger runs one cycle, each refusal is the handshake's (exception 3 or 6)."""
    row = FaultRow(f"{pairs} trigger + acknowledge pairs without waiting", tries)
    for n in range(tries):
        _settle(port)
        counter0, rejects0 = _registers(port, COUNTER, 1)[0], _registers(port, REJECTS, 1)[0]
        data = b"".join(frame(2 * i + 1, trigger_pdu(f"JOB-{n}{i:05d}")) + frame(2 * i + 2, write_pdu(0, [4]))
                        for i in range(pairs))
        with connect(port, timeout=30) as s:
            s.sendall(data)
            answers, _ = receive(s, 2 * pairs, timeout=5)
        _settle(port)
        counter1, rejects1 = _registers(port, COUNTER, 1)[0], _registers(port, REJECTS, 1)[0]
        accepted = sum(1 for tid, _u, pdu in answers if tid % 2 and pdu[0] == 16)
        refused = [pdu for _t, _u, pdu in answers if pdu[0] & 0x80]
        consistent = ((counter1 - counter0) % 65536 == accepted and (rejects1 - rejects0) % 65536 == len(refused)
                      and all(p[1] in (3, 6) for p in refused) and accepted >= 1)
        _judge(row, [(tid, None) for tid in range(1, 2 * pairs + 1)], answers, extra_ok=consistent)
    return row


GARBAGE = {
    "protocol id 0x1234": lambda rng: frame(3, read_pdu(STATE, 1), protocol=0x1234),
    "length 0": lambda rng: frame(3, read_pdu(STATE, 1), length=0),
    "length 1": lambda rng: frame(3, read_pdu(STATE, 1), length=1),
    "length 255..65535": lambda rng: frame(3, read_pdu(STATE, 1), length=rng.randint(255, 65535)),
    "random bytes": lambda rng: bytes([0xFF]) + bytes(rng.getrandbits(8) for _ in range(rng.randint(7, 600))),
}


def _row_garbage(port: int, tries: int) -> FaultRow:
    """A valid read, garbage, a valid read on one connection: the first answered, the connection
    closed; then a valid read on a new connection answered."""
    row = FaultRow("garbage, then a valid request on a new connection", tries)
    rng = random.Random(2)
    want = _read_answer(port, STATE, 1)
    for n in range(tries):
        garbage = list(GARBAGE.values())[n % len(GARBAGE)](rng)
        with connect(port) as s:
            s.sendall(frame(1, read_pdu(STATE, 1)) + garbage + frame(2, read_pdu(STATE, 1)))
            before, closed = receive(s, 2, timeout=2)
        with connect(port) as s:
            s.sendall(frame(9, read_pdu(STATE, 1)))
            after, _ = receive(s, 1, timeout=2)
        _judge(row, [(1, want), (9, want)], before[:1] + after, extra_ok=closed and len(before) == 1)
    return row


MALFORMED = [  # (row, request PDU, the answer docs/plc.md specifies)
    ("FC3 count 0 -> 83 03", read_pdu(STATE, 0), bytes([0x83, 3])),
    ("FC3 count 126 -> 83 03", read_pdu(STATE, 126), bytes([0x83, 3])),
    ("short FC16 -> 90 03", bytes([16, 0, 0, 0, 2, 4, 0]), bytes([0x90, 3])),
    ("short FC15 (coils: not in the map) -> 8F 01", bytes([15, 0, 0]), bytes([0x8F, 1])),
    ("short FC22 (not implemented) -> 96 01", bytes([22, 0, 0]), bytes([0x96, 1])),
    ("short FC23 (not implemented) -> 97 01", bytes([23, 0, 0]), bytes([0x97, 1])),
    ("FC22 writing the command register -> 96 01", bytes([22, 0, 0, 0, 0, 0, 1]), bytes([0x96, 1])),
    ("unknown FC99 -> E3 01", bytes([99]), bytes([0xE3, 1])),
    ("unknown FC127 -> FF 01", bytes([127, 0, 0]), bytes([0xFF, 1])),
    ("FC128 (an exception code) -> 80 01", bytes([128]), bytes([0x80, 1])),
    ("FC17 report server id: the station's, not Pymodbus", bytes([17]), None),
]


def _rows_malformed(port: int, tries: int) -> list[FaultRow]:
    rows = []
    state = _read_answer(port, STATE, 1)
    for name, pdu, want in MALFORMED:
        row = FaultRow(name, tries)
        for _ in range(tries):
            with connect(port) as s:  # and a read after it on the same connection
                s.sendall(frame(5, pdu) + frame(6, read_pdu(STATE, 1)))
                answers, _ = receive(s, 2, timeout=2)
            ok = True
            if want is None:  # function 17
                ok = bool(answers) and answers[0][2][:1] == b"\x11" and b"wheel alignment station" in answers[0][2] \
                    and b"Pymodbus" not in answers[0][2]
            _judge(row, [(5, want), (6, state)], answers, extra_ok=ok)
        rows.append(row)
    return rows


def _row_flood(port: int, tries: int, size: int = 150) -> FaultRow:
    """``size`` idle connections: all but plc.max_connections closed at once, the rest kept;
    then the flood goes and a PLC runs a whole checked cycle."""
    row = FaultRow(f"{size} idle connections (limit {MAX_CONNECTIONS}), then a PLC cycle", tries)
    for n in range(tries):
        time.sleep(0.3)  # the previous cycle's connection is closed at the station too
        flood = [socket.create_connection(("127.0.0.1", port), timeout=2) for _ in range(size)]
        closed = len(_closed_within(flood, 0.5))
        for s in flood:
            s.close()
        time.sleep(0.3)
        ok = _plc_cycle(port, f"JOB-{n + 1:06d}")
        _judge(row, [(1, None)], [(1, 0, b"")] if ok else [], extra_ok=closed == size - MAX_CONNECTIONS)
    return row


def _closed_within(socks: list[socket.socket], seconds: float) -> set[int]:
    """Indices of ``socks`` the server closed within ``seconds`` (watched all at once)."""
    pending, closed = {s: i for i, s in enumerate(socks)}, set()
    deadline = time.monotonic() + seconds
    while pending and (left := deadline - time.monotonic()) > 0:
        for s in select.select(list(pending), [], [], left)[0]:
            try:
                data = s.recv(64)
            except ConnectionResetError:
                data = b""
            if not data:
                closed.add(pending.pop(s))
    return closed


def _plc_cycle(port: int, job: str, source: str | None = None) -> bool:
    """A whole handshake by the PLC simulator (pymodbus client), every value checked."""
    from pymodbus.client import ModbusTcpClient

    from station.plc.master import PlcSimulator, dry_run_expectation

    kw = {"source_address": (source, 0)} if source else {}
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=3, **kw)
    try:
        if not client.connect():
            return False
        return PlcSimulator(client).run_cycle(job, expect=dry_run_expectation(10)).problems == []
    except Exception:  # noqa: BLE001 - a failed handshake is what this row counts
        return False
    finally:
        client.close()


def _row_idle(port: int, tries: int) -> FaultRow:
    """Idle connections (at most plc.max_connections - 1 at once) beside one polling every
    0.1 s: after plc.idle_timeout_s every idle one is closed, the polling one is still served."""
    row = FaultRow(f"idle connections closed after plc.idle_timeout_s ({IDLE_TIMEOUT_S:g} s)", tries)
    done = 0
    while done < tries:
        batch = min(tries - done, MAX_CONNECTIONS - 1)
        idle = [connect(port) for _ in range(batch)]
        t0 = time.monotonic()
        with connect(port) as polling:
            served = True
            while time.monotonic() - t0 < IDLE_TIMEOUT_S + 1.0:
                polling.sendall(frame(1, read_pdu(STATE, 1)))
                served &= len(receive(polling, 1, timeout=1)[0]) == 1
                time.sleep(0.1)
        for s in idle:
            if not closed_by_server(s, timeout=0.5):
                row.wrong += 1  # left open
            elif not served:
                row.lost += 1  # the polling PLC went unanswered meanwhile
            else:
                row.correct += 1
            s.close()
        done += batch
    return row


def _row_read_only(port: int, tries: int) -> FaultRow:
    """Writes (6 and 16, the trigger among them) from a client plc.allowed_clients lets only
    read: exception 1 each, nothing written, no cycle; a writer from 127.0.0.2 runs a cycle."""
    row = FaultRow("writes from a read-only client (127.0.0.1 read)", tries)
    counter0 = _registers(port, COUNTER, 1)[0]
    for n in range(tries):
        pdu = write_pdu(0, [1]) if n % 2 else trigger_pdu(f"JOB-{n:06d}")
        with connect(port) as s:
            s.sendall(frame(7, pdu) + frame(8, read_pdu(0, 1)))
            answers, _ = receive(s, 2, timeout=2)
        _judge(row, [(7, bytes([pdu[0] | 0x80, 1])), (8, bytes([3, 2, 0, 0]))], answers)
    if _registers(port, COUNTER, 1)[0] != counter0 or _registers(port, STATE, 1)[0] != IDLE:
        row.wrong, row.correct = row.wrong + row.correct, 0  # a write got through: no try counts
    if not _plc_cycle(port, "JOB-000001", source="127.0.0.2") and row.correct:
        row.lost, row.correct = row.lost + 1, row.correct - 1  # the writer could not run its cycle
    return row


def _row_soak(port: int, n: int) -> FaultRow:
    """``n`` pipelined requests on one connection, sent while the answers are read: reads of
    the map version (3 and 4), of the status block, report server id; each answer in order, with
    its own transaction id and the right contents."""
    import threading

    row = FaultRow(f"soak: {n:,} pipelined requests on one connection", n)
    version = _read_answer(port, VERSION, 1)
    kinds = [(read_pdu(VERSION, 1), version), (read_pdu(VERSION, 1, fc=4), bytes([4]) + version[1:]),
             (read_pdu(100, 20), None), (bytes([17]), None)]
    sent = [(i % 65536, kinds[i % 4][1]) for i in range(n)]
    data = b"".join(frame(i % 65536, kinds[i % 4][0]) for i in range(n))
    with connect(port, timeout=60) as s:
        sender = threading.Thread(target=s.sendall, args=(data,), daemon=True)
        sender.start()
        answers, _ = receive(s, n, timeout=10)
        sender.join(10)
    for i, ((tid, want), got) in enumerate(zip(sent, answers)):
        if got[0] != tid:
            row.wrong += 1
        elif want is not None and got[2] != want:
            row.wrong += 1
        elif want is None and got[2][0] != kinds[i % 4][0][0]:
            row.wrong += 1
        else:
            row.correct += 1
    row.lost += max(0, n - len(answers))
    return row


def _row_out_of_files(port: int, tries: int, size: int = 150) -> FaultRow:
    """A station allowed 32 open files and plc.max_connections 1000: ``size`` connections held
    for 2 s (accept() fails for lack of file descriptors), released, then a PLC cycle."""
    row = FaultRow(f"{size} connections held against 32 open files, then a PLC cycle", tries)
    for n in range(tries):
        flood = []
        for _ in range(size):
            try:
                flood.append(socket.create_connection(("127.0.0.1", port), timeout=1))
            except OSError:
                break
        time.sleep(2.0)
        for s in flood:
            s.close()
        time.sleep(1.0)
        ok = _plc_cycle(port, f"JOB-{n + 1:06d}")
        _judge(row, [(1, None)], [(1, 0, b"")] if ok else [])
    return row


def rows(tries: int | None) -> list[FaultRow]:
    t = (lambda default: tries or default)
    out: list[FaultRow] = []
    servers: list[Server] = []
    with tempfile.TemporaryDirectory(prefix="faults-plc-") as tmp:
        folder = Path(tmp)
        try:
            main = Server(folder / "main", max_connections=MAX_CONNECTIONS, idle_timeout_s=IDLE_TIMEOUT_S)
            servers.append(main)
            port = main.port
            out.append(_row_two_reads_apart(port, t(100)))
            out.append(_row_two_reads_one_segment(port, t(100)))
            out.append(_row_fifty_in_one_segment(port, t(100)))
            out.append(_row_trigger_and_read(port, t(60), trigger_first=True))
            out.append(_row_trigger_and_read(port, t(60), trigger_first=False))
            out.append(_row_trigger_ack_burst(port, t(5)))
            out.append(_row_garbage(port, t(100)))
            out.extend(_rows_malformed(port, t(20)))
            out.append(_row_flood(port, t(5)))
            time.sleep(0.3)  # the flood's connections are gone
            out.append(_row_idle(port, t(7)))
            out.append(_row_soak(port, tries or 10_000))
            read_only = Server(folder / "read-only", allowed_clients=["127.0.0.1 read", "127.0.0.2"])
            servers.append(read_only)
            out.append(_row_read_only(read_only.port, t(100)))
            few_files = Server(folder / "few-files", nofile=32, max_connections=1000)
            servers.append(few_files)
            out.append(_row_out_of_files(few_files.port, t(3)))
        finally:
            logs = FaultRow("server processes stopped, their logs free of tracebacks", len(servers))
            for server in servers:
                procs, mib = server.stop()
                logs.procs_left += procs
                logs.mib_left += mib
                if "Traceback" in server.log:
                    logs.wrong += 1
                else:
                    logs.correct += 1
            out.append(logs)
    return out


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tries", type=int, default=None)
    result = rows(ap.parse_args().tries)
    print("| fault | tries | correct | lost | wrong | procs left | MiB left |")
    print("|---|---|---|---|---|---|---|")
    for r in result:
        print(r.markdown())
    sys.exit(1 if any(r.lost or r.wrong or r.procs_left or r.correct != r.tries for r in result) else 0)
