"""Keeping a cycle's frames: cycle ids and lossless replay sets (docs/replay-format.md).

    path = save_capture(frames, config.data_path("captures", new_cycle_id()))

A failed cycle's partial frames are kept too (``capture_and_save``): nothing is lost. In a
measurement cycle the frames are in memory and the measurement does not need them on disk, so
there a full or read-only disk is a warning (``capture_and_keep``); for ``station capture``,
where the saved set is the point, it is an error.
"""

from __future__ import annotations

import datetime as _dt
import itertools
import logging
from dataclasses import dataclass
from pathlib import Path

from drivers.base import Camera, Frame
from drivers.context import DriverContext
from drivers.frame_store import UNFINISHED, save_cycle
from station.capture.sync import capture_averaged
from station.compute.orphans import remove_orphans
from station.errors import CODED_ERRORS, StorageError

log = logging.getLogger("station.capture")

_cycle_counter = itertools.count(1)


def new_cycle_id() -> str:
    """A sortable, unique id: UTC time to the millisecond + a process counter."""
    now = _dt.datetime.now(_dt.timezone.utc)
    return f"{now:%Y%m%dT%H%M%S}{now.microsecond // 1000:03d}Z-{next(_cycle_counter):04d}"


def save_capture(frames: dict[str, Frame], directory, *, cycle_id: str | None = None,
                 failures: dict[str, str] | None = None, truth: dict | None = None,
                 extra: dict | None = None) -> Path:
    """Save a (possibly partial) set losslessly with its metadata (docs/replay-format.md).
    A folder that cannot be written (full, read-only, no permission) raises StorageError and
    leaves nothing behind."""
    directory = Path(directory)
    meta = {"cycle_id": cycle_id or directory.name,
            "saved_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"),
            "complete": not failures, "failures": dict(failures or {}), **(extra or {})}
    try:
        return save_cycle(directory, frames, extra=meta, truth=truth)
    except OSError as e:
        raise StorageError(f"{directory}: cannot save the images: {e.strerror or e}",
                           hint="free space on the data disk, or check that the data folder (data_dir, "
                                "$STATION_DATA_DIR) is writable") from e


@dataclass
class KeptCapture:
    """Where a cycle's frames were kept (``path``), or why they could not be (``error``)."""

    path: Path | None
    error: StorageError | None = None

    @property
    def warning(self) -> str | None:
        """The sentence for the cycle's result when the frames could not be kept."""
        return None if self.error is None else f"{self.error}; the measurement is kept, this cycle's images are not"


def keep_capture(frames: dict[str, Frame], directory, **meta) -> KeptCapture:
    """:func:`save_capture` for a measurement cycle: a failure to save is returned, not raised."""
    try:
        return KeptCapture(save_capture(frames, directory, **meta))
    except StorageError as e:
        return KeptCapture(None, e)


def capture_and_keep(cameras: dict[str, Camera], timeout_s: float, out_dir, *, trigger_board=None,
                     max_skew_s: float | None = None, truth: dict | None = None,
                     extra: dict | None = None, frames_averaged: int = 1) -> tuple[dict[str, Frame], KeptCapture]:
    """capture_averaged, then keep the frames (:func:`keep_capture`); a failed cycle's partial
    frames are kept too, then it raises. The error then has ``kept`` (a :class:`KeptCapture`) and
    ``saved_to`` (its path or None) besides ``frames`` and ``failures``."""
    out_dir = Path(out_dir)
    try:
        frames = capture_averaged(cameras, timeout_s, trigger_board, max_skew_s, frames_averaged)
    except CODED_ERRORS as e:
        partial = getattr(e, "frames", {})
        e.kept = KeptCapture(None)
        if partial:
            e.kept = keep_capture(partial, out_dir, failures=getattr(e, "failures", {}), truth=truth, extra=extra)
            if e.kept.path is not None:
                log.warning("cycle failed; %d frame(s) kept in %s", len(partial), e.kept.path)
        e.saved_to = e.kept.path
        raise
    return frames, keep_capture(frames, out_dir, truth=truth, extra=extra)


def capture_and_save(cameras: dict[str, Camera], timeout_s: float, out_dir, **options) -> tuple[dict[str, Frame], Path]:
    """:func:`capture_and_keep` where the saved set is the point (``station capture``): a set that
    cannot be saved raises StorageError. A failed capture raises its own error (``saved_to``:
    where its partial frames are, or None)."""
    frames, kept = capture_and_keep(cameras, timeout_s, out_dir, **options)
    if kept.error is not None:
        raise kept.error
    return frames, kept.path


def remove_unfinished_captures(captures_dir: Path) -> int:
    """Remove the temporary folders of saves whose process was killed mid-save (their owner's
    PID no longer runs); returns how many. A running process's save is left alone."""
    return remove_orphans(captures_dir, UNFINISHED)


def capture_station_cycle(cameras: dict[str, Camera], config, *, trigger_board=None, context: DriverContext | None = None,
                          truth: dict | None = None, extra: dict | None = None) -> tuple[dict[str, Frame], Path | None]:
    """The station's cycle: capture with ``capture.timeout_s`` (or the simulated cameras' own
    deadline from ``context``) and, if ``capture.keep_captures``, save under
    ``<data_dir>/captures/<cycle id>`` (a failed cycle's partial set too). (frames, path or None)."""
    timeout = max(config.capture.timeout_s, context.capture_timeout_s if context is not None else 0.0)
    n = config.capture.frames_averaged
    if not config.capture.keep_captures:
        return capture_averaged(cameras, timeout, trigger_board, frames=n), None
    cycle_id = new_cycle_id()
    return capture_and_save(cameras, timeout, config.data_path("captures", cycle_id), trigger_board=trigger_board,
                            truth=truth, extra={"station": config.name, **(extra or {})}, frames_averaged=n)
