"""Modbus TCP: the station's own asyncio transport (MBAP framing) in front of the request handler.

Modbus TCP lets a client send several requests without waiting for the answers. Each
connection here reads frames by their MBAP header (transaction id, protocol id, length, unit
id), queues them in arrival order and answers one at a time: a request is executed and its
answer written before the next request is looked at, each answer with its own request's
transaction id. Requests split across TCP segments or many in one segment are all answered.

A header that cannot start a Modbus TCP frame (protocol id not 0, length outside 2..254) means
the byte stream has lost its framing; there is no reliable way to find the next frame in it,
so the connection is closed after the requests before it are answered (a PLC reconnects), and
that is logged once per burst.

Also here: the allow-list with read-only clients (:mod:`station.plc.clients`), a limit on open
connections (a client beyond it is closed at once), an idle timeout, TCP keepalive, flow
control (a client that does not read its answers is not read from either), and a one-line log
instead of a traceback per attempt when the process runs out of file descriptors.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import resource
import socket
import struct
import time
from collections import deque
from dataclasses import dataclass

from station.plc.clients import Access, ClientAccess
from station.plc.functions import (GATEWAY_TARGET_FAILED, READ_ONLY_CLIENT, WRITE_FUNCTIONS, RequestHandler,
                                   exception_pdu, request_error)
from station.plc.log_bursts import BurstLog

log = logging.getLogger("station.plc")

MBAP = struct.Struct(">HHHB")  # transaction id, protocol id, length (unit id + PDU), unit id
MIN_LENGTH, MAX_LENGTH = 2, 254  # unit id + function code .. unit id + the largest PDU (253)
QUEUE_PAUSE = 64  # requests waiting on one connection: stop reading it until they are answered
ACCEPT_RETRY_S = 0.5  # after accept() failed for lack of file descriptors
FILES_BESIDES_CONNECTIONS = 64  # cameras, images, the history, recordings, worker pipes
OUT_OF_RESOURCES = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)


@dataclass
class ServerCounters:
    """What the server refused or closed, for the log's summary and the tests."""

    refused_clients: int = 0  # not in plc.allowed_clients
    over_limit: int = 0  # beyond plc.max_connections
    idle_closed: int = 0  # no request for plc.idle_timeout_s
    bad_frames: int = 0  # connections closed for bytes that are not Modbus TCP
    read_only_writes: int = 0  # writes refused to clients that may only read
    unknown_ids: int = 0  # requests for another device id
    accept_failures: int = 0  # accept() failed: out of file descriptors


def _keepalive(sock) -> None:
    """TCP keepalive on a PLC connection: a PLC that was switched off without closing its
    connection is noticed within about 25 s instead of leaving a dead connection open forever."""
    if sock is None or sock.family not in (socket.AF_INET, socket.AF_INET6):
        return
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for name, value in (("TCP_KEEPIDLE", 10), ("TCP_KEEPINTVL", 5), ("TCP_KEEPCNT", 3)):
        if hasattr(socket, name):
            sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, name), value)


