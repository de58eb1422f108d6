"""Processes and disks, a section of bench/faults.py: kill -9 of `station measure` and `station
serve`, a full and a read-only data disk, a history on a read-only disk, the leftovers of a
killed cycle.

    .venv/bin/python bench/faults.py --only processes [--tries N]

Everything runs on the small simulated station (tests/station_fixtures.py: half resolution,
one frame per camera) in a temporary folder; `station` runs as a child process, as a watchdog
would start it. Every child carries a token in its environment, and so does every process it
starts (the measurement workers, multiprocessing's forkserver and resource tracker), so what a
killed child leaves running is found by the token, also after it was reparented to init, and
only those processes are ended afterwards (tests/process_tree.py). The disks are real: a
private mount namespace (`unshare -m`) with a small tmpfs filled up, or remounted read-only.

The rows (what counts as ``correct``):

* kill -9 of ``station measure`` at a random moment of its run (uniform over the time an
  uninterrupted run takes): no process left 5 s later, and nothing in /dev/shm (its frames,
  the named semaphores its processes had open);
* kill -9 of ``station serve`` idle (after a PLC cycle, its workers waiting) and mid-cycle (at
  a random moment of a PLC cycle): the same;
* ``station measure`` on a full data disk, ``--json`` elsewhere: exit 4, the result printed
  with a warning naming the full disk, the JSON written; ``--json`` on the full disk: exit 2,
  the result printed, "cannot write the result JSON" on stderr;
* ``station measure`` on a read-only data disk: exit 4, the result printed with warnings, the
  JSON written;
* ``station history`` on a read-only disk (history closed, left by a killed station with its
  -wal and -shm, and with its -wal only): exit 0, every cycle listed, no file created;
* a cycle killed while saving its images / while recording: the half-saved folder or the .part
  file is there, and gone after the next ``station measure``, which completes.

``lost``: no result printed, or neither the JSON nor a message saying why not (or a cycle the
history does not list); ``wrong``: a traceback, an internal error, another exit status.
"""

from __future__ import annotations

import json
import os
import queue
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.faults import FaultRow  # noqa: E402
from tests.process_tree import end_marked, left_after, marked_env, new_token, shared_memory_of  # noqa: E402

DEFAULT_TRIES = {"kill measure": 10, "kill serve": 3, "disk": 2, "history": 3, "leftovers": 4}
SETTLE_S = 5.0  # how long a killed process's descendants get to end
SHM = Path("/dev/shm")


@dataclass
class Bay:
    """The small simulated station in a temporary folder: its configuration and calibration."""

    work: Path
    config: Path
    calibration: Path

    def data_dir(self, name: str) -> Path:
        """A fresh data folder holding the calibration."""
        data = self.work / name
        (data / "calibration").mkdir(parents=True)
        shutil.copy(self.calibration, data / "calibration" / self.calibration.name)
        return data

    def env(self, token: str, data: Path) -> dict:
        return marked_env(token, STATION_DATA_DIR=str(data), HOME=str(self.work), PYTHONPATH=str(ROOT))

    def station(self, *args: str) -> list[str]:
        return [sys.executable, "-m", "station.cli", "--config", str(self.config), *args]


def _bay(work: Path) -> Bay:
    from tests.station_fixtures import small_station_config, truth_calibration

    config = small_station_config(work, capture__frames_averaged=1)
    truth_calibration(config)
    return Bay(work, config.path, config.calibration_file)


@dataclass
class Left:
    """What a child left behind: processes, their resident MiB, files in shared memory."""

    procs: int = 0
    mib: float = 0.0
    shm_files: int = 0

    @property
    def nothing(self) -> bool:
        return self.procs == 0 and self.shm_files == 0


