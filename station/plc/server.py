"""The Modbus transports: TCP (default 127.0.0.1:5020) or RTU on a serial line, same map.

* **TCP** is the station's own asyncio transport (:mod:`station.plc.tcp`): pipelined requests
  answered once each, in order, with their own transaction ids; the allow-list with read-only
  clients, a connection limit and an idle timeout. The station answers to its device id and to
  0 and 255 (the "this device" unit ids of Modbus/TCP); any other id gets exception 0x0B
  (gateway target failed to respond).
* **RTU** stays on pymodbus 3.16's serial server: the station answers only to its own id and
  stays silent otherwise, as a device on a shared RS-485 line must (pymodbus alone logs a
  traceback and answers exception 4). RTU frames are delimited by silence; pymodbus hunts for a
  frame in whatever it has buffered, so noise can hold a later good frame hostage; the handler
  here drops a partial buffer after ``rtu_gap_s`` of silence (3.5 characters by the standard,
  widened for USB adapters), so the next request after noise is answered.

Both answer the same functions (:mod:`station.plc.functions`) from the same register memory.
"""

from __future__ import annotations

import asyncio
import logging
import time

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.framer import FramerType
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.server import ModbusSerialServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator.simcore import SimCore

from station.errors import PlcError
from station.plc.clients import ClientAccess
from station.plc.device import PlcDevice
from station.plc.functions import (FUNCTIONS, ILLEGAL_DATA_VALUE, ILLEGAL_FUNCTION, RequestHandler,
                                   report_server_id)
from station.plc.log_bursts import BurstLog
from station.plc.tcp import ServerCounters, TcpListener

log = logging.getLogger("station.plc")
TCP_SELF_IDS = (0, 255)


def parse_allowed(entries) -> ClientAccess:
    """``plc.allowed_clients`` -> the access rules; raises ConfigError naming a bad entry."""
    return ClientAccess(entries)


class _Core(SimCore):
    """SimCore that knows which device ids it answers to and raises NoSuchIdException for the
    rest (pymodbus then answers 0x0B, or stays silent with ignore_missing_devices)."""

    def __init__(self, device, ids):
        super().__init__(device)
        runtime = self.devices[device.id]
        self.devices = {i: runtime for i in ids}

    def _check(self, device_id):
        if device_id not in self.devices:
            raise NoSuchIdException(f"device id {device_id} is not this station")

    async def async_getValues(self, device_id, func_code, address, count=1):
        self._check(device_id)
        return await super().async_getValues(device_id, func_code, address, count)

    async def async_setValues(self, device_id, func_code, address, values):
        self._check(device_id)
        return await super().async_setValues(device_id, func_code, address, values)


class _PduBytes(ModbusPDU):
    """A response PDU given as bytes (function code first), for pymodbus's serial framer."""

    def __init__(self, pdu: bytes, dev_id: int):
        super().__init__(dev_id=dev_id)
        self.function_code = pdu[0]
        self._data = pdu[1:]

    def encode(self) -> bytes:
        return self._data


class _MalformedRequest(ModbusPDU):
    """A framed request pymodbus could not decode (a count of 0, a byte count that does not
    match): it keeps the function code, so the answer can carry it."""

    def __init__(self, function_code: int):
        super().__init__()
        self.function_code = function_code


class _SerialDecoder(DecodePDU):
    """pymodbus's decoder returns None for a request it cannot decode, and its handler then
    answers with function code 0 ("80 01"); this one keeps the request's code."""

    def decode(self, frame: bytes) -> ModbusPDU | None:
        pdu = super().decode(frame)
        return _MalformedRequest(frame[0]) if pdu is None and frame else pdu


class _SerialHandler(ServerRequestHandler):
    """The serial line: other device ids, RTU silence framing, the station's functions only."""

    def __init__(self, owner, *args):
        super().__init__(owner, *args)
        self._plc = owner.plc_server
        self._last_rx = 0.0

    async def handle_request(self):
        pdu = self.last_pdu
        if pdu is None:
            return
        if pdu.dev_id not in self.server.context.devices:
            self._plc.counters.unknown_ids += 1
            log.info("request for device id %d ignored: this station is %d", pdu.dev_id,
                     self._plc.device.device_id)
            return  # silence: the line is shared
        answer = None
        if pdu.function_code not in FUNCTIONS:
            answer = ExceptionResponse(pdu.function_code, ExcCodes(ILLEGAL_FUNCTION))
        elif isinstance(pdu, _MalformedRequest):
            answer = ExceptionResponse(pdu.function_code, ExcCodes(ILLEGAL_DATA_VALUE))
        elif pdu.function_code == 17:
            answer = _PduBytes(report_server_id(self._plc.device.device_id), pdu.dev_id)
        if answer is None:
            await super().handle_request()
            return
        answer.transaction_id, answer.dev_id = pdu.transaction_id, pdu.dev_id
        self.server_send(answer, self.last_addr)

    def datagram_received(self, data, addr):
        now = time.monotonic()
        if self.recv_buffer and now - self._last_rx > self._plc.rtu_gap_s:
            log.debug("RTU: dropped %d bytes of an unfinished frame after silence", len(self.recv_buffer))
            self.recv_buffer = b""
        self._last_rx = now
        super().datagram_received(data, addr)


