"""PLC benchmark (issue 5): back-to-back PLC-triggered cycles over Modbus TCP and RTU.

`station serve` runs as its own process (dry run: synthetic results from the job id, every
10th job failing on purpose; or `--real`: the simulated station's measurement pipeline). The
PLC simulator drives every cycle through the full handshake and checks every step and value.
Prints per transport: cycles completed, results lost or wrong, faults (on purpose), the
handshake latency at the PLC excluding the measurement (trigger written -> idle again after the
acknowledge, minus the station's own measurement time), and the station process's resident
memory at cycle 100 and at the last cycle.

    .venv/bin/python bench/plc.py                       # 1,000 cycles over TCP and over RTU
    .venv/bin/python bench/plc.py --cycles 200 --transport rtu
    .venv/bin/python bench/plc.py --real --cycles 20    # the simulated station, real measurement
"""

from __future__ import annotations

import argparse
import os
import select
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pymodbus.client import ModbusSerialClient, ModbusTcpClient  # noqa: E402
from pymodbus.framer.rtu import FramerRTU  # noqa: E402

from station.plc.master import PlcSimulator, dry_run_expectation  # noqa: E402
from tests.serve_process import free_port  # noqa: E402


def _vmrss_kib(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:  # gone meanwhile
        pass
    return 0


def _descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (the measurement workers and their forkserver)."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(d.name))
    out, stack = [], [pid]
    while stack:
        for c in children.get(stack.pop(), []):
            out.append(c)
            stack.append(c)
    return out


def rss_kib(pid: int) -> int:
    """Resident memory of the station: its process and every process below it (KiB)."""
    return _vmrss_kib(pid) + sum(_vmrss_kib(c) for c in _descendants(pid)) if Path(f"/proc/{pid}").exists() else -1


def start_serve(args, transport: str, tmp: Path):
    """(serve process, client, extra processes to stop)."""
    extra = []
    cmd = [sys.executable, "-m", "station.cli", "serve", "--log-level", "warning", "--heartbeat-s", "0.1"]
    cmd += ["--dry-run", "--fail-every", str(args.fail_every)] if not args.real else []
    if transport == "tcp":
        port = free_port()
        cmd += ["--port", str(port)]
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=args.timeout, retries=1)
    else:
        if not shutil.which("socat"):
            raise SystemExit("bench/plc.py: RTU needs socat (apt-get install socat)")
        a, b = tmp / "station", tmp / "plc"
        extra.append(subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        while not (a.exists() and b.exists()):
            time.sleep(0.01)
        cmd += ["--rtu", str(a), "--parity", "N"]  # a pseudo-terminal takes no parity
        client = ModbusSerialClient(str(b), baudrate=19200, parity="N", timeout=args.timeout, retries=1)
    log = open(tmp / f"serve-{transport}.log", "w")
    serve = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=log, text=True)
    line = serve.stdout.readline()
    if "serving" not in line:
        serve.kill()
        raise SystemExit(f"station serve did not start: {line}{(tmp / f'serve-{transport}.log').read_text()}")
    if not client.connect():
        raise SystemExit(f"cannot connect the PLC simulator ({transport})")
    return serve, client, extra