class TcpListener:
    """Serves ``handler`` on ``host:port``. ``active_connections``: peer "ip:port" -> connection.

    Connections are accepted here rather than by asyncio's server: a client that is not allowed
    or beyond ``max_connections`` is closed before a transport is made for it, and when accept()
    fails for lack of file descriptors, listening pauses for ``ACCEPT_RETRY_S`` with one log
    line per burst (asyncio 3.11 retries up to 100 times per wake-up, each with a traceback).
    """

    def __init__(self, handler: RequestHandler, answered_ids, *, clients: ClientAccess,
                 max_connections: int = 8, idle_timeout_s: float = 60.0,
                 counters: ServerCounters | None = None, bursts: BurstLog | None = None):
        self.handler = handler
        self.answered_ids = frozenset(answered_ids)
        self.clients = clients
        self.max_connections = max_connections
        self.idle_timeout_s = idle_timeout_s
        self.counters = counters or ServerCounters()
        self.bursts = bursts or BurstLog(log)
        self.active_connections: dict[str, Connection] = {}
        self.sockets: list[socket.socket] = []
        self._starting = 0  # accepted, transport being made
        self._loop: asyncio.AbstractEventLoop | None = None
        self._retry: asyncio.TimerHandle | None = None

    async def start(self, host: str, port: int) -> int:
        """Listen; returns the bound port. Raises OSError when the address cannot be bound."""
        self._loop = asyncio.get_running_loop()
        infos = await self._loop.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        try:
            for family, kind, proto, _name, address in dict.fromkeys(infos):
                sock = socket.socket(family, kind, proto)
                self.sockets.append(sock)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6:
                    sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                if port == 0 and len(self.sockets) > 1:  # one free port for every address
                    address = (address[0], self.sockets[0].getsockname()[1], *address[2:])
                sock.bind(address)
                sock.listen(socket.SOMAXCONN)  # a flood is refused from the queue, not by dropped SYNs
                sock.setblocking(False)
        except OSError:
            self._close_sockets()
            raise
        for sock in self.sockets:
            self._loop.add_reader(sock.fileno(), self._accept, sock)
        soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        if soft != resource.RLIM_INFINITY and self.max_connections + FILES_BESIDES_CONNECTIONS > soft:
            log.warning("plc.max_connections is %d, but this process may open only %d files (the station needs "
                        "about %d besides its PLC connections); lower plc.max_connections or raise the "
                        "limit (ulimit -n)", self.max_connections, soft, FILES_BESIDES_CONNECTIONS)
        return self.sockets[0].getsockname()[1]

    async def close(self) -> None:
        self._close_sockets()
        workers = [c.worker for c in self.active_connections.values() if c.worker is not None]
        for connection in list(self.active_connections.values()):
            connection.transport.abort()
        if workers:
            await asyncio.wait(workers, timeout=5)
        self.bursts.flush()

    def _close_sockets(self) -> None:
        if self._retry is not None:
            self._retry.cancel()
        for sock in self.sockets:
            if self._loop is not None and sock.fileno() >= 0:
                self._loop.remove_reader(sock.fileno())
            sock.close()
        self.sockets = []

    def _accept(self, sock: socket.socket) -> None:
        for _ in range(128):  # then let the loop serve the open connections
            try:
                conn, peer = sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionAbortedError:
                continue
            except OSError as e:
                if e.errno in OUT_OF_RESOURCES:
                    self._out_of_files(e)
                else:  # a connection that failed while it waited in the queue
                    self.bursts("PLC connections failed before they were accepted",
                                "a PLC connection failed before it was accepted: %s", e, level=logging.INFO)
                return
            host = str(peer[0]) if isinstance(peer, tuple) else str(peer)
            access, rule = self.clients.of(host)
            if access is Access.REFUSED:
                self.counters.refused_clients += 1
                self.bursts(f"PLC client {host} refused", "PLC client %s refused: not in plc.allowed_clients "
                            "(add its address or network there to let it connect)", host)
                conn.close()
            elif len(self.active_connections) + self._starting >= self.max_connections:
                self.counters.over_limit += 1
                self.bursts("PLC connections refused beyond plc.max_connections",
                            "PLC client %s refused: %d connections are open, plc.max_connections is %d "
                            "(idle ones close after plc.idle_timeout_s = %g s)", host,
                            len(self.active_connections) + self._starting, self.max_connections,
                            self.idle_timeout_s)
                conn.close()
            else:
                try:
                    conn.setblocking(False)
                    _keepalive(conn)
                except OSError:  # reset by the client already
                    conn.close()
                    continue
                self._starting += 1
                self._loop.create_task(self._connect(conn, access, rule))

    async def _connect(self, conn: socket.socket, access: Access, rule: str) -> None:
        """Sets up an accepted connection; it counts as starting until it is active (its
        ``connection_made``, which moves it), so it is never counted twice against the limit."""
        made: list[Connection] = []

        def protocol() -> Connection:
            made.append(Connection(self, access, rule))
            return made[-1]

        try:
            await self._loop.connect_accepted_socket(protocol, conn)
        except OSError as e:  # the client went away, or no memory for the transport
            log.info("PLC connection not set up: %s", e)
            conn.close()
        finally:
            if not (made and made[-1].active):
                self._starting -= 1

    def _out_of_files(self, error: OSError) -> None:
        """accept() failed for lack of file descriptors: stop listening for a moment."""
        self.counters.accept_failures += 1
        soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        self.bursts("PLC connections not accepted for lack of file descriptors",
                    "cannot accept PLC connections: %s (%d PLC connections open, open-file limit %d); "
                    "retrying every %g s; lower plc.max_connections or raise the limit (ulimit -n)",
                    error.strerror or error, len(self.active_connections) + self._starting, soft, ACCEPT_RETRY_S)
        for sock in self.sockets:
            self._loop.remove_reader(sock.fileno())
        self._retry = self._loop.call_later(ACCEPT_RETRY_S, self._listen_again)

    def _listen_again(self) -> None:
        self._retry = None
        for sock in self.sockets:
            self._loop.add_reader(sock.fileno(), self._accept, sock)

    async def answer(self, frame: bytes, connection: Connection) -> bytes:
        """The response frame to one request frame (its MBAP header checked)."""
        tid, _pid, _length, unit_id = MBAP.unpack_from(frame)
        pdu = frame[MBAP.size:]
        fc = pdu[0]
        if unit_id not in self.answered_ids:
            self.counters.unknown_ids += 1
            self.bursts(f"requests for device ids other than {self.handler.device_id}",
                        "request for device id %d answered with exception 0x0B: this station is %d",
                        unit_id, self.handler.device_id, level=logging.INFO)
            out = exception_pdu(fc, GATEWAY_TARGET_FAILED)
        elif (code := request_error(pdu)) is not None:
            log.debug("%s: function %d request answered with exception %d", connection.peer, fc, code)
            out = exception_pdu(fc, code)
        elif fc in WRITE_FUNCTIONS and connection.access is Access.READ:
            self.counters.read_only_writes += 1
            address = struct.unpack_from(">H", pdu, 1)[0]
            self.bursts(f"writes refused to read-only client {connection.host}",
                        "PLC client %s may only read (plc.allowed_clients %r): its write (function %d, register "
                        "%d) is refused with exception %d", connection.host, connection.rule, fc, address,
                        READ_ONLY_CLIENT)
            out = exception_pdu(fc, READ_ONLY_CLIENT)
        else:
            out = await self.handler.answer(pdu, unit_id, tid)
        return MBAP.pack(tid, 0, len(out) + 1, unit_id) + out


