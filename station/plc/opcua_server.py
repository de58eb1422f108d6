"""The station as an OPC UA server: the same device as the Modbus server, another protocol.

``station serve --opcua`` serves the one :class:`~station.plc.device.PlcDevice` over Modbus and
OPC UA at once: one register memory, one handshake table (station/plc/handshake.py), so a PLC
on Modbus and an MES on OPC UA see the same cycle, and either may drive it (the table refuses
what is not allowed now, whoever sends it). Library: asyncua, on the server's event loop.

Address space (namespace ``urn:wheel-alignment-station:plc``, docs/shop.md), under
``Objects/Station``:

* a variable for every station -> PLC field of the register map (station/plc/register_map.py,
  its name as node name): ``state``, ``fault_code``, ``fault_reason``, ``heartbeat``,
  ``cycle_counter``, ``result_valid``, every angle (``FL_toe_f32``: Float, NaN: no value; the
  int16 copies as Double in their unit, NaN: no value), pass/judged/warning bits, the roll and
  steer prompts, runout and steering results; plus ``state_name``, ``warnings`` (the texts of the
  last valid result) and ``station_name``. Read-only; subscriptions see each change.
* methods for the commands: ``Measure``, ``CalibrationCheck``, ``MeasureCompensated``,
  ``MeasureCaster`` (in: ``JobId``, ``VehicleSpec``: printable ASCII, up to 32 characters each),
  ``Acknowledge``, ``ResetFault``, ``InPosition``; out: ``RejectCode`` (0: accepted, else the
  handshake's refusal code, 501..508, as in ``reject_code``) and ``Message``. A call with the
  wrong arguments gets ``BadInvalidArgument`` / ``BadTypeMismatch`` and changes nothing.

The variables mirror the registers after every complete step of the device (a state entered,
a command refused: the device's listeners, on the loop, so no reader sees half a result) and
every 50 ms for the heartbeat and live readings.

Bound to 127.0.0.1 by default. On any other address ``opcua.users`` (user: SHA-256 of the
password) must name who may log in, and anonymous sessions are refused.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import ipaddress
import logging
import math

from station.errors import ConfigError, PlcBadJobId, PlcError
from station.plc import register_map as rm
from station.plc.device import PlcDevice
from station.plc.handshake import Event

log = logging.getLogger("station.plc.opcua")
NAMESPACE = "urn:wheel-alignment-station:plc"
MIRROR_S = 0.05
TEXT_LIMIT = 2 * rm.FIELDS["job_id"].count  # 32 characters
METHODS = {  # node name -> (command, takes job id and vehicle spec)
    "Measure": (Event.MEASURE, True),
    "CalibrationCheck": (Event.CALIBRATION_CHECK, True),
    "MeasureCompensated": (Event.MEASURE_COMPENSATED, True),
    "MeasureCaster": (Event.MEASURE_CASTER, True),
    "ResetFault": (Event.RESET_FAULT, False),
    "Acknowledge": (Event.ACKNOWLEDGE, False),
    "InPosition": (Event.IN_POSITION, False),
}


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_binding(host: str, users: dict) -> None:
    """ConfigError unless ``host`` is loopback or users are configured (a network needs a login)."""
    if not is_loopback(host) and not users:
        raise ConfigError(f"OPC UA on {host}: a server reachable from the network needs a login",
                          hint="name the users in opcua.users (user: SHA-256 hex of the password; docs/shop.md), "
                               "or keep opcua.host at 127.0.0.1")


def _import_asyncua():
    try:
        import asyncua  # noqa: F401
    except ImportError:
        raise PlcError("station serve --opcua needs the asyncua package",
                       hint="pip install asyncua (the station's `shop` extra)") from None
    from asyncua import Server, ua
    from asyncua.crypto.permission_rules import User, UserRole
    return Server, ua, User, UserRole


class _Users:
    """asyncua's user manager: username + password against opcua.users' SHA-256 digests."""

    def __init__(self, users: dict[str, str], User, UserRole):
        self.users, self.User, self.UserRole = users, User, UserRole

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if not self.users:
            return self.User(role=self.UserRole.User)  # loopback only (check_binding)
        digest = self.users.get(username or "")
        if digest is None or password is None:
            log.warning("OPC UA login refused for user %r", username)
            return None
        given = hashlib.sha256(password.encode() if isinstance(password, str) else bytes(password)).hexdigest()
        if not hmac.compare_digest(given, digest):
            log.warning("OPC UA login refused for user %r: wrong password", username)
            return None
        return self.User(role=self.UserRole.User, name=username)


def _kind(field: rm.Field) -> str:
    """The OPC UA type of a register-map field's variable."""
    return {"u16": "UInt16", "bits": "UInt16", "u32": "UInt32", "f32": "Float", "i16": "Double",
            "ascii": "String"}[field.type]