def raw_rtu_answer_ms(device: str, count: int, n: int = 200) -> tuple[float, float]:
    """The station's own answer time on the serial line: a read of ``count`` registers written
    straight to the pty and timed until the whole response is back (no Modbus library on
    the PLC side). Returns (median, max) in ms."""
    import tty
    body = bytes([1, 3, 0, 100, 0, count])
    frame = body + FramerRTU.compute_CRC(body).to_bytes(2, "big")
    want = 5 + 2 * count
    fd = os.open(device, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        times = []
        for _ in range(n):
            t = time.perf_counter()
            os.write(fd, frame)
            got = b""
            while len(got) < want:
                if not select.select([fd], [], [], 2.0)[0]:
                    raise SystemExit("bench/plc.py: the station did not answer a raw RTU read")
                got += os.read(fd, 512)
            times.append((time.perf_counter() - t) * 1e3)
            time.sleep(0.002)  # line silence between frames
    finally:
        os.close(fd)
    return statistics.median(times), max(times)


def run_transport(args, transport: str, tmp: Path) -> dict:
    serve, client, extra = start_serve(args, transport, tmp)
    expect = None if args.real else dry_run_expectation(args.fail_every)
    sim = PlcSimulator(client, timeout_s=args.cycle_timeout)
    hs, measure, problems = [], [], []
    completed = faults = 0
    rss = {}
    t0 = time.perf_counter()
    try:
        for i in range(1, args.cycles + 1):
            rep = sim.run_cycle(f"JOB-{i:06d}", args.spec, expect=expect)
            if rep.state in ("done", "fault") and not any("acknowledge" in p for p in rep.problems):
                completed += 1
                hs.append(rep.handshake_s * 1e3)
                measure.append(rep.measure_s)
            faults += rep.state == "fault"
            problems += [(i, p) for p in rep.problems]
            if i % 100 == 0 or i in (args.cycles, min(100, args.cycles)):
                rss[i] = rss_kib(serve.pid)
        raw = {}
        if transport == "rtu":
            client.close()
            raw = {n: raw_rtu_answer_ms(str(tmp / "plc"), n) for n in (1, 108)}
    finally:
        wall = time.perf_counter() - t0
        client.close()
        serve.terminate()
        serve.wait(10)
        for p in extra:
            p.terminate()
            p.wait(5)
    hs_sorted = sorted(hs)
    first = min(100, args.cycles)
    return {
        "transport": transport, "cycles": args.cycles, "completed": completed,
        "lost_or_wrong": len({i for i, _ in problems}), "faults": faults,
        "median_ms": statistics.median(hs) if hs else float("nan"),
        "p99_ms": hs_sorted[int(0.99 * (len(hs) - 1))] if hs else float("nan"),
        "max_ms": max(hs) if hs else float("nan"),
        "measure_s": statistics.median(measure) if measure else float("nan"),
        "rss_first": rss.get(first, -1), "rss_last": rss.get(args.cycles, -1), "first": first,
        "rss_half": rss.get(max((i for i in rss if i <= args.cycles // 2), default=first), -1),
        "wall_s": wall, "problems": problems[:10], "rss": rss, "raw": raw,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=1000)
    ap.add_argument("--transport", default="tcp,rtu", help="tcp, rtu or tcp,rtu")
    ap.add_argument("--real", action="store_true", help="the real (simulated) station instead of the dry run")
    ap.add_argument("--fail-every", type=int, default=10, help="dry run: jobs failing on purpose")
    ap.add_argument("--spec", default="toyota-echo-2003", help="vehicle spec id (config/vehicles.yaml) sent with every trigger")
    ap.add_argument("--timeout", type=float, default=2.0, help="Modbus response timeout (s)")
    ap.add_argument("--cycle-timeout", type=float, default=120.0)
    ap.add_argument("--rss-series", action="store_true", help="print the station's RSS (with its worker processes) every 100 cycles")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for transport in args.transport.split(","):
            rows.append(run_transport(args, transport.strip(), Path(tmp)))
    mode = "real simulated station" if args.real else f"dry run, every {args.fail_every}th job fails on purpose"
    print(f"PLC benchmark: {args.cycles} back-to-back cycles per transport ({mode})")
    print("| transport | cycles completed | results lost or wrong | faults (on purpose) | handshake median ms "
          "| p99 ms | max ms | measurement median s | station RSS at cycle %d -> %d (KiB) | RSS growth, 2nd half (KiB) | wall s |"
          % (rows[0]["first"], args.cycles))
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['transport']} | {r['completed']}/{r['cycles']} | {r['lost_or_wrong']} | {r['faults']} | "
              f"{r['median_ms']:.2f} | {r['p99_ms']:.2f} | {r['max_ms']:.2f} | {r['measure_s']:.4f} | "
              f"{r['rss_first']} -> {r['rss_last']} ({r['rss_last'] - r['rss_first']:+d}) | {r['rss_last'] - r['rss_half']:+d} | {r['wall_s']:.1f} |")
    for r in rows:
        for n, (med, mx) in r["raw"].items():
            print(f"station answer time on the RTU line (raw pty client, read of {n} registers): "
                  f"median {med:.2f} ms, max {mx:.2f} ms")
    if args.rss_series:
        for r in rows:
            print(f"{r['transport']} station RSS (KiB) by cycle: "
                  + ", ".join(f"{i}: {v}" for i, v in sorted(r["rss"].items())))
    for r in rows:
        for i, p in r["problems"]:
            print(f"{r['transport']} cycle {i}: {p}")
    return 1 if any(r["lost_or_wrong"] or r["completed"] != r["cycles"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
