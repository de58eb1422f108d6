"""Worker processes for the per-wheel work: same results as in-process, a dead worker is a
clear error and the pool recovers."""

import os
import time

import numpy as np
import pytest

from station.errors import WorkerFailure
from station.compute.workers import WorkerPool


def _square(x):
    return x * x


def _pid(_):
    return os.getpid()


def _sleep(seconds):
    time.sleep(seconds)
    return os.getpid()


def _die(_):
    os._exit(3)  # a worker killed mid-task (the OOM killer, a segfault)


def test_results_come_back_in_order_from_every_worker():
    with WorkerPool(2) as w:
        assert w.map(_square, [(i,) for i in range(7)]) == [i * i for i in range(7)]
        assert os.getpid() not in w.map(_pid, [(i,) for i in range(4)])


def test_a_dead_worker_fails_the_cycle_clearly_and_the_next_cycle_runs():
    with WorkerPool(2) as w:
        with pytest.raises(WorkerFailure, match="worker process died"):
            w.map(_die, [(0,)])
        assert w.map(_square, [(3,)]) == [9]


@pytest.mark.slow
def test_measure_frames_in_workers_equals_in_process(tmp_path):
    from simulators.world import SimWorld
    from station.measure import measure_frames
    from tests.station_fixtures import small_station_config

    cfg = small_station_config(tmp_path)
    world = SimWorld.from_config(cfg)
    world.set_scene(world.vehicle_scene(5))
    images = world.render_all(np.random.default_rng(5))
    local = measure_frames(images, world.cameras, cfg)
    with WorkerPool(2) as w:
        pooled = measure_frames(images, world.cameras, cfg, workers=w)
    assert local.valid and pooled.valid
    for wheel in ("FL", "FR", "RL", "RR"):
        for k in ("toe_deg", "camber_deg", "toe_std_deg"):
            assert getattr(pooled.wheels[wheel], k) == getattr(local.wheels[wheel], k)


def test_close_does_not_wait_forever_for_a_stuck_worker():
    w = WorkerPool(1)
    pid = w.map(_sleep, [(0.0,)])[0]
    w._pool.submit(_sleep, 60.0)  # a task that will not finish in time
    time.sleep(0.5)
    t = time.monotonic()
    w.close(timeout_s=1.0)
    assert time.monotonic() - t < 5.0
    time.sleep(0.5)
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


OWNER = """
import sys, time
sys.path.insert(0, {root!r})
from station.compute.workers import WorkerPool
from tests.test_compute_workers import _sleep
if __name__ == "__main__":
    import numpy as np
    from station.compute.frame_handoff import FrameHandoff
    pool = WorkerPool(2)
    FrameHandoff(dict(cam1=np.zeros((4, 4), np.uint8))).__enter__()  # frames in /dev/shm, as mid-cycle
    if sys.argv[1] == "busy":
        pool._pool.submit(_sleep, 600.0)
        pool._pool.submit(_sleep, 600.0)
        time.sleep(0.5)  # both tasks have reached a worker
    print("ready", flush=True)
    time.sleep(600)
"""


@pytest.mark.parametrize("workers", ["idle", "busy"])
def test_a_killed_owner_leaves_no_process_behind(tmp_path, workers):
    """SIGKILL of the pool's owner: its workers, the forkserver and the resource tracker end too,
    and its frames in /dev/shm go, even while the owner is a zombie that nobody has reaped yet."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    from tests.process_tree import end_marked, left_after, marked_env, marked_processes, new_token

    token = new_token()
    script = tmp_path / "owner.py"
    script.write_text(OWNER.format(root=str(Path(__file__).resolve().parent.parent)))
    owner = subprocess.Popen([sys.executable, str(script), workers], stdout=subprocess.PIPE, text=True,
                             env=marked_env(token))
    try:
        assert owner.stdout.readline().strip() == "ready"
        started = marked_processes(token)
        assert len(started) >= 4, started  # the owner, the resource tracker, the forkserver, 2 workers
        frames = list(Path("/dev/shm").glob(f"station-frames-{owner.pid}-*"))
        assert frames
        owner.send_signal(signal.SIGKILL)  # not reaped until the end: a zombie meanwhile
        left = left_after(token, within_s=5.0)
        assert left == {}, [p.cmd[:100] for p in left.values()]
        assert not [f for f in frames if f.exists()]
    finally:
        owner.kill()
        owner.wait()
        end_marked(token)
