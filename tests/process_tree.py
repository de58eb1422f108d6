"""Every process a test started, found again after its parent was killed.

A process started with :func:`marked_env` carries a unique token in its environment, and so
does every process it starts (multiprocessing's forkserver, resource tracker and workers inherit
the environment), even after they were reparented to init. :func:`marked_processes` finds them
all by that token, so a test or the fault bench can count what a killed process left behind and
end exactly those processes, never another one.
"""

from __future__ import annotations

import os
import signal
import time
import uuid
from dataclasses import dataclass

MARK = "STATION_PROCESS_MARK"


@dataclass(frozen=True)
class Proc:
    pid: int
    ppid: int
    rss_kib: int
    cmd: str


def new_token() -> str:
    return uuid.uuid4().hex


def marked_env(token: str, **extra: str) -> dict:
    """This process's environment plus the token (and ``extra`` variables)."""
    return {**os.environ, MARK: token, **extra}


def marked_processes(token: str) -> dict[int, Proc]:
    """{pid: Proc} of every running process started with ``token`` (zombies have no environment
    left and are not counted: they hold no memory)."""
    needle = f"{MARK}={token}".encode()
    found = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/environ", "rb") as f:
                if needle not in f.read().split(b"\0"):
                    continue
            with open(f"/proc/{name}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{name}/status") as f:
                rss = next((int(line.split()[1]) for line in f if line.startswith("VmRSS:")), 0)
            with open(f"/proc/{name}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
        except (OSError, ValueError, IndexError):
            continue  # gone meanwhile
        found[int(name)] = Proc(int(name), ppid, rss, cmd)
    return found


def left_after(token: str, within_s: float) -> dict[int, Proc]:
    """The marked processes still running ``within_s`` seconds from now (returns as soon as
    there are none)."""
    deadline = time.monotonic() + within_s
    while True:
        left = marked_processes(token)
        if not left or time.monotonic() >= deadline:
            return left
        time.sleep(0.1)


def shared_memory_of(token: str) -> set[str]:
    """The files in /dev/shm that the marked processes have mapped (multiprocessing's named
    semaphores ``sem.mp-*``, frames handed to workers): what a killed process may leave there."""
    files = set()
    for pid in marked_processes(token):
        try:
            with open(f"/proc/{pid}/maps") as f:
                files.update(line.split(None, 5)[5].strip() for line in f
                             if len(line.split(None, 5)) == 6 and line.split(None, 5)[5].startswith("/dev/shm/"))
        except OSError:
            continue
    return files


def end_marked(token: str, tracker_grace_s: float = 2.0) -> None:
    """SIGKILL whatever still runs with ``token`` (only processes this test started carry it).
    multiprocessing's resource tracker goes last: once the others are gone it unlinks their
    named semaphores and exits by itself; killed first, it would leave them in /dev/shm."""
    left = marked_processes(token)
    trackers = {pid for pid, p in left.items() if "resource_tracker" in p.cmd}
    for pid in set(left) - trackers:
        _kill(pid)
    deadline = time.monotonic() + tracker_grace_s
    while trackers & set(marked_processes(token)) and time.monotonic() < deadline:
        time.sleep(0.05)
    for pid in trackers & set(marked_processes(token)):
        _kill(pid)


def _kill(pid: int) -> None:
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
