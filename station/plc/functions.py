"""The Modbus functions the station answers, and how one request PDU is checked and answered.

Transport-free: a request PDU (function code + data, as bytes) in, a response PDU out. The
register memory and the handshake stay in pymodbus's datastore (:class:`station.plc.device.PlcDevice`
behind a SimCore); this module decides what reaches it. The order of the checks is the one of
the Modbus Application Protocol specification (V1.1b3, figure 9): the function code (exception
1), then the request's quantity and length (exception 3), then the addresses (exception 2, by
the datastore), then the execution (exception 4 for a fault inside the station).

An exception response carries the request's function code with its high bit set. A request
whose function code already has the high bit set (128..255: the range the specification reserves
for exception responses) is answered exception 1 with that same function code byte.
"""

from __future__ import annotations

import logging
import struct

from pymodbus.pdu import DecodePDU

from station.plc import register_map as rm

log = logging.getLogger("station.plc")

# Exception codes (Modbus Application Protocol, section 7)
ILLEGAL_FUNCTION, ILLEGAL_DATA_ADDRESS, ILLEGAL_DATA_VALUE, SERVER_DEVICE_FAILURE = 1, 2, 3, 4
GATEWAY_TARGET_FAILED = 0x0B
READ_ONLY_CLIENT = ILLEGAL_FUNCTION  # a write from a client that may only read

READ_FUNCTIONS = {3: "read holding registers", 4: "read input registers (the same map)",
                  17: "report server id"}
WRITE_FUNCTIONS = {6: "write single register", 16: "write multiple registers"}
FUNCTIONS = {**READ_FUNCTIONS, **WRITE_FUNCTIONS}
NOT_IMPLEMENTED = {1: "read coils", 2: "read discrete inputs", 5: "write single coil",
                   15: "write multiple coils", 22: "mask write register",
                   23: "read/write multiple registers", 43: "read device identification"}
MAX_READ, MAX_WRITE = 125, 123  # registers per request (the specification's limits)

IDENTIFICATION = f"wheel alignment station, PLC register map {rm.MAP_VERSION}"
RUN_INDICATOR_ON = 0xFF


def exception_pdu(function_code: int, code: int) -> bytes:
    """The exception response to a request with ``function_code``."""
    return bytes([(function_code | 0x80) & 0xFF, code])


def request_error(pdu: bytes) -> int | None:
    """The exception code that answers ``pdu`` before it reaches the registers, or None when it
    is a well-formed request of a function the station implements."""
    fc = pdu[0]
    if fc not in FUNCTIONS:
        return ILLEGAL_FUNCTION
    n = len(pdu)
    if fc in (3, 4):
        ok = n == 5 and 1 <= struct.unpack_from(">H", pdu, 3)[0] <= MAX_READ
    elif fc == 6:
        ok = n == 5
    elif fc == 16:
        ok = n >= 6 and 1 <= (count := struct.unpack_from(">H", pdu, 3)[0]) <= MAX_WRITE \
            and pdu[5] == 2 * count and n == 6 + pdu[5]
    else:  # 17
        ok = n == 1
    return None if ok else ILLEGAL_DATA_VALUE


def report_server_id(device_id: int) -> bytes:
    """Function 17's answer: byte count, server id (the device id), run indicator (on), then the
    station's identification text."""
    data = bytes([device_id, RUN_INDICATOR_ON]) + IDENTIFICATION.encode("ascii")
    return bytes([17, len(data)]) + data


class RequestHandler:
    """Answers request PDUs against the datastore ``core`` (a SimCore holding the station's
    registers, the device's action callback inside)."""

    def __init__(self, core, device_id: int):
        self.core = core
        self.device_id = device_id
        self._decoder = DecodePDU(is_server=True)

    async def answer(self, pdu: bytes, unit_id: int, transaction_id: int = 0) -> bytes:
        """The response PDU to a checked request (:func:`request_error` gave None) addressed to
        one of the ids this station answers."""
        fc = pdu[0]
        if fc == 17:
            return report_server_id(self.device_id)
        request = self._decoder.decode(pdu)
        if request is None:  # request_error lets nothing through that pymodbus cannot decode
            return exception_pdu(fc, ILLEGAL_DATA_VALUE)
        request.dev_id, request.transaction_id = unit_id, transaction_id
        try:
            response = await request.datastore_update(self.core, unit_id)
        except Exception:  # noqa: BLE001 - a bug must cost one answer, not the connection
            log.exception("function %d request failed inside the station", fc)
            return exception_pdu(fc, SERVER_DEVICE_FAILURE)
        return bytes([response.function_code]) + response.encode()


def markdown_table() -> str:
    """The function codes for docs/plc.md."""
    rows = ["| function | name | answer |", "|---:|---|---|"]
    for fc in sorted({**FUNCTIONS, **NOT_IMPLEMENTED}):
        if fc in FUNCTIONS:
            answer = "yes" + ("; refused (exception 1) to a client that may only read" if fc in WRITE_FUNCTIONS else "")
            name = FUNCTIONS[fc]
        else:
            answer, name = "exception 1 (illegal function)", NOT_IMPLEMENTED[fc]
        rows.append(f"| {fc} | {name} | {answer} |")
    rows.append("| any other | | exception 1 (illegal function), with the request's function code + 0x80 "
                "(a code of 128..255 unchanged) |")
    return "\n".join(rows) + "\n"
