"""The Modbus transports: TCP (default 127.0.0.1:5020) or RTU on a serial line, same map.

On top of pymodbus 3.16:

* **unknown device id**: over TCP the station answers to its device id and to 0 and 255 (the
  "this device" unit ids of Modbus/TCP); any other id gets exception 0x0B (gateway target failed
  to respond). On RTU it answers only to its own id and stays silent otherwise, as a device on a
  shared RS-485 line must (pymodbus alone logs a traceback and answers exception 4).
* **garbage on the serial line**: RTU frames are delimited by silence. pymodbus hunts for a
  frame in whatever it has buffered, so noise can hold a later good frame hostage; the handler
  here drops a partial buffer after ``rtu_gap_s`` of silence (3.5 characters by the standard,
  widened for USB adapters), so the next request after noise is answered.
* **allow-list**: ``allowed_clients`` (IP addresses or networks); a TCP client from elsewhere is
  disconnected at once and logged.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
import time

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.framer import FramerType
from pymodbus.pdu import ExceptionResponse
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator.simcore import SimCore
from pymodbus.transport import CommType

from station.errors import ConfigError, PlcError
from station.plc.device import PlcDevice

log = logging.getLogger("station.plc")
TCP_SELF_IDS = (0, 255)


def parse_allowed(entries) -> list:
    """Allow-list entries -> ip networks; raises ConfigError naming a bad entry."""
    nets = []
    for entry in entries or ():
        try:
            nets.append(ipaddress.ip_network(str(entry), strict=False))
        except ValueError:
            raise ConfigError(f"plc.allowed_clients: {entry!r} is not an IP address or network",
                              hint="write addresses like 127.0.0.1 or networks like 10.0.0.0/24") from None
    return nets


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


def _keepalive(sock) -> None:
    """TCP keepalive on a PLC connection: a PLC that was switched off without closing its
    connection is noticed within about 25 s instead of leaving a dead connection open forever."""
    if sock is None or sock.family not in (socket.AF_INET, socket.AF_INET6):
        return
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for name, value in (("TCP_KEEPIDLE", 10), ("TCP_KEEPINTVL", 5), ("TCP_KEEPCNT", 3)):
        if hasattr(socket, name):
            sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, name), value)


class _Handler(ServerRequestHandler):
    """One connection (TCP) or the serial line: allow-list and RTU silence framing."""

    def __init__(self, owner, *args):
        super().__init__(owner, *args)
        self._plc = owner.plc_server
        self._last_rx = 0.0

    def connection_made(self, transport):
        super().connection_made(transport)
        _keepalive(transport.get_extra_info("socket"))
        peer = transport.get_extra_info("peername")
        if self._plc.allowed and isinstance(peer, tuple):
            ip = ipaddress.ip_address(peer[0])
            if not any(ip in net for net in self._plc.allowed):
                self._plc.refused_clients += 1
                log.warning("PLC client %s refused: not in plc.allowed_clients", peer[0])
                self.close()

    async def handle_request(self):
        pdu = self.last_pdu
        if pdu is not None and pdu.dev_id not in self.server.context.devices:
            self._plc.unknown_ids += 1
            log.info("request for device id %d ignored: this station is %d", pdu.dev_id,
                     self._plc.device.device_id)
            if self.comm_params.comm_type != CommType.SERIAL:  # RTU: silence, the line is shared
                response = ExceptionResponse(pdu.function_code, ExcCodes.GATEWAY_NO_RESPONSE)
                response.transaction_id, response.dev_id = pdu.transaction_id, pdu.dev_id
                self.server_send(response, self.last_addr)
            return
        await super().handle_request()

    def datagram_received(self, data, addr):
        now = time.monotonic()
        if (self.comm_params.comm_type == CommType.SERIAL and self.recv_buffer
                and now - self._last_rx > self._plc.rtu_gap_s):
            log.debug("RTU: dropped %d bytes of an unfinished frame after silence", len(self.recv_buffer))
            self.recv_buffer = b""
        self._last_rx = now
        super().datagram_received(data, addr)


class _TcpServer(ModbusTcpServer):
    def callback_new_connection(self):
        return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class _SerialServer(ModbusSerialServer):
    def callback_new_connection(self):
        return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class PlcServer:
    """``device`` served on one transport. ``await start_tcp(...)`` or ``start_rtu(...)``,
    then ``await stop()``."""

    def __init__(self, device: PlcDevice, *, allowed_clients=(), rtu_gap_s: float = 0.05):
        self.device = device
        self.allowed = parse_allowed(allowed_clients)
        self.rtu_gap_s = rtu_gap_s
        self.refused_clients = 0
        self.unknown_ids = 0
        self.server = None
        self.address: str = ""

    def _install(self, server, ids) -> None:
        server.plc_server = self
        core = _Core(self.device.simdevice(), ids)
        server.context = core
        start, _count, registers, _flags = core.devices[self.device.device_id].block["x"]
        self.device.bind(registers, start)

    async def start_tcp(self, host: str = "127.0.0.1", port: int = 5020) -> int:
        """Listen on host:port (port 0: any free port); returns the bound port."""
        server = _TcpServer(self.device.simdevice(), address=(host, port))
        self._install(server, (self.device.device_id, *TCP_SELF_IDS))
        await self._listen(server, f"tcp {host}:{port}")
        port = server.transport.sockets[0].getsockname()[1]
        self.address = f"Modbus TCP {host}:{port}"
        return port

    async def start_rtu(self, port: str, *, baudrate: int = 19200, parity: str = "E") -> None:
        """Serve Modbus RTU on the serial device ``port`` (8 data bits, 1 stop bit)."""
        server = _SerialServer(self.device.simdevice(), framer=FramerType.RTU, port=port,
                               baudrate=baudrate, parity=parity, ignore_missing_devices=True,
                               reconnect_delay=1.0)
        self._install(server, (self.device.device_id,))
        await self._listen(server, f"serial line {port}")
        self.address = f"Modbus RTU {port} {baudrate} 8{parity}1"

    async def _listen(self, server, where: str) -> None:
        try:
            await server.serve_forever(background=True)
        except Exception as e:  # noqa: BLE001 - RuntimeError, OSError, termios.error, SerialException
            server.close()
            raise PlcError(f"cannot open {where} for the PLC ({e})",
                           hint="check that the address or serial device exists and is not in use, "
                                "and its settings (a pseudo-terminal takes parity N only); "
                                "plc.* in config/station.yaml, or --host/--port/--rtu/--parity") from None
        if not server.transport:
            raise PlcError(f"cannot open {where} for the PLC",
                           hint="check that the address or serial device exists and is not in use")
        self.server = server
        self.device.start_heartbeat()
        log.info("serving %s, device id %d", where, self.device.device_id)

    async def stop(self) -> None:
        await self.device.stop()
        if self.server:
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
