"""Frames handed to the measurement workers through shared memory instead of the pool's pipe.

``ProcessPoolExecutor`` pickles every task's arguments through one pipe, from one feeder
thread: eight 1280x1024 frames (10.5 MB) took 23 ms to reach two workers that did nothing
with them, a tenth of a measurement cycle (docs/speed.md). Written once into ``/dev/shm`` (a
file system in RAM) they cost one memory copy, and each worker maps its frames read-only
without another copy. Where there is no ``/dev/shm``, or it is full, the frames travel
through the pipe as before: same results, only slower.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from station.compute import orphans

SHM_DIR = Path("/dev/shm")
PREFIX = "station-frames-"  # then the owner's PID: a folder whose owner is gone is an orphan
_ORPHAN = re.compile(re.escape(PREFIX) + r"(?P<pid>\d+)-.*")


@dataclass(frozen=True)
class FrameRef:
    """A frame in shared memory: what a worker receives instead of the array."""

    path: str

    def load(self) -> np.ndarray:
        return np.load(self.path, mmap_mode="r")


def resolve(frame) -> np.ndarray:
    """The array of ``frame``: a :class:`FrameRef` is mapped, an array is returned as it is."""
    return frame.load() if isinstance(frame, FrameRef) else frame


class FrameHandoff:
    """``with FrameHandoff(images) as frames:`` {camera id: array} -> {camera id: FrameRef} in
    a private folder under ``/dev/shm``, removed on leaving the block (the workers are done
    with the frames by then). Falls back to the arrays themselves when the folder cannot be
    written."""

    def __init__(self, images: dict[str, np.ndarray], shm_dir: Path = SHM_DIR):
        self.images = images
        self.shm_dir = shm_dir
        self.folder: str | None = None

    def __enter__(self) -> dict:
        try:
            remove_orphans(self.shm_dir)
            self.folder = tempfile.mkdtemp(prefix=f"{PREFIX}{os.getpid()}-", dir=self.shm_dir)
            refs = {}
            for cam_id, image in self.images.items():
                path = Path(self.folder) / f"{cam_id}.npy"
                np.save(path, np.ascontiguousarray(image))
                refs[cam_id] = FrameRef(str(path))
            return refs
        except OSError:  # no /dev/shm, or it is full: the pipe still works
            self._remove()
            return dict(self.images)

    def __exit__(self, *exc) -> None:
        self._remove()

    def _remove(self) -> None:
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


def remove_orphans(shm_dir: Path = SHM_DIR) -> int:
    """Remove frame folders left by a station process that was killed mid-cycle (their owner's
    PID no longer runs); returns how many. Folders of running processes are left alone."""
    return orphans.remove_orphans(shm_dir, _ORPHAN)


def remove_frames_of(owner_pid: int, shm_dir: Path = SHM_DIR) -> None:
    """Remove the frame folders of ``owner_pid``, which the caller knows to be gone (a killed
    process is still a zombie to :func:`remove_orphans` until its parent has reaped it)."""
    for folder in shm_dir.glob(f"{PREFIX}{owner_pid}-*"):
        shutil.rmtree(folder, ignore_errors=True)
