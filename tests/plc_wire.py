"""Modbus TCP on the wire, written independently of pymodbus and of the station: frames built
byte by byte, answers read back and split by their MBAP header. For tests and the fault bench
that send what a library client never would (pipelined requests, garbage, odd lengths)."""

from __future__ import annotations

import socket
import struct
import time

MBAP = struct.Struct(">HHHB")


def frame(tid: int, pdu: bytes, unit: int = 1, protocol: int = 0, length: int | None = None) -> bytes:
    """One Modbus TCP frame (``length`` overrides the MBAP length field)."""
    return MBAP.pack(tid, protocol, len(pdu) + 1 if length is None else length, unit) + pdu


def read_pdu(address: int, count: int, fc: int = 3) -> bytes:
    return struct.pack(">BHH", fc, address, count)


def write_pdu(address: int, values: list[int]) -> bytes:
    if len(values) == 1:
        return struct.pack(">BHH", 6, address, values[0])
    return struct.pack(">BHHB", 16, address, len(values), 2 * len(values)) + b"".join(
        struct.pack(">H", v) for v in values)


def ascii_regs(text: str, count: int) -> list[int]:
    raw = text.encode("ascii").ljust(2 * count, b"\0")
    return [raw[i] << 8 | raw[i + 1] for i in range(0, 2 * count, 2)]


def trigger_pdu(job: str, command: int = 1) -> bytes:
    return write_pdu(0, [command] + ascii_regs(job, 16) + [0] * 16)


def connect(port: int, timeout: float = 5.0) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def split(data: bytes) -> tuple[list[tuple[int, int, bytes]], bytes]:
    """Complete frames in ``data`` as (transaction id, unit id, pdu), and the bytes left over."""
    out = []
    while len(data) >= MBAP.size:
        tid, _pid, length, unit = MBAP.unpack_from(data)
        end = 6 + length
        if len(data) < end:
            break
        out.append((tid, unit, data[MBAP.size:end]))
        data = data[end:]
    return out, data


def receive(sock: socket.socket, n: int, timeout: float = 5.0) -> tuple[list[tuple[int, int, bytes]], bool]:
    """Up to ``n`` answers (stops early when the connection closes or ``timeout`` passes without
    data); returns (answers, closed): closed when the server closed the connection."""
    answers, rest, closed = [], b"", False
    deadline = time.monotonic() + timeout
    while len(answers) < n:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            data = sock.recv(1 << 16)
        except (TimeoutError, socket.timeout):
            break
        except ConnectionResetError:
            closed = True
            break
        if not data:
            closed = True
            break
        deadline = time.monotonic() + timeout
        got, rest = split(rest + data)
        answers += got
    return answers, closed


def closed_by_server(sock: socket.socket, timeout: float = 2.0) -> bool:
    """True when the server closes ``sock`` within ``timeout`` (EOF or reset)."""
    sock.settimeout(timeout)
    try:
        while sock.recv(4096):
            pass
        return True
    except ConnectionResetError:
        return True
    except (TimeoutError, socket.timeout):
        return False
