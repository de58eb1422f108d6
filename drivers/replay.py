"""ReplayCamera: serves the frames of saved cycles (docs/replay-format.md), bit for bit.

URI: ``replay://DIR`` or ``replay://DIR?camera=cam3&loop=1``. DIR is either one cycle
directory (``cycle.json`` + ``<camera_id>.png``, written by ``drivers.frame_store``) or a
directory of cycle directories, served in name order, one cycle per trigger. ``camera``
picks the saved camera to serve (default: this camera's own id); ``loop=1`` starts again
after the last cycle (otherwise the end of the recording is a CameraMissing error).
Relative DIRs are relative to the working directory, ``replay:///abs/dir`` is absolute.

The image is returned exactly as saved (same dtype, same bytes). ``timestamp_ns`` is the
host's monotonic clock at the grab, so the capture's timestamp checks work as with live
cameras; the recorded values are in ``metadata["recorded_timestamp_ns"]`` and
``metadata["recorded_frame_id"]``.

Configured to another exposure than the one it was opened with, the camera serves the frame
the station took again at that exposure in the cycle it served last (the cycle's
``exposure-<factor>`` folder, station/capture/exposure_bracket.py), so a replay repeats the
cycle's second take as well.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from urllib.parse import parse_qs

from drivers.base import Camera, CameraIdentity, CameraSettings, Frame
from drivers.context import DriverContext
from drivers.errors import CameraMissing, DriverError, FrameError
from drivers.frame_store import read_image


def parse_replay_uri(uri: str) -> tuple[Path, dict[str, str]]:
    """``replay://DIR?k=v`` -> (DIR, {k: v})."""
    rest = uri.split("://", 1)[1]
    path, _, query = rest.partition("?")
    if not path:
        raise DriverError(f"{uri!r}: a replay URI needs a directory, e.g. replay://var/captures/CYCLE")
    return Path(path), {k: v[-1] for k, v in parse_qs(query).items()}


class ReplayCamera(Camera):
    scheme = "replay"
    exposes = False  # the saved frames, as they were kept (a kept burst is already averaged)

    def __init__(self, camera_id: str, uri: str, settings: CameraSettings | None = None,
                 context: DriverContext | None = None):
        super().__init__(camera_id, uri, settings, context)
        self.directory, opts = parse_replay_uri(uri)
        self.source_id = opts.get("camera", camera_id)
        self.loop = opts.get("loop", "0") in ("1", "true", "yes")
        self._cycles: list[Path] = []
        self._next = 0
        self._pending: Frame | None = None
        self._lock = threading.Lock()
        self._triggered = threading.Event()
        self._frame_id = 0

    def _open(self) -> None:
        d = self.directory
        if not d.is_dir():
            raise CameraMissing(f"{self.camera_id}: replay directory {d} does not exist ({self.uri})")
        if (d / "cycle.json").exists():
            cycles = [d]
        else:
            cycles = sorted(p for p in d.iterdir() if (p / "cycle.json").exists())
        if not cycles:
            raise CameraMissing(f"{self.camera_id}: {d} holds no saved cycle (no cycle.json) ({self.uri})")
        # Fail at open, not mid-run, if this camera is absent from the first cycle.
        cams = _cycle_meta(cycles[0]).get("cameras", {})
        if self.source_id not in cams:
            raise CameraMissing(f"{self.camera_id}: the saved cycle {cycles[0]} has no frame of "
                                f"{self.source_id} (it has {', '.join(sorted(cams)) or 'none'})")
        self._cycles, self._next = cycles, 0
        self._exposure_us = self.settings.exposure_us

    def _arm(self) -> None:
        self._triggered.clear()

    def _trigger(self) -> None:
        self._triggered.set()

    def _grab(self, timeout_s: float) -> Frame | None:
        # Replay frames come on demand: software trigger, or at once for free-run; a
        # hardware-triggered replay camera has no wire, so it serves at once as well.
        if self.settings.trigger == "software" and not self._triggered.wait(timeout_s):
            return None
        self._triggered.clear()
        if self.settings.exposure_us != self._exposure_us:
            return self._retaken(self.settings.exposure_us / self._exposure_us)
        with self._lock:
            if self._next >= len(self._cycles):
                if not self.loop or not self._cycles:
                    raise CameraMissing(f"{self.camera_id}: replay of {self.directory} is at its end "
                                        f"({len(self._cycles)} cycle(s) served); add ?loop=1 to repeat")
                self._next = 0
            cycle = self._cycles[self._next]
            self._next += 1
        return self._frame(cycle)

    def _retaken(self, factor: float) -> Frame:
        """The frame the station took again at ``factor`` times the exposure in the cycle
        served last (its ``exposure-<factor>`` folder: station/capture/exposure_bracket.py)."""
        if not self._next:
            raise FrameError(f"{self.camera_id}: no cycle served yet to take again at {factor:g}x the exposure")
        folder = self._cycles[self._next - 1] / f"exposure-{factor:g}"
        if not (folder / "cycle.json").exists():
            raise FrameError(f"{self.camera_id}: the saved cycle holds no frame taken at {factor:g}x the exposure "
                             f"({folder})")
        return self._frame(folder)  # which names a camera the folder lacks

    def _frame(self, cycle: Path) -> Frame:
        info = _cycle_meta(cycle).get("cameras", {}).get(self.source_id)
        if info is None:
            raise FrameError(f"{self.camera_id}: saved cycle {cycle} has no frame of {self.source_id}")
        image = read_image(cycle / info["file"])
        if list(image.shape) != list(info.get("shape", image.shape)) or str(image.dtype) != info.get("dtype", str(image.dtype)):
            raise FrameError(f"{self.camera_id}: {cycle / info['file']} is {image.dtype} {image.shape}, "
                             f"cycle.json says {info.get('dtype')} {info.get('shape')} (corrupt file?)")
        self._frame_id += 1
        md = {k: v for k, v in info.items() if k not in ("file", "timestamp_ns", "frame_id")}
        md.update(recorded_timestamp_ns=int(info.get("timestamp_ns", 0)),
                  recorded_frame_id=int(info.get("frame_id", 0)),
                  replay_cycle=str(cycle), source_camera=self.source_id)
        return Frame(self.camera_id, image, time.monotonic_ns(), self._frame_id, md)

    def _identity(self) -> CameraIdentity:
        s = self.settings
        return CameraIdentity("replay", "ReplayCamera", f"{self.directory}#{self.source_id}", s.width, s.height)

    def _close(self) -> None:
        self._cycles = []


def _cycle_meta(cycle: Path) -> dict:
    path = cycle / "cycle.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise CameraMissing(f"{cycle}: not a saved cycle (no cycle.json)") from None
    except (OSError, ValueError) as e:
        raise FrameError(f"{path}: unreadable ({e})") from None