def _left_behind(token: str, pid: int, shm_before: frozenset[str] = frozenset()) -> Left:
    """What is still there ``SETTLE_S`` after ``pid`` ended: the token's processes, ``pid``'s
    frames in shared memory and, of ``shm_before`` (the /dev/shm files the token's processes had
    mapped before the kill: multiprocessing's named semaphores), those still there. Then ends
    and removes them."""
    procs = left_after(token, SETTLE_S)
    shm = [Path(f) for f in shm_before if os.path.exists(f)] + list(SHM.glob(f"station-frames-{pid}-*"))
    shm_bytes = sum(f.stat().st_size for entry in shm
                    for f in ([entry] if entry.is_file() else entry.rglob("*")) if f.is_file())
    end_marked(token)  # the resource tracker last: it unlinks the semaphores when the rest is gone
    for entry in shm:
        if entry.is_dir():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
    return Left(len(procs), sum(p.rss_kib for p in procs.values()) / 1024 + shm_bytes / 2**20, len(shm))


def _count(row: FaultRow, left: Left) -> None:
    row.procs_left += left.procs
    row.mib_left += left.mib


# --- kill -9 of station measure -------------------------------------------------------------------
def _timed_measure(bay: Bay) -> float:
    """Seconds an uninterrupted `station measure` takes (also warms the caches)."""
    token, data = new_token(), bay.data_dir("timing")
    t0 = time.monotonic()
    subprocess.run(bay.station("measure", "--seed", "1"), env=bay.env(token, data), cwd=ROOT,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=300)
    _left_behind(token, -1)
    return time.monotonic() - t0


def _kill_measure(bay: Bay, tries: int, run_s: float, rng: random.Random) -> FaultRow:
    row = FaultRow("kill -9 of `station measure` at a random moment", tries)
    for i in range(tries):
        data = bay.data_dir(f"kill-measure-{i}")
        for _attempt in range(5):  # a kill that came after the run ended provoked nothing: again
            token = new_token()
            proc = subprocess.Popen(bay.station("measure", "--seed", str(i)), env=bay.env(token, data), cwd=ROOT,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            time.sleep(rng.uniform(0.05, 0.95) * run_s)
            shm = frozenset(shared_memory_of(token))
            killed = proc.poll() is None
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            left = _left_behind(token, proc.pid, shm)
            if killed:
                break
        _count(row, left)
        if not killed:
            _why_not(row, i, "the run ended before every kill drawn")
        elif not left.nothing:
            _why_not(row, i, f"left {left}")
        row.correct += killed and left.nothing
    return row


# --- kill -9 of station serve ---------------------------------------------------------------------
class _Lines:
    """A child's stdout lines, read in a thread so that waiting for one can time out."""

    def __init__(self, stream):
        self.lines: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream):
        for line in stream:
            self.lines.put(line)
        self.lines.put(None)

    def wait_for(self, pattern: str, timeout_s: float) -> re.Match | None:
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self.lines.get(timeout=left)
            except queue.Empty:
                return None
            if line is None:
                return None
            if m := re.search(pattern, line):
                return m
        return None


