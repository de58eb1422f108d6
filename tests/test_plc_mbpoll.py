"""A third-party Modbus master nobody here wrote - Debian's `mbpoll` (libmodbus) - drives a cycle:
writes the job id and the command register, reads the result registers as big-endian float32 and
as int16, and gets the right Modbus exceptions for bad writes. Over TCP and over RTU (socat)."""

import shutil
import subprocess
import time

import pytest

from station.plc import register_map as rm
from station.plc.background import BackgroundServer
from station.plc.device import PlcDevice
from station.plc.runner import CycleRequest, dry_run_runner, synthetic_result
from tests.mbpoll_cli import mbpoll, parse, signed

pytestmark = pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed (apt-get install mbpoll)")
JOB = "WVWZZZ1KZAW000017"


def wait_state(target: list[str], state: str, count: int, timeout_s: float = 10.0) -> dict:
    """Poll the status registers 100.. (``count`` of them) with mbpoll until ``state`` or the
    timeout; the last read {address: text}."""
    deadline = time.monotonic() + timeout_s
    while True:
        status = parse(mbpoll(target[:-1] + ["-r", "100", "-c", str(count), target[-1]]).stdout)
        if status.get(100) == state or time.monotonic() > deadline:
            return status
        time.sleep(0.05)


def drive_a_cycle(target: list[str]) -> None:
    """One handshake done entirely by mbpoll: job id, trigger, poll, read, acknowledge."""
    regs = rm.ascii_to_regs(JOB, 16)
    r = mbpoll(target[:-1] + ["-r", "1", target[-1]], *regs)
    assert r.returncode == 0, r.stdout + r.stderr
    r = mbpoll(target[:-1] + ["-r", "0", target[-1]], 1)  # measure
    assert r.returncode == 0 and "Written 1 references" in r.stdout, r.stdout + r.stderr
    status = wait_state(target, "2", count=8)
    assert status[100] == "2" and status[104] == "1" and status[101] == "0", status  # done, valid, no fault
    want = synthetic_result(CycleRequest("measure", JOB, None, 0), fail_every=10)
    floats = parse(mbpoll(target[:-1] + ["-r", "120", "-c", "11", "-t", "4:float", "-B", target[-1]]).stdout)
    ints = parse(mbpoll(target[:-1] + ["-r", "142", "-c", "11", target[-1]]).stdout)
    expected = [want.angle(name) for name in rm.ANGLES]
    assert [120 + 2 * i for i in range(11)] == sorted(floats)
    for i, x in enumerate(expected):
        assert float(floats[120 + 2 * i]) == pytest.approx(x, abs=2e-6), rm.ANGLES[i]
        assert signed(ints[142 + i]) == round(x * 100), rm.ANGLES[i]
    tail = parse(mbpoll(target[:-1] + ["-r", "112", "-c", "3", target[-1]]).stdout)
    assert tail[112] == str(rm.MAP_VERSION)
    assert int(tail[113]) == 0  # the dry run's result carries a warning text only: no wheel's warning
    assert int(tail[114]) == 1 << rm.ANY_WARNING_BIT  # but "any warning"
    r = mbpoll(target[:-1] + ["-r", "0", target[-1]], 4)  # acknowledge
    assert r.returncode == 0
    assert parse(mbpoll(target[:-1] + ["-r", "100", target[-1]]).stdout)[100] == "0"


def check_refusals(target: list[str]) -> None:
    r = mbpoll(target[:-1] + ["-r", "104", target[-1]], 1)  # result_valid is the station's
    assert r.returncode != 0 and "Illegal data address" in r.stderr
    r = mbpoll(target[:-1] + ["-r", "0", target[-1]], 9)  # not a command
    assert r.returncode != 0 and "Illegal data value" in r.stderr
    r = mbpoll(target[:-1] + ["-r", "0", target[-1]], 4)  # nothing to acknowledge
    assert r.returncode != 0 and "Illegal data value" in r.stderr
    status = parse(mbpoll(target[:-1] + ["-r", "100", "-c", "8", target[-1]]).stdout)
    assert status[100] == "0" and status[106] == "503" and status[107] == "2"  # refused commands only


def test_mbpoll_over_tcp():
    with BackgroundServer(PlcDevice(dry_run_runner(10))) as bg:
        port = bg.start_tcp()
        target = ["-m", "tcp", "-p", str(port), "-a", "1", "127.0.0.1"]
        drive_a_cycle(target)
        check_refusals(target)
        assert bg.device.stats["done"] == 1


@pytest.mark.skipif(shutil.which("socat") is None, reason="socat is not installed")
def test_mbpoll_over_rtu(tmp_path):
    a, b = tmp_path / "station", tmp_path / "plc"
    socat = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 5
        while not (a.exists() and b.exists()):
            assert time.monotonic() < deadline
            time.sleep(0.01)
        with BackgroundServer(PlcDevice(dry_run_runner(10), device_id=5)) as bg:
            bg.start_rtu(str(a), baudrate=19200, parity="N")
            target = ["-m", "rtu", "-b", "19200", "-P", "none", "-a", "5", str(b)]
            drive_a_cycle(target)
            check_refusals(target)
    finally:
        socat.terminate()
        socat.wait(5)


def test_mbpoll_reads_which_wheels_a_refused_cycle_refused_and_why():
    """A cycle refused for two uncertain wheels (fault 404): mbpoll reads the fault, warning_bits
    with the two wheels' bits and uncertain_reasons with each one's reason code."""
    from station.result import Failure, Measurement, WarningFlag

    def refused(request):
        return Measurement(station="test", failure=Failure(404, "FR, RL less certain than the 0.06 deg limit", None,
                                                           "FR,RL"),
                           warning_flags=[WarningFlag("uncertain", "FR", reason="dark_lip"),
                                          WarningFlag("uncertain", "RL", reason="faint_edge")])

    with BackgroundServer(PlcDevice(refused)) as bg:
        target = ["-m", "tcp", "-p", str(bg.start_tcp()), "-a", "1", "127.0.0.1"]
        assert mbpoll(target[:-1] + ["-r", "0", target[-1]], 1).returncode == 0  # measure
        status = wait_state(target, "3", count=20)
        assert (status[100], status[101], status[104]) == ("3", "404", "0"), status  # fault 404, no result
        assert int(status[113]) == 1 << 1 | 1 << 2  # FR and RL uncertain
        codes = rm.UNCERTAIN_REASON_CODES
        assert int(status[119]) == codes["dark_lip"] << 4 | codes["faint_edge"] << 8