class _SerialServer(ModbusSerialServer):
    def callback_new_connection(self):
        return _SerialHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class PlcServer:
    """``device`` served on one transport. ``await start_tcp(...)`` or ``start_rtu(...)``,
    then ``await stop()``. ``counters`` counts what was refused or closed."""

    def __init__(self, device: PlcDevice, *, allowed_clients=(), max_connections: int = 8,
                 idle_timeout_s: float = 60.0, rtu_gap_s: float = 0.05):
        self.device = device
        self.clients = parse_allowed(allowed_clients)
        self.max_connections = max_connections
        self.idle_timeout_s = idle_timeout_s
        self.rtu_gap_s = rtu_gap_s
        self.counters = ServerCounters()
        self.bursts = BurstLog(log)
        self.server: TcpListener | _SerialServer | None = None
        self.address: str = ""

    @property
    def refused_clients(self) -> int:
        """Clients refused because plc.allowed_clients does not name them."""
        return self.counters.refused_clients

    @property
    def unknown_ids(self) -> int:
        return self.counters.unknown_ids

    def _core(self, ids) -> _Core:
        """The register memory, answering to ``ids``, bound to the device."""
        core = _Core(self.device.simdevice(), ids)
        start, _count, registers, _flags = core.devices[self.device.device_id].block["x"]
        self.device.bind(registers, start)
        return core

    async def start_tcp(self, host: str = "127.0.0.1", port: int = 5020) -> int:
        """Listen on host:port (port 0: any free port); returns the bound port."""
        ids = (self.device.device_id, *TCP_SELF_IDS)
        listener = TcpListener(RequestHandler(self._core(ids), self.device.device_id), ids,
                               clients=self.clients, max_connections=self.max_connections,
                               idle_timeout_s=self.idle_timeout_s, counters=self.counters, bursts=self.bursts)
        try:
            port = await listener.start(host, port)
        except (OSError, OverflowError) as e:
            raise PlcError(f"cannot open tcp {host}:{port} for the PLC ({e})",
                           hint="check that the address exists on this machine and the port is not in use; "
                                "plc.host/plc.port in config/station.yaml, or --host/--port") from None
        self._started(listener, f"tcp {host}:{port}")
        self.address = f"Modbus TCP {host}:{port}"
        return port

    async def start_rtu(self, port: str, *, baudrate: int = 19200, parity: str = "E") -> None:
        """Serve Modbus RTU on the serial device ``port`` (8 data bits, 1 stop bit)."""
        server = _SerialServer(self.device.simdevice(), framer=FramerType.RTU, port=port,
                               baudrate=baudrate, parity=parity, ignore_missing_devices=True,
                               reconnect_delay=1.0)
        server.plc_server = self
        server.decoder = _SerialDecoder(is_server=True)
        server.context = self._core((self.device.device_id,))
        where = f"serial line {port}"
        try:
            await server.serve_forever(background=True)
        except Exception as e:  # noqa: BLE001 - RuntimeError, OSError, termios.error, SerialException
            server.close()
            raise PlcError(f"cannot open {where} for the PLC ({e})",
                           hint="check that the serial device exists and is not in use, and its settings "
                                "(a pseudo-terminal takes parity N only); plc.* in config/station.yaml, "
                                "or --rtu/--baudrate/--parity") from None
        if not server.transport:
            raise PlcError(f"cannot open {where} for the PLC",
                           hint="check that the serial device exists and is not in use")
        self._started(server, where)
        self.address = f"Modbus RTU {port} {baudrate} 8{parity}1"

    def _started(self, server, where: str) -> None:
        self.server = server
        self.device.start_heartbeat()
        log.info("serving %s, device id %d", where, self.device.device_id)

    async def stop(self) -> None:
        await self.device.stop()
        if isinstance(self.server, TcpListener):
            await self.server.close()
        elif self.server is not None:
            await self.server.shutdown()
        self.server = None


async def wait_until(predicate, timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll ``predicate()`` on the loop until true or ``timeout_s`` passes."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(poll_s)
    return True
