"""Worker processes for a cycle's per-wheel work, so that it runs on every core.

A measurement splits into four independent wheels: find the rim in both cameras of the pair,
rebuild the 3-D wheel (station/measure.py ``measure_wheel``). Threads overlap that work poorly:
most of the detector is numpy on arrays of a few thousand elements, where the interpreter (and
its lock) is busy between the calls. Processes share nothing, so two workers on two cores
take about half the time of one (docs/speed.md).

The workers are started once (forkserver: a clean process that has imported the measurement
code, forked per worker; not the caller, which may hold threads of a PLC server or a recording)
and live as long as their owner, the :class:`station.cycle.Station` or ``station live``; each
keeps its detector caches (undistortion tables, profile bases) between cycles. Images go to a
worker pickled through a pipe (1.3 MB per 1280x1024 frame).

A worker also ends when its owner is killed (SIGKILL runs no cleanup), which ends the rest:
an idle worker waits on a task queue whose writing end it holds itself, so it never sees the
owner go; the forkserver stays while any worker holds the write end of its "alive" pipe, and
multiprocessing's resource tracker while any process holds its pipe. So each worker watches its
owner (a pidfd, or polling where there is none) and exits when it is gone; then the forkserver
and the resource tracker see end-of-file and exit too.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import select
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from station.compute import frame_handoff
from station.compute.orphans import owner_alive
from station.errors import WorkerFailure

PRELOAD = ["station.measure", "station.rim.detector", "station.wheel.circle_fit"]


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _init_worker(owner_pid: int) -> None:
    # Ctrl-C in a terminal reaches the whole process group: it is the main process's to handle
    # (it ends the loop and closes the pool); a worker interrupted mid-task would only print a
    # traceback and break the pool
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_with_owner, args=(owner_pid,), name="owner-watch", daemon=True).start()


def _exit_with_owner(owner_pid: int) -> None:
    """Wait until the process that owns the pool is gone, then end this worker at once (also
    mid-task: the task's result has nobody to go to), removing the frames the owner left in
    shared memory. The owner is not this worker's parent (the forkserver is), so the
    parent-death signal cannot tell."""
    try:
        pidfd = os.pidfd_open(owner_pid)
    except ProcessLookupError:
        pidfd = None
    except (AttributeError, OSError):  # no pidfd (not Linux, or a kernel before 5.3)
        pidfd = None
        while owner_alive(owner_pid):
            time.sleep(1.0)
    if pidfd is not None:
        watch = select.poll()
        watch.register(pidfd, select.POLLIN)  # a pidfd becomes readable when its process has exited
        while not watch.poll():
            pass
    frame_handoff.remove_frames_of(owner_pid)
    os._exit(0)


def _ready(_index: int) -> int:
    time.sleep(0.05)  # long enough that each of the n start-up tasks lands on its own worker
    return os.getpid()


class WorkerPool:
    """A pool of ``n`` worker processes. ``map(fn, args)`` runs ``fn(*a)`` for each tuple of
    ``args`` (``fn`` a module-level function) and returns the results in order. Use as a
    context manager or call :meth:`close`."""

    def __init__(self, n: int | None = None):
        self.n = n or default_workers()
        self._pool: ProcessPoolExecutor | None = None
        self._start()

    def _start(self) -> None:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)
        self._pool = ProcessPoolExecutor(self.n, mp_context=ctx, initializer=_init_worker,
                                         initargs=(os.getpid(),))
        # start every worker now (the first cycle should not pay for it): n tasks at once
        self._pids = set(self._pool.map(_ready, range(self.n)))

    def map(self, fn, args: list[tuple]) -> list:
        try:
            futures = [self._pool.submit(fn, *a) for a in args]
            return [f.result() for f in futures]
        except BrokenProcessPool as e:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._start()
            raise WorkerFailure("a measurement worker process died during the cycle; the workers were restarted",
                                hint="run the cycle again; if it repeats, check the machine's memory") from e

    def close(self, timeout_s: float = 10.0) -> None:
        """Stop the workers: queued tasks are cancelled, running ones finish. A worker still
        busy after ``timeout_s`` is ended by the PID it reported at start (SIGTERM)."""
        if self._pool is None:
            return
        pool, self._pool = self._pool, None
        t = threading.Thread(target=pool.shutdown, kwargs={"wait": True, "cancel_futures": True}, daemon=True)
        t.start()
        t.join(timeout_s)
        if t.is_alive():
            for pid in self._pids:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.kill(pid, signal.SIGTERM)
            t.join(timeout_s)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
