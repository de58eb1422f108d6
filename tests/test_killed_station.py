"""A station process killed with SIGKILL (a watchdog, the OOM killer) leaves nothing running:
not its measurement workers, not multiprocessing's forkserver or resource tracker, not its
frames in shared memory; idle or mid-cycle."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.process_tree import end_marked, left_after, marked_env, marked_processes, new_token, shared_memory_of

ROOT = Path(__file__).resolve().parent.parent

STATION = """
import sys, time
from pathlib import Path
sys.path.insert(0, {root!r})
from station.cycle import Station
from tests.station_fixtures import small_station_config, truth_calibration

if __name__ == "__main__":
    Path(sys.argv[1]).mkdir(parents=True, exist_ok=True)
    cfg = small_station_config(Path(sys.argv[1]), capture__frames_averaged=1, recording__enabled=False)
    truth_calibration(cfg)
    with Station(cfg, seed=3, workers=2, progress=lambda msg: print(msg, flush=True)) as station:
        print("ready", flush=True)
        if sys.argv[2] == "idle":
            time.sleep(600)
        station.measure()
        time.sleep(600)
"""


def _kill_at(tmp_path: Path, when: str, line_wanted: str) -> tuple[dict, set, dict, int]:
    """Start a station with two workers, SIGKILL it when it prints ``line_wanted``: (processes
    before the kill, their files in /dev/shm, processes left 5 s after, the station's PID)."""
    token = new_token()
    script = tmp_path / "station_process.py"
    script.write_text(STATION.format(root=str(ROOT)))
    proc = subprocess.Popen([sys.executable, str(script), str(tmp_path / "station"), when],
                            stdout=subprocess.PIPE, text=True, env=marked_env(token))
    try:
        for line in proc.stdout:
            if line_wanted in line:
                break
        else:
            pytest.fail(f"the station ended before printing {line_wanted!r} (exit {proc.wait()})")
        before, shm = marked_processes(token), shared_memory_of(token)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        return before, shm, left_after(token, within_s=5.0), proc.pid
    finally:
        proc.kill()
        proc.wait()
        end_marked(token)


@pytest.mark.slow
@pytest.mark.parametrize("when, line_wanted", [("idle", "ready"), ("mid-cycle", "detecting rims")])
def test_a_killed_station_leaves_no_process_and_no_shared_memory(tmp_path, when, line_wanted):
    before, shm, left, pid = _kill_at(tmp_path, when, line_wanted)
    assert len(before) >= 5, before  # the station, 2 workers, the forkserver, the resource tracker
    assert left == {}, [f"{p.pid} {p.cmd[:90]}" for p in left.values()]
    assert any("/sem.mp-" in f for f in shm)  # the pool's named semaphores ...
    assert not [f for f in shm if os.path.exists(f)]  # ... unlinked by the resource tracker on its way out
    assert not list(Path("/dev/shm").glob(f"station-frames-{pid}-*"))
