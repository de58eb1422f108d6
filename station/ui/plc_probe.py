"""What the Station page can honestly know of a PLC server it does not run: `station serve` runs on
its own, so the screen looks at it from outside, as a PLC would, and only reads.

:func:`probe`: does ``plc.host:plc.port`` accept a Modbus TCP connection, and if so, the register
map's ``state``, ``fault_code``, ``heartbeat``, ``cycle_counter`` and ``map_version`` (one FC3 read of
registers 100..112, then a second read of the heartbeat a moment later: advancing or stopped).
Never a write; a 0.5 s timeout and no retries, so a missing server costs the page little.
"""

from __future__ import annotations

import logging
import time

from station.plc import register_map as rm

TIMEOUT_S = 0.5
HEARTBEAT_WAIT_S = 0.3   # the server's heartbeat ticks every 0.1 s by default (PlcDevice.heartbeat_s)
ANY_ADDRESS = ("0.0.0.0", "::", "")  # a server bound to every address is reached on loopback
FIRST = rm.FIELDS["state"].address                                  # 100
COUNT = rm.FIELDS["map_version"].address - FIRST + 1                # 100..112


def _read(client, address: int, count: int, device_id: int) -> list[int] | str:
    """The registers, or why there are none (a sentence)."""
    try:
        r = client.read_holding_registers(address, count=count, device_id=device_id)
    except Exception as e:  # noqa: BLE001 - pymodbus raises its own and socket errors; the page says which
        return f"no answer to a read ({type(e).__name__}: {e})"
    if r.isError():
        return f"the read was refused ({r})"
    return list(r.registers)


def probe(host: str, port: int, device_id: int = 1, *, timeout_s: float = TIMEOUT_S,
          heartbeat_wait_s: float = HEARTBEAT_WAIT_S) -> dict:
    """{listening, message, state, heartbeat, heartbeat_advancing, map_version, ...} of the PLC
    server at host:port, as one looking from outside can know them."""
    from pymodbus.client import ModbusTcpClient

    where = f"{host}:{port}"
    target = "127.0.0.1" if host in ANY_ADDRESS else host
    out = {"address": where, "listening": False, "state": None, "fault_code": None, "heartbeat": None,
           "heartbeat_advancing": None, "cycle_counter": None, "map_version": None}
    quiet = logging.getLogger("pymodbus")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # a closed port is an answer here, not an error for the log
    client = ModbusTcpClient(target, port=port, timeout=timeout_s, retries=0)
    try:
        if not client.connect():
            out["message"] = f"no PLC server listening at {where}"
            return out
        out["listening"] = True
        first = _read(client, FIRST, COUNT, device_id)
        if isinstance(first, str):
            out["message"] = (f"something accepts connections at {where} but it is not answering as the "
                              f"station's PLC server: {first}")
            return out
        reg = {name: first[rm.FIELDS[name].address - FIRST]
               for name in ("state", "fault_code", "heartbeat", "cycle_counter", "map_version")}
        out.update(reg, state=rm.STATES.get(reg["state"], f"unknown ({reg['state']})"))
        time.sleep(heartbeat_wait_s)
        again = _read(client, rm.FIELDS["heartbeat"].address, 1, device_id)
        if isinstance(again, str):
            beat = f"heartbeat {reg['heartbeat']}, then {again}"
        else:
            out["heartbeat_advancing"] = again[0] != reg["heartbeat"]
            beat = ("heartbeat advancing" if out["heartbeat_advancing"] else
                    f"heartbeat stopped at {reg['heartbeat']} (the server is not running its loop)")
        state = out["state"] + (f" (fault code {reg['fault_code']})" if out["state"] == "fault" else "")
        version = ("" if reg["map_version"] == rm.MAP_VERSION else
                   f"; register map version {reg['map_version']}, this screen knows {rm.MAP_VERSION}")
        out["message"] = f"PLC server at {where}: state {state}, {beat}{version}"
        return out
    finally:
        client.close()
        quiet.setLevel(level)


def plc_view(plc) -> dict:
    """The Station page's PLC card for the configuration's ``plc`` section."""
    if plc.transport != "tcp":
        return {"address": plc.serial_port, "listening": None,
                "message": f"the PLC link is serial (Modbus RTU on {plc.serial_port}); the screen does not open the "
                           "port `station serve` holds, so its state is not shown here"}
    return probe(plc.host, plc.port, plc.device_id)