class Connection(asyncio.Protocol):
    """One client connection: MBAP framing, requests answered one at a time in arrival order."""

    def __init__(self, listener: TcpListener, access: Access = Access.WRITE, rule: str = ""):
        self.listener = listener
        self.transport: asyncio.Transport | None = None
        self.peer = self.host = "?"
        self.access, self.rule = access, rule  # the allow-list's verdict and its entry
        self.worker: asyncio.Task | None = None
        self._buffer = bytearray()
        self._requests: deque[bytes] = deque()
        self._wake = asyncio.Event()
        self._writable = asyncio.Event()
        self._writable.set()
        self._reading = True
        self._closing = False  # no more requests are read; those queued are answered, then close
        self._closed = False
        self.active = False  # connection_made has counted it among the listener's active connections
        self._last_activity = time.monotonic()  # a request read or an answer written
        self._idle_timer: asyncio.TimerHandle | None = None

    # --- asyncio.Protocol ---------------------------------------------------------------------
    def connection_made(self, transport) -> None:
        self.transport = transport
        peer = transport.get_extra_info("peername")
        if isinstance(peer, tuple):
            self.host, self.peer = str(peer[0]), f"{peer[0]}:{peer[1]}"
        self.listener.active_connections[self.peer] = self
        self.listener._starting -= 1  # no longer starting: active
        self.active = True
        if self.listener.idle_timeout_s > 0:
            self._arm_idle(self.listener.idle_timeout_s)
        self.worker = asyncio.get_running_loop().create_task(self._serve(), name=f"plc {self.peer}")

    def data_received(self, data: bytes) -> None:
        if self._closing or self._closed:
            return
        self._last_activity = time.monotonic()
        buf = self._buffer
        buf += data
        start = 0
        while len(buf) - start >= MBAP.size:
            _tid, protocol, length, _unit = MBAP.unpack_from(buf, start)
            if protocol != 0 or not MIN_LENGTH <= length <= MAX_LENGTH:
                self._not_modbus(protocol, length)
                break
            end = start + 6 + length
            if end > len(buf):
                break
            self._requests.append(bytes(buf[start:end]))
            start = end
        del buf[:start]
        if self._requests:
            self._wake.set()
        if len(self._requests) >= QUEUE_PAUSE and self._reading:
            self._reading = False
            self.transport.pause_reading()

    def pause_writing(self) -> None:
        self._writable.clear()

    def resume_writing(self) -> None:
        self._writable.set()

    def connection_lost(self, exc) -> None:
        self._closed = True
        self._wake.set()
        self._writable.set()
        if self._idle_timer is not None:
            self._idle_timer.cancel()
        if self.listener.active_connections.get(self.peer) is self:
            del self.listener.active_connections[self.peer]

    # --- serving --------------------------------------------------------------------------------
    async def _serve(self) -> None:
        while not self._closed:
            if not self._requests:
                if self._closing:
                    self.transport.close()  # after the answers already written
                    return
                self._wake.clear()
                await self._wake.wait()
                continue
            try:
                response = await self.listener.answer(self._requests.popleft(), self)
            except Exception:  # noqa: BLE001 - a bug costs this connection, not the server
                log.exception("PLC client %s: request failed; connection closed", self.peer)
                self.transport.abort()
                return
            await self._writable.wait()  # the client reads its answers before it gets more
            if self._closed:
                return
            self.transport.write(response)
            self._last_activity = time.monotonic()
            if not self._reading and not self._closing and len(self._requests) <= QUEUE_PAUSE // 2:
                self._reading = True
                self.transport.resume_reading()
            await asyncio.sleep(0)  # let the loop run: other connections, the mailbox reset, the heartbeat

    def _not_modbus(self, protocol: int, length: int) -> None:
        listener = self.listener
        listener.counters.bad_frames += 1
        listener.bursts("PLC connections closed for bytes that are not Modbus TCP",
                        "PLC client %s sent bytes that are not a Modbus TCP frame (protocol id %d, length %d; "
                        "Modbus TCP has protocol id 0 and length 2..254): its connection is closed after the "
                        "requests before them are answered; the client must reconnect", self.peer, protocol, length)
        self._closing = True
        self._buffer.clear()
        if self._reading:
            self._reading = False
            self.transport.pause_reading()
        self._wake.set()

    def _arm_idle(self, delay: float) -> None:
        self._idle_timer = asyncio.get_running_loop().call_later(delay, self._idle_check)

    def _idle_check(self) -> None:
        timeout = self.listener.idle_timeout_s
        idle = time.monotonic() - self._last_activity
        if idle < timeout:
            self._arm_idle(timeout - idle)
            return
        self.listener.counters.idle_closed += 1
        self.listener.bursts("PLC connections closed when idle", "PLC client %s closed: no request and no "
                             "answer read for %g s (plc.idle_timeout_s)", self.peer, timeout, level=logging.INFO)
        self.transport.abort()
