"""Frames handed to worker processes through /dev/shm: the same arrays, nothing left behind,
and the arrays themselves where shared memory cannot be written."""

import os
from pathlib import Path

import numpy as np
import pytest

from station.compute.frame_handoff import FrameHandoff, FrameRef, resolve


def _images():
    rng = np.random.default_rng(0)
    return {"cam1": rng.integers(0, 256, (64, 80), dtype=np.uint8),
            "cam2": rng.integers(0, 65536, (64, 80), dtype=np.uint16)}


def _checksum(ref):
    return int(resolve(ref).astype(np.int64).sum()), os.getpid()


@pytest.mark.skipif(not Path("/dev/shm").is_dir(), reason="no /dev/shm on this machine")
def test_frames_come_back_equal_and_the_folder_is_removed():
    images = _images()
    with FrameHandoff(images) as frames:
        assert all(isinstance(f, FrameRef) for f in frames.values())
        folder = Path(frames["cam1"].path).parent
        assert folder.parent == Path("/dev/shm")
        for cam, image in images.items():
            back = resolve(frames[cam])
            assert back.dtype == image.dtype and np.array_equal(back, image)
            assert not back.flags.writeable  # a worker cannot change the cycle's frame
    assert not folder.exists()


@pytest.mark.skipif(not Path("/dev/shm").is_dir(), reason="no /dev/shm on this machine")
def test_a_worker_process_reads_the_frame():
    from station.compute.workers import WorkerPool

    images = _images()
    with FrameHandoff(images) as frames, WorkerPool(1) as w:
        (total, pid), = w.map(_checksum, [(frames["cam2"],)])
    assert total == int(images["cam2"].astype(np.int64).sum()) and pid != os.getpid()


def test_without_shared_memory_the_arrays_travel_as_they_are(tmp_path):
    images = _images()
    with FrameHandoff(images, shm_dir=tmp_path / "missing") as frames:
        assert frames["cam1"] is images["cam1"]
        assert resolve(frames["cam1"]) is images["cam1"]


def test_folders_of_a_killed_station_are_removed_and_live_ones_kept(tmp_path):
    import subprocess

    from station.compute.frame_handoff import PREFIX, remove_orphans

    dead = subprocess.Popen(["true"])
    dead.wait()                                   # a PID that no longer runs
    orphan = tmp_path / f"{PREFIX}{dead.pid}-abc"
    live = tmp_path / f"{PREFIX}{os.getpid()}-def"
    other = tmp_path / "someone-else"
    for d in (orphan, live, other):
        d.mkdir()
        (d / "cam1.npy").write_bytes(b"x")
    assert remove_orphans(tmp_path) == 1
    assert not orphan.exists() and live.exists() and other.exists()