class OpcUaServer:
    """``device`` over OPC UA. ``await start()``, then ``await stop()``; ``endpoint`` is the URL."""

    def __init__(self, device: PlcDevice, *, host: str = "127.0.0.1", port: int = 4840,
                 users: dict[str, str] | None = None, station_name: str = "station"):
        self.device = device
        self.host, self.port = host, port
        self.users = dict(users or {})
        self.station_name = station_name
        self.endpoint = f"opc.tcp://{host}:{port}/station"
        self.calls = {"accepted": 0, "refused": 0, "bad": 0}
        self._server = None
        self._nodes: dict[str, object] = {}  # variable name -> NodeId
        self._last: dict[str, object] = {}
        self._mirror: asyncio.Task | None = None

    async def start(self) -> None:
        check_binding(self.host, self.users)
        Server, ua, User, UserRole = _import_asyncua()
        self.ua = ua
        server = Server(user_manager=_Users(self.users, User, UserRole))
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name(f"Wheel alignment station {self.station_name}")
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        server.set_identity_tokens([ua.UserNameIdentityToken] if self.users else [ua.AnonymousIdentityToken])
        ns = await server.register_namespace(NAMESPACE)
        station = await server.nodes.objects.add_object(ua.NodeId("Station", ns), ua.QualifiedName("Station", ns))
        values = self._values()
        for name, (value, vtype) in values.items():
            node = await station.add_variable(ua.NodeId(name, ns), ua.QualifiedName(name, ns),
                                              ua.Variant(value, getattr(ua.VariantType, vtype)))
            self._nodes[name] = node.nodeid
        self._last = {k: v for k, (v, _) in values.items()}
        text = ua.VariantType.String
        for name, (event, takes_text) in METHODS.items():
            inputs = []
            if takes_text:
                inputs = [self._argument("JobId", text, "job id / VIN, printable ASCII, up to 32 characters"),
                          self._argument("VehicleSpec", text, "vehicle spec id (empty: no pass/fail)")]
            outputs = [self._argument("RejectCode", ua.VariantType.UInt16,
                                      "0: accepted; else the refusal's code (501..508, as reject_code)"),
                       self._argument("Message", text, "why it was refused, or 'accepted'")]
            await station.add_method(ua.NodeId(name, ns), ua.QualifiedName(name, ns),
                                     self._method(event, takes_text), inputs, outputs)
        try:
            await server.start()
        except OSError as e:
            raise PlcError(f"cannot open OPC UA on {self.host}:{self.port} ({e.strerror or e})",
                           hint="check that the address exists on this machine and the port is not in use; "
                                "opcua.host/opcua.port in config/station.yaml, or --opcua-host/--opcua-port") from None
        self._server = server
        self.device.listeners.append(self.publish)
        self._mirror = asyncio.get_running_loop().create_task(self._mirror_loop())
        log.info("serving OPC UA at %s", self.endpoint)

    def _argument(self, name: str, vtype, doc: str):
        ua = self.ua
        arg = ua.Argument()
        arg.Name = name
        arg.DataType = ua.NodeId(vtype.value)
        arg.ValueRank = -1
        arg.Description = ua.LocalizedText(doc)
        return arg

    # --- the device's registers as values --------------------------------------------------------
    def _values(self) -> dict[str, tuple[object, str]]:
        """{variable name: (value, OPC UA type)} from the device's registers, in one synchronous read."""
        lo, hi = rm.STATION_AREA
        block = rm.decode_block(self.device.registers(lo, hi - lo), lo)
        out: dict[str, tuple[object, str]] = {}
        for f in rm.FIELDS.values():
            if f.writable or f.name not in block:
                continue
            kind, v = _kind(f), block[f.name]
            if kind in ("Float", "Double"):
                v = math.nan if v is None else float(v)
            elif kind == "String":
                v = v or ""
            out[f.name] = (v, kind)
        out["state_name"] = (rm.STATES.get(block["state"], "unknown"), "String")
        result = self.device.last_result
        warnings = list(getattr(result, "warnings", None) or []) if block["result_valid"] else []
        out["warnings"] = (warnings, "String")
        out["station_name"] = (self.station_name, "String")
        return out

    def publish(self) -> None:
        """Mirror the registers into the variables, in one synchronous step (no OPC UA request is
        served in between); subscriptions are told of each changed value."""
        if self._server is None:
            return
        ua = self.ua
        aspace = self._server.iserver.aspace
        loop = asyncio.get_running_loop()
        for name, (value, vtype) in self._values().items():
            old = self._last.get(name)
            if old == value or (isinstance(value, float) and isinstance(old, float)
                                and math.isnan(value) and math.isnan(old)):
                continue
            self._last[name] = value
            dv = ua.DataValue(ua.Variant(value, getattr(ua.VariantType, vtype)))
            attribute = aspace._nodes[self._nodes[name]].attributes[ua.AttributeIds.Value]
            attribute.value = dv  # what a Read returns from now on
            for handle, callback in list(attribute.datachange_callbacks.items()):
                loop.create_task(callback(handle, dv))  # subscriptions: notified after this step

    async def _mirror_loop(self) -> None:
        while True:
            await asyncio.sleep(MIRROR_S)
            try:
                self.publish()
            except Exception:  # noqa: BLE001 - the mirror must outlive a bad value
                log.exception("OPC UA mirror failed")

    # --- methods -----------------------------------------------------------------------------------
    def _method(self, event: Event, takes_text: bool):
        ua = self.ua

        def bad(code: str, why: str):
            """A malformed call: answered with a Bad status code, nothing changed."""
            self.calls["bad"] += 1
            log.warning("OPC UA call %s refused: %s", event.name.lower(), why)
            return ua.StatusCode(getattr(ua.StatusCodes, code))

        async def call(parent, *args):
            wanted = 2 if takes_text else 0
            if len(args) != wanted:
                return bad("BadArgumentsMissing" if len(args) < wanted else "BadTooManyArguments",
                           f"{len(args)} arguments, {wanted} expected")
            texts = []
            for a in args:
                value = a.Value if isinstance(a, ua.Variant) else a
                if value is not None and not isinstance(value, str):
                    return bad("BadTypeMismatch", f"{type(value).__name__} where text belongs")
                texts.append(value or "")
            plc = self.device.registers(*rm.PLC_AREA) if takes_text else [0] * (rm.PLC_AREA[1] - rm.PLC_AREA[0])
            refused: PlcError | None = None
            for name, text in zip(("job_id", "vehicle_spec"), texts):
                if not (text.isascii() and text.isprintable() and len(text) <= TEXT_LIMIT):
                    refused = PlcBadJobId(f"trigger refused: {name} is not printable ASCII of up to {TEXT_LIMIT} "
                                          "characters")
                    break
                f = rm.FIELDS[name]
                plc[f.address:f.end] = rm.ascii_to_regs(text, f.count)
            if refused is not None:  # counted as the handshake counts a refusal
                self.device.refuse(refused, event.name.lower())
            else:
                refused = self.device.submit(event.value, plc)
                self.publish()  # the state the call led to is what the next read sees
            self.calls["refused" if refused else "accepted"] += 1
            code, message = (0, "accepted") if refused is None else (refused.code, str(refused))
            return [ua.Variant(code, ua.VariantType.UInt16), ua.Variant(message, ua.VariantType.String)]

        return call

    async def stop(self) -> None:
        if self.publish in self.device.listeners:
            self.device.listeners.remove(self.publish)
        if self._mirror is not None:
            self._mirror.cancel()
            try:
                await self._mirror
            except asyncio.CancelledError:
                pass
        if self._server is not None:
            server, self._server = self._server, None
            await server.stop()