def _kill_serve(bay: Bay, tries: int, when: str, rng: random.Random) -> FaultRow:
    from pymodbus.client import ModbusTcpClient

    from station.plc import register_map as rm
    from station.plc.master import PlcSimulator

    row = FaultRow(f"kill -9 of `station serve`, {when}", tries)
    for i in range(tries):
        token, data = new_token(), bay.data_dir(f"kill-serve-{when}-{i}")
        proc = subprocess.Popen(bay.station("serve", "--seed", str(i), "--port", "0"), env=bay.env(token, data),
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        client = None
        killed_as_meant = False
        shm: frozenset[str] = frozenset()
        try:
            m = _Lines(proc.stdout).wait_for(r"Modbus TCP [\d.]+:(\d+)", 60)
            if m is None:
                _why_not(row, i, "`station serve` did not start")
                row.lost += 1
                continue
            client = ModbusTcpClient("127.0.0.1", port=int(m.group(1)), timeout=5, retries=0)
            client.connect()
            plc = PlcSimulator(client, timeout_s=180)
            first = plc.run_cycle(f"JOB-{i}-1")  # assembles the station and starts its workers
            if first.state != "done" or first.problems:
                _why_not(row, i, f"the first PLC cycle: {first.state} {first.problems}")
                row.wrong += 1
                continue
            if when == "idle":
                shm = frozenset(shared_memory_of(token))
                killed_as_meant = plc.read_block(status_only=True)["state"] == rm.STATE_CODES["idle"]
            else:
                steady = plc.run_cycle(f"JOB-{i}-2")  # how long a cycle takes once assembled
                for attempt in range(5):  # a cycle that ended before the moment drawn: another one
                    delay = rng.uniform(0.05, 0.9) * steady.measure_s
                    killed_as_meant, shm = _busy_after(plc, rm, token, f"JOB-{i}-{3 + attempt}", delay)
                    if killed_as_meant:
                        break
                    plc.acknowledge()
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            if client is not None:
                client.close()
            left = _left_behind(token, proc.pid, shm)
            _count(row, left)
        if not killed_as_meant:
            _why_not(row, i, f"the kill did not land while {when}")
        elif not left.nothing:
            _why_not(row, i, f"left {left}")
        row.correct += killed_as_meant and left.nothing
    return row


def _busy_after(plc, rm, token: str, job_id: str, delay_s: float) -> tuple[bool, frozenset[str]]:
    """Start a cycle and wait ``delay_s`` after the station reports busy: (still busy, the
    token's files in /dev/shm), the last read just before the caller's kill."""
    f_job, f_spec = rm.FIELDS["job_id"], rm.FIELDS["vehicle_spec"]
    plc.write(rm.COMMAND, [rm.COMMAND_CODES["measure"]] + rm.ascii_to_regs(job_id, f_job.count)
              + rm.ascii_to_regs(None, f_spec.count))
    deadline = time.monotonic() + 30
    while plc.read_block(status_only=True)["state"] != rm.STATE_CODES["busy"]:
        if time.monotonic() > deadline:
            return False, frozenset()
        time.sleep(0.01)
    time.sleep(delay_s)
    shm = frozenset(shared_memory_of(token))
    return plc.read_block(status_only=True)["state"] == rm.STATE_CODES["busy"], shm


def _why_not(row: FaultRow, i: int, why: str) -> None:
    print(f"  {row.fault}, try {i + 1}: {why}", file=sys.stderr, flush=True)


# --- full and read-only data disks ----------------------------------------------------------------
_DISKS = {
    "full": "mount -t tmpfs -o size=256k tmpfs {mnt} && mkdir {mnt}/calibration && cp {cal} {mnt}/calibration/ "
            "&& (dd if=/dev/zero of={mnt}/filler bs=4k 2>/dev/null; true)",
    "read-only": "mount -t tmpfs -o size=1m tmpfs {mnt} && mkdir {mnt}/calibration && cp {cal} {mnt}/calibration/ "
                 "&& mount -o remount,ro {mnt}",
}
_REASON = {"full": "No space left on device", "read-only": "Read-only file system"}


def _printed_a_result(out: str) -> bool:
    return all(s in out for s in ("FL ", "FR ", "RL ", "RR ", "thrust angle"))


def _measure_on_disk(bay: Bay, tries: int, disk: str, json_on_disk: bool) -> FaultRow:
    where = "on it" if json_on_disk else "elsewhere"
    row = FaultRow(f"`station measure` on a {disk} data disk, --json {where}", tries)
    for i in range(tries):
        token = new_token()
        name = f"{disk}-{'json-on-disk' if json_on_disk else 'json-elsewhere'}-{i}"
        mnt = bay.work / f"disk-{name}"
        mnt.mkdir()
        json_path = (mnt if json_on_disk else bay.work) / f"result-{name}.json"
        listing = bay.work / f"listing-{name}.txt"
        cmd = (_DISKS[disk].format(mnt=mnt, cal=bay.calibration) + " && { "
               + " ".join(bay.station("measure", "--seed", str(i), "--json", str(json_path)))
               + f"; status=$?; ls -A {mnt} > {listing}; exit $status; }}")
        p = subprocess.run(["unshare", "-m", "sh", "-c", cmd], env=bay.env(token, mnt), cwd=ROOT,
                           capture_output=True, text=True, timeout=300)
        _count(row, _left_behind(token, -1))
        if "Traceback" in p.stderr or "internal error" in p.stderr:
            _why_not(row, i, f"exit {p.returncode}: {p.stderr.strip()[-300:]}")
            row.wrong += 1
            continue
        printed = _printed_a_result(p.stdout)
        warned = f"cannot save the images: {_REASON[disk]}" in p.stdout
        left_on_disk = listing.read_text().split() if listing.exists() else []
        if json_on_disk:
            answered = (p.returncode == 2 and "cannot write the result JSON" in p.stderr
                        and json_path.name not in left_on_disk)
        else:
            answered = p.returncode == 4 and json_path.exists() and json.loads(json_path.read_text())["valid"]
        if not printed or not answered:
            _why_not(row, i, f"exit {p.returncode}, result printed: {printed}; {p.stderr.strip()[-300:]}")
            row.lost += 1
        elif not warned or any(name.startswith(".") for name in left_on_disk):
            _why_not(row, i, f"warned: {warned}, on the disk: {left_on_disk}")
            row.wrong += 1  # no warning, or a half-written file left on the disk
        else:
            row.correct += 1
    return row


# --- a history on a read-only disk ----------------------------------------------------------------
_HISTORY_WRITER = """
import os, sys
sys.path.insert(0, {root!r})
sys.path.insert(0, {root!r} + "/tests")
from result_builder import make_result
from station.records.history import History
h = History(sys.argv[1] + "/history.sqlite")
for i in range(1, 6):
    h.store(make_result(i, cycle=i, job_id=f"JOB-{{i}}"))
if sys.argv[2] != "closed":
    os._exit(0)  # killed: the cycles stay in the -wal file and its -shm index
h.close()
"""


def _history_read_only(bay: Bay, tries: int) -> FaultRow:
    row = FaultRow("`station history` on a read-only disk", tries)
    writer = bay.work / "history_writer.py"
    writer.write_text(_HISTORY_WRITER.format(root=str(ROOT)))
    states = ["closed", "killed", "killed, -shm lost"]
    for i in range(tries):
        token, state = new_token(), states[i % len(states)]
        data = bay.work / f"history-ro-{i}"
        data.mkdir()
        subprocess.run([sys.executable, str(writer), str(data), state], check=True, timeout=60)
        if state == "killed, -shm lost":
            (data / "history.sqlite-shm").unlink()
        before = sorted(f.name for f in data.iterdir())
        cmd = (f"mount --bind {data} {data} && mount -o remount,bind,ro {data} && "
               + " ".join(bay.station("history")))
        p = subprocess.run(["unshare", "-m", "sh", "-c", cmd], env=bay.env(token, data), cwd=ROOT,
                           capture_output=True, text=True, timeout=120)
        _count(row, _left_behind(token, -1))
        listed = "5 cycle(s)" in p.stdout and all(f"JOB-{k}" in p.stdout for k in range(1, 6))
        if "Traceback" in p.stderr or "internal error" in p.stderr or p.returncode != 0 or not listed:
            _why_not(row, i, f"{state}: exit {p.returncode}, listed: {listed}; {p.stderr.strip()[-300:]}")
        if "Traceback" in p.stderr or "internal error" in p.stderr:
            row.wrong += 1
        elif p.returncode != 0 or not listed:
            row.lost += 1
        elif sorted(f.name for f in data.iterdir()) != before:
            _why_not(row, i, f"{state}: files before {before}, after {sorted(f.name for f in data.iterdir())}")
            row.wrong += 1  # it wrote where it must not
        else:
            row.correct += 1
    return row


# --- leftovers of a killed cycle ------------------------------------------------------------------
def _leftovers(bay: Bay, tries: int) -> FaultRow:
    row = FaultRow("a cycle killed while saving its images / recording: leftovers removed at the next start", tries)
    for i in range(tries):
        what = ("images", "recording")[i % 2]
        data = bay.data_dir(f"leftovers-{i}")
        leftover = None
        for _attempt in range(5):  # until a kill lands while the file is being written
            token = new_token()
            proc = subprocess.Popen(bay.station("measure", "--seed", str(i)), env=bay.env(token, data), cwd=ROOT,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            leftover = _wait_for_unfinished(data, what, proc)
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            _count(row, _left_behind(token, proc.pid))
            if leftover is not None and leftover.exists():
                break
            leftover = None
        if leftover is None:
            _why_not(row, i, f"no kill landed while the {what} were being written")
            continue  # never provoked: not counted as correct
        token = new_token()
        p = subprocess.run(bay.station("measure", "--seed", str(i)), env=bay.env(token, data), cwd=ROOT,
                           capture_output=True, text=True, timeout=300)
        _count(row, _left_behind(token, -1))
        hidden = [f for sub in ("captures", "recordings") if (data / sub).exists()
                  for f in (data / sub).iterdir() if f.name.startswith(".")]
        if "Traceback" in p.stderr or p.returncode != 0 or leftover.exists() or hidden:
            _why_not(row, i, f"next start: exit {p.returncode}, {leftover.name} still there: {leftover.exists()}, "
                             f"hidden: {[f.name for f in hidden]}")
            row.wrong += 1
        else:
            row.correct += 1
    return row


def _wait_for_unfinished(data: Path, what: str, proc: subprocess.Popen) -> Path | None:
    """The temporary folder (images) or .part file (recording) ``proc`` is writing, as soon as it
    appears; None if ``proc`` ended first."""
    folder, pattern = ((data / "captures", rf"\..+\.{proc.pid}\.[a-z0-9_]{{8}}") if what == "images"
                       else (data / "recordings", rf"\..+\.rrd\.{proc.pid}\.part"))
    while proc.poll() is None:
        try:
            for entry in os.scandir(folder):
                if re.fullmatch(pattern, entry.name):
                    return Path(entry.path)
        except FileNotFoundError:
            pass
        time.sleep(0.002)
    return None


# --- the section ------------------------------------------------------------------------------------
def rows(tries: int | None) -> list[FaultRow]:
    n = {k: tries or v for k, v in DEFAULT_TRIES.items()}
    rng = random.Random(31)
    out: list[FaultRow] = []
    with tempfile.TemporaryDirectory(prefix="faults-processes-") as tmp:
        bay = _bay(Path(tmp))
        run_s = _timed_measure(bay)
        out.append(_kill_measure(bay, n["kill measure"], run_s, rng))
        out.append(_kill_serve(bay, n["kill serve"], "idle", rng))
        out.append(_kill_serve(bay, n["kill serve"], "mid-cycle", rng))
        if shutil.which("unshare") is None:
            print("unshare is not installed: the disk rows are left out", file=sys.stderr)
        else:
            out.append(_measure_on_disk(bay, n["disk"], "full", json_on_disk=False))
            out.append(_measure_on_disk(bay, n["disk"], "full", json_on_disk=True))
            out.append(_measure_on_disk(bay, n["disk"], "read-only", json_on_disk=False))
            out.append(_history_read_only(bay, n["history"]))
        out.append(_leftovers(bay, n["leftovers"]))
    return out


if __name__ == "__main__":
    for r in rows(int(sys.argv[1]) if len(sys.argv) > 1 else None):
        print(r.markdown())
