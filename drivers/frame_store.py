"""Save and load one cycle's frames losslessly: the replay format (docs/replay-format.md).

A cycle directory holds ``<camera_id>.png`` (8- or 16-bit, lossless) and ``cycle.json`` with
each frame's metadata; a simulated set also has ``truth.json``. Writing goes to a temporary
directory renamed into place, so a cycle is either complete on disk or absent. The temporary
directory, ``.<name>.<writer's PID>.<random>`` beside the target, is what a writer killed
mid-save leaves behind (:data:`UNFINISHED` matches it).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from drivers.base import Frame
from drivers.errors import FrameError

FORMAT_VERSION = 1
UNFINISHED = re.compile(r"\.(?P<name>.+)\.(?P<pid>\d+)\.[a-z0-9_]{8}")  # a save's temporary directory


def save_cycle(directory: str | os.PathLike, frames: dict[str, Frame], extra: dict | None = None,
               truth: dict | None = None) -> Path:
    """Write frames (keyed by camera id) atomically to ``directory`` (must not exist yet)."""
    directory = Path(directory)
    if directory.exists():
        raise FrameError(f"{directory}: already exists; a saved cycle is never overwritten")
    directory.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{directory.name}.{os.getpid()}.", dir=directory.parent))
    try:
        meta = {"format_version": FORMAT_VERSION, "cameras": {}, **(extra or {})}
        for cam_id, frame in frames.items():
            name = f"{cam_id}.png"
            ok, buf = cv2.imencode(".png", frame.image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
            if not ok:
                raise FrameError(f"{cam_id}: could not encode the frame as PNG")
            (tmp / name).write_bytes(buf.tobytes())
            meta["cameras"][cam_id] = {"file": name, "timestamp_ns": int(frame.timestamp_ns),
                                       "frame_id": int(frame.frame_id),
                                       "shape": list(frame.image.shape), "dtype": str(frame.image.dtype),
                                       **{k: v for k, v in frame.metadata.items() if _jsonable(v)}}
        (tmp / "cycle.json").write_text(json.dumps(meta, indent=1))
        if truth is not None:
            (tmp / "truth.json").write_text(json.dumps(truth, indent=1))
        os.replace(tmp, directory)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return directory


def load_cycle(directory: str | os.PathLike) -> tuple[dict[str, Frame], dict]:
    """Read a cycle directory back: (frames keyed by camera id, cycle.json contents)."""
    directory = Path(directory)
    meta_path = directory / "cycle.json"
    try:
        meta = json.loads(meta_path.read_text())
    except FileNotFoundError:
        raise FrameError(f"{directory}: not a saved cycle (no cycle.json)") from None
    except (OSError, ValueError) as e:
        raise FrameError(f"{meta_path}: unreadable ({e})") from None
    frames = {}
    for cam_id, info in meta.get("cameras", {}).items():
        frames[cam_id] = Frame(cam_id, read_image(directory / info["file"]), int(info.get("timestamp_ns", 0)),
                               int(info.get("frame_id", 0)), {k: v for k, v in info.items() if k not in ("file",)})
    return frames, meta


def read_image(path: Path, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray:
    """Read an image file, raising FrameError (never returning None) when it is unreadable."""
    path = Path(path)
    try:
        data = np.frombuffer(path.read_bytes(), np.uint8)
    except OSError as e:
        raise FrameError(f"{path}: cannot read ({e.strerror or e})") from None
    image = cv2.imdecode(data, flags) if data.size else None
    if image is None:
        raise FrameError(f"{path}: not a readable image (truncated or not PNG/JPEG?)")
    return image


def _jsonable(v) -> bool:
    try:
        json.dumps(v)
        return True
    except TypeError:
        return False
