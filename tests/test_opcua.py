"""The OPC UA server (`station serve --dry-run --opcua`) driven by real OPC UA clients: asyncua's
own client, and the legacy python-opcua client (another code base) where it is installed.
Every result is checked value by value against the dry run's synthetic result of its job, and the
Modbus server of the same process sees the same device (one handshake table for both)."""

from __future__ import annotations

import asyncio
import hashlib
import math
import socket
import struct
import subprocess
import sys
import time

import pytest
import yaml

from station.plc import register_map as rm
from station.plc.runner import CycleRequest, synthetic_result
from tests.serve_process import free_port

asyncua = pytest.importorskip("asyncua", reason="asyncua (the `shop` extra) is not installed")
from asyncua import Client, ua  # noqa: E402

PY = sys.executable
NS = "urn:wheel-alignment-station:plc"


def _start(*extra: str, config: str | None = None):
    mb, op = free_port(), free_port()
    cmd = [PY, "-m", "station.cli", *(["--config", config] if config else []), "serve", "--dry-run",
           "--port", str(mb), "--opcua", "--opcua-port", str(op), "--log-level", "warning", *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if "station serving" not in line:
        proc.kill()
        raise AssertionError(line + proc.communicate(timeout=10)[1])
    assert f"OPC UA opc.tcp://127.0.0.1:{op}/station" in line and f"Modbus TCP 127.0.0.1:{mb}" in line
    return proc, mb, op


def _stop(proc) -> tuple[str, str]:
    proc.terminate()
    try:
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    return out, err


@pytest.fixture(scope="module")
def server():
    proc, mb, op = _start()
    yield mb, op
    _stop(proc)


def _f32(x: float) -> float:
    return struct.unpack(">f", struct.pack(">f", x))[0]


class Station:
    """The station's nodes on one asyncua client connection."""

    def __init__(self, client: Client, ns: int):
        self.client, self.ns = client, ns
        self.obj = client.get_node(ua.NodeId("Station", ns))

    def var(self, name: str):
        return self.client.get_node(ua.NodeId(name, self.ns))

    async def read(self, *names: str) -> dict:
        values = await self.client.read_values([self.var(n) for n in names])
        return dict(zip(names, values))

    async def call(self, method: str, *args):
        return await self.obj.call_method(ua.QualifiedName(method, self.ns), *args)

    async def wait_end(self, timeout_s: float = 10.0) -> int:
        deadline = time.monotonic() + timeout_s
        while (state := await self.var("state").read_value()) not in (2, 3):
            assert time.monotonic() < deadline, f"still in state {state}"
            await asyncio.sleep(0.002)
        return state


async def _connect(port: int, **login) -> tuple[Client, Station]:
    client = Client(f"opc.tcp://127.0.0.1:{port}/station", timeout=5)
    if login:
        client.set_user(login["user"])
        client.set_password(login["password"])
    await client.connect()
    return client, Station(client, await client.get_namespace_index(NS))


async def _handshake(st: Station, job: str, spec: str = "") -> str:
    """One measure cycle through the handshake; checks every value; 'done' or 'fault'."""
    assert await st.call("Measure", job, spec) == [0, "accepted"]
    state = await st.wait_end()
    names = ["result_valid", "fault_code", "fault_reason", "result_job_id", "warnings", "state_name",
             "pass_bits", "judged_bits", "station_warning_bits", "active_command"] + \
            [f"{a.replace('.', '_')}_f32" for a in rm.ANGLES] + [f"{a.replace('.', '_')}_i16" for a in rm.ANGLES]
    v = await st.read(*names)
    assert v["active_command"] == 1
    n = int(job.rsplit("-", 1)[1])
    if n % 10 == 0:  # the dry run's on-purpose failure
        assert state == 3 and v["state_name"] == "fault" and v["result_valid"] == 0
        assert v["fault_code"] == 401 and f"job {n}" in v["fault_reason"]
        assert all(math.isnan(v[f"{a.replace('.', '_')}_f32"]) for a in rm.ANGLES)
    else:
        expected = synthetic_result(CycleRequest("measure", job, spec or None, 0))
        assert state == 2 and v["state_name"] == "done" and v["result_valid"] == 1 and v["fault_code"] == 0
        assert v["result_job_id"] == job and v["warnings"] == ["dry run: synthetic result, no cameras"]
        for a in rm.ANGLES:
            key = a.replace(".", "_")
            assert v[f"{key}_f32"] == _f32(expected.angle(a)), a
            assert v[f"{key}_i16"] == pytest.approx(round(expected.angle(a) * 100) / 100, abs=1e-9), a
        assert v["station_warning_bits"] & 1
        if spec:
            assert v["judged_bits"] & (1 << rm.OVERALL_BIT)
    assert await st.call("Acknowledge") == [0, "accepted"]
    assert await st.var("state").read_value() == 0
    return "done" if state == 2 else "fault"


def test_handshake_with_asyncua_client(server):
    _, op = server

    async def run():
        client, st = await _connect(op)
        try:
            v = await st.read("map_version", "station_name", "state")
            assert v == {"map_version": rm.MAP_VERSION, "station_name": "simulated bay 1", "state": 0}
            ends = [await _handshake(st, f"OPC-{i:06d}", "dodge-caravan-2007" if i % 3 else "") for i in range(1, 22)]
            assert ends.count("fault") == 2 and ends.count("done") == 19
            counter = await st.var("cycle_counter").read_value()
            assert counter >= 21
        finally:
            await client.disconnect()
    asyncio.run(run())


def test_refusals_are_the_handshake_tables(server):
    _, op = server

    async def run():
        client, st = await _connect(op)
        try:
            before = await st.var("reject_count").read_value()
            assert (await st.call("Acknowledge"))[0] == 503
            assert (await st.call("InPosition"))[0] == 508
            assert await st.call("Measure", "OPC-000031", "") == [0, "accepted"]
            await st.wait_end()
            code, message = await st.call("Measure", "OPC-000032", "")
            assert code == 502 and "acknowledge" in message
            code, message = await st.call("MeasureCaster", "OPC-000033", "")
            assert code == 502
            assert (await st.call("ResetFault"))[0] == 503  # done, not fault
            v = await st.read("reject_code", "reject_count", "result_job_id", "state")
            assert v == {"reject_code": 503, "reject_count": before + 5, "result_job_id": "OPC-000031", "state": 2}
            assert (await st.call("Acknowledge"))[0] == 0
            code, message = await st.call("Measure", "JOB\u00e9", "")  # not ASCII
            assert code == 506 and "ASCII" in message
            code, _ = await st.call("Measure", "J" * 33, "")  # too long for the registers
            assert code == 506
            assert await st.var("state").read_value() == 0
        finally:
            await client.disconnect()
    asyncio.run(run())


def test_garbage_calls_get_bad_status_and_change_nothing(server):
    _, op = server

    async def run():
        client, st = await _connect(op)
        try:
            before = await st.read("state", "cycle_counter", "reject_count")
            for args, status in ((("JOB-1",), "BadArgumentsMissing"), (("a", "b", "c"), "BadTooManyArguments"),
                                 ((5, ""), "BadTypeMismatch"), ((b"\x00\xff", ""), "BadTypeMismatch")):
                with pytest.raises(ua.UaStatusCodeError) as e:
                    await st.call("Measure", *args)
                assert type(e.value).__name__ == status, (args, e.value)
            with pytest.raises(ua.UaStatusCodeError):
                await st.call("Acknowledge", "extra")
            with pytest.raises(ua.UaStatusCodeError):  # no such method
                await st.obj.call_method(ua.NodeId("Explode", st.ns))
            with pytest.raises(ua.UaStatusCodeError):  # the variables are read-only
                await st.var("state").write_value(ua.DataValue(ua.Variant(2, ua.VariantType.UInt16)))
            assert await st.read("state", "cycle_counter", "reject_count") == before
            assert await _handshake(st, "OPC-000041") == "done"  # still serving
        finally:
            await client.disconnect()
        # bytes that are not OPC UA on a fresh connection: dropped, the server goes on
        with socket.create_connection(("127.0.0.1", op), timeout=5) as s:
            s.sendall(b"GET / HTTP/1.1\r\n\r\n" + bytes(range(256)) * 8)
            try:
                s.recv(100)
            except OSError:
                pass
        client, st = await _connect(op)
        try:
            assert await _handshake(st, "OPC-000042") == "done"
        finally:
            await client.disconnect()
    asyncio.run(run())


def test_modbus_and_opcua_share_one_device(server):
    """A cycle started over OPC UA is seen (and acknowledged) over Modbus, and the other way round;
    a subscription sees the state move."""
    from pymodbus.client import ModbusTcpClient
    mb, op = server

    async def run():
        client, st = await _connect(op)
        seen: list[int] = []

        class Handler:
            def datachange_notification(self, node, val, data):
                seen.append(val)

        sub = await client.create_subscription(20, Handler())
        await sub.subscribe_data_change(st.var("state"))
        plc = ModbusTcpClient("127.0.0.1", port=mb, timeout=3)
        assert plc.connect()
        try:
            assert await st.call("Measure", "OPC-000051", "") == [0, "accepted"]
            await st.wait_end()
            regs = plc.read_holding_registers(100, count=125, device_id=1).registers
            block = rm.decode_block(regs)
            assert block["state"] == 2 and block["result_job_id"] == "OPC-000051"
            expected = synthetic_result(CycleRequest("measure", "OPC-000051", None, 0))
            assert rm.angles_from_block(block)["FL.toe"] == _f32(expected.angle("FL.toe"))
            # the PLC may not trigger over a result the MES has not acknowledged: the same table
            assert plc.write_registers(0, [1] + rm.ascii_to_regs("MB-000052", 16), device_id=1).isError()
            assert plc.write_register(0, 4, device_id=1).function_code == 6  # acknowledged over Modbus
            assert await st.var("state").read_value() == 0
            assert not plc.write_registers(0, [1] + rm.ascii_to_regs("MB-000052", 16), device_id=1).isError()
            await st.wait_end()
            assert await st.var("result_job_id").read_value() == "MB-000052"
            assert await st.call("Acknowledge") == [0, "accepted"]
            await asyncio.sleep(0.2)
            assert 1 in seen and 2 in seen and seen[-1] == 0
        finally:
            plc.close()
            await sub.delete()
            await client.disconnect()
    asyncio.run(run())


def test_second_independent_client_python_opcua(server):
    opcua = pytest.importorskip("opcua", reason="the legacy python-opcua client is not installed (optional)")
    _, op = server
    client = opcua.Client(f"opc.tcp://127.0.0.1:{op}/station", timeout=5)
    client.connect()
    try:
        ns = client.get_namespace_index(NS)
        st = client.get_node(opcua.ua.NodeId("Station", ns))
        state = client.get_node(opcua.ua.NodeId("state", ns))
        for job in ("PY-000061", "PY-000070"):
            assert st.call_method(opcua.ua.QualifiedName("Measure", ns), job, "") == [0, "accepted"]
            deadline = time.monotonic() + 10
            while state.get_value() not in (2, 3):
                assert time.monotonic() < deadline
                time.sleep(0.002)
            toe = client.get_node(opcua.ua.NodeId("FR_camber_f32", ns)).get_value()
            if job.endswith("70"):
                assert state.get_value() == 3 and math.isnan(toe)
                assert client.get_node(opcua.ua.NodeId("fault_code", ns)).get_value() == 401
            else:
                assert toe == _f32(synthetic_result(CycleRequest("measure", job, None, 0)).angle("FR.camber"))
            assert st.call_method(opcua.ua.QualifiedName("Acknowledge", ns)) == [0, "accepted"]
    finally:
        client.disconnect()


def _config(tmp_path, **opcua) -> str:
    from station.config import DEFAULT_CONFIG
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["vehicle_specs"] = str(DEFAULT_CONFIG.parent / data.get("vehicle_specs", "vehicles.yaml"))
    data["calibration"]["box"] = str(DEFAULT_CONFIG.parent / data["calibration"].get("box", "box.yaml"))
    data["opcua"] = opcua
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_login_required_beyond_loopback_and_checked(tmp_path):
    from station.cli import main
    assert main(["serve", "--dry-run", "--opcua", "--opcua-host", "0.0.0.0"]) == 2  # no users: refused
    assert main(["--config", _config(tmp_path, users={"mes": "xyz"}), "serve", "--dry-run", "--opcua"]) == 2
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    try:
        assert main(["serve", "--dry-run", "--port", "0", "--opcua", "--opcua-port", str(busy.getsockname()[1])]) == 2
    finally:
        busy.close()
    cfg = _config(tmp_path, users={"mes": hashlib.sha256(b"line-3-secret").hexdigest()})
    proc, _, op = _start(config=cfg)
    try:
        async def run():
            for login in ({}, {"user": "mes", "password": "wrong"}, {"user": "nobody", "password": "line-3-secret"}):
                with pytest.raises(ua.UaStatusCodeError):  # anonymous and wrong logins are refused
                    c, _ = await _connect(op, **login)
                    await c.disconnect()
            client, st = await _connect(op, user="mes", password="line-3-secret")
            try:
                assert await _handshake(st, "OPC-000071") == "done"
            finally:
                await client.disconnect()
        asyncio.run(run())
    finally:
        _stop(proc)
