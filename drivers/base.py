"""The camera interface every driver implements (sim, replay, aravis, v4l2).

The public methods live here and call the driver's protected ``_open``, ``_configure``,
``_trigger``, ``_grab`` and ``_close``, so deadlines, logging and error wrapping are written
once (the python-can pattern: ``recv`` -> ``_recv_internal``). Drivers know no geometry.
"""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from drivers.context import DriverContext
from drivers.errors import CameraTimeout, DriverError, FrameError

log = logging.getLogger("station.drivers")

TRIGGER_MODES = ("free-run", "software", "hardware")
# Pixel formats a driver may be configured for (GenICam PFNC names) and the array each gives:
# Mono8 -> (H, W) uint8, Mono16 -> (H, W) uint16, Bayer??8 -> (H, W) uint8 grey (demosaiced by
# the driver: the station measures grey levels only).
PIXEL_FORMATS = ("Mono8", "Mono16", "BayerRG8", "BayerGR8", "BayerGB8", "BayerBG8")
FRAME_DTYPE = {"Mono16": np.uint16}  # every other format gives uint8
# Frame.metadata key: the image is the mean of this many exposures (station/capture/frame_average.py),
# kept as (H, W) uint16 whatever the pixel format (a replayed burst comes back so)
AVERAGED_FRAMES_KEY = "averaged_frames"


@dataclass(frozen=True)
class CameraSettings:
    width: int = 1280
    height: int = 1024
    pixel_format: str = "Mono8"
    exposure_us: float = 8000.0
    gain_db: float = 0.0
    trigger: str = "software"
    roi: tuple[int, int, int, int] | None = None  # x, y, w, h; None = full sensor
    response_gamma: float = 1.0  # what the station expects: 1 = linear grey (the driver switches gamma and LUT off)


@dataclass(frozen=True)
class CameraIdentity:
    vendor: str
    model: str
    serial: str
    width: int
    height: int


@dataclass
class Frame:
    """One image from one camera. image: (H, W) uint8, or (H, W) uint16 for Mono16.

    timestamp_ns is the host's monotonic clock when the frame was exposed or arrived (comparable
    across cameras); a camera's own clock, if any, is in metadata["camera_timestamp_ns"].
    """

    camera_id: str
    image: np.ndarray
    timestamp_ns: int  # camera or host clock, monotonic
    frame_id: int
    metadata: dict[str, Any] = field(default_factory=dict)


class Camera(ABC):
    """Base class. Subclasses implement the ``_`` methods; users call the public ones."""

    scheme = ""
    exposes = True  # each frame is a new exposure (False: a replay of saved frames, never averaged again)

    def __init__(self, camera_id: str, uri: str, settings: CameraSettings | None = None,
                 context: DriverContext | None = None):
        self.camera_id = camera_id
        self.uri = uri
        self.settings = settings or CameraSettings()
        self.context = context or DriverContext()
        self.is_open = False
        self.last_frame: Frame | None = None
        self._armed = False

    # --- public API -------------------------------------------------------------------------
    def open(self) -> "Camera":
        if not self.is_open:
            self._validate(self.settings)
            self._wrap("open", self._open)
            self.is_open = True
            try:
                self._wrap("configure", self._configure, self.settings)
            except BaseException:
                self.close()  # release the device: a half-open camera would lock out the next open
                raise
            log.info("%s: opened %s", self.camera_id, self.uri)
        return self

    def configure(self, **changes) -> None:
        settings = replace(self.settings, **changes)
        self._validate(settings)
        if self.is_open:
            self._wrap("configure", self._configure, settings)
        self.settings = settings

    def arm(self) -> None:
        """Get ready for the next trigger (start acquisition if needed)."""
        self._require_open()
        self._wrap("arm", self._arm)
        self._armed = True

    def trigger(self) -> None:
        """Software trigger (no-op for free-run and hardware-triggered cameras)."""
        self._require_open()
        if self.settings.trigger == "software":
            self._wrap("trigger", self._trigger)

    def grab(self, timeout_s: float) -> Frame:
        """The next frame, or CameraTimeout after ``timeout_s``. Never blocks longer."""
        self._require_open()
        deadline = time.monotonic() + timeout_s
        frame = self._wrap("grab", self._grab, timeout_s)
        if frame is None or time.monotonic() > deadline + 0.05:
            raise CameraTimeout(f"{self.camera_id}: no frame within {timeout_s:.3g} s ({self.uri})",
                                hint="check the camera's cable, power and trigger wiring")
        self._check_frame(frame)
        self.last_frame = frame
        return frame

    def snap(self, timeout_s: float) -> Frame:
        """arm + trigger + grab: one frame now."""
        self.arm()
        self.trigger()
        return self.grab(timeout_s)

    def fault(self, reason: str) -> None:
        """Tell the driver its last cycle failed (e.g. a capture deadline passed while it was
        still busy); the next ``arm()`` re-establishes the connection. Never raises."""
        log.warning("%s: fault: %s", self.camera_id, reason)
        try:
            self._on_fault(reason)
        except Exception as e:  # noqa: BLE001 - reporting a fault must not fail
            log.warning("%s: error while marking a fault: %s", self.camera_id, e)

    def identity(self) -> CameraIdentity:
        self._require_open()
        return self._wrap("identity", self._identity)

    def close(self) -> None:
        if self.is_open:
            try:
                self._close()
            except Exception as e:  # closing must never raise; log and go on
                log.warning("%s: error while closing: %s", self.camera_id, e)
            self.is_open = False
            self._armed = False

    def state(self) -> dict:
        """What ``station cameras`` shows: open?, identity, last frame (never raises)."""
        out: dict[str, Any] = {"id": self.camera_id, "uri": self.uri, "open": self.is_open,
                               "driver": type(self).__name__}
        if self.is_open:
            try:
                out["identity"] = self.identity()
            except DriverError as e:
                out["error"] = str(e)
        if self.last_frame is not None:
            f = self.last_frame
            out["last_frame"] = {"frame_id": f.frame_id, "timestamp_ns": f.timestamp_ns,
                                 "shape": tuple(f.image.shape), "mean": float(f.image.mean())}
        return out

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    # --- to implement -----------------------------------------------------------------------
    @abstractmethod
    def _open(self) -> None:
        """Connect to the device (called once by :meth:`open`)."""

    def _configure(self, settings: CameraSettings) -> None:
        pass

    def _arm(self) -> None:
        pass

    def _trigger(self) -> None:
        pass

    @abstractmethod
    def _grab(self, timeout_s: float) -> Frame | None:
        """The next frame, or None when none came within ``timeout_s``."""

    def _identity(self) -> CameraIdentity:
        s = self.settings
        return CameraIdentity("unknown", type(self).__name__, self.uri, s.width, s.height)

    def _close(self) -> None:
        pass

    def _on_fault(self, reason: str) -> None:
        pass

    # --- helpers ----------------------------------------------------------------------------
    def _require_open(self):
        if not self.is_open:
            raise DriverError(f"{self.camera_id}: camera is not open ({self.uri})")

    def _validate(self, s: CameraSettings) -> None:
        if s.trigger not in TRIGGER_MODES:
            raise DriverError(f"{self.camera_id}: unknown trigger mode {s.trigger!r}; "
                              f"expected one of {', '.join(TRIGGER_MODES)}")
        if s.pixel_format not in PIXEL_FORMATS:
            raise DriverError(f"{self.camera_id}: unsupported pixel format {s.pixel_format!r}; "
                              f"expected one of {', '.join(PIXEL_FORMATS)}",
                              hint="fix pixel_format in the station configuration")
        if s.width <= 0 or s.height <= 0:
            raise DriverError(f"{self.camera_id}: resolution {s.width}x{s.height} is not positive")
        if s.roi is not None:
            x, y, w, h = s.roi
            if x < 0 or y < 0 or w <= 0 or h <= 0 or x + w > s.width or y + h > s.height:
                raise DriverError(f"{self.camera_id}: ROI {s.roi} does not fit the {s.width}x{s.height} sensor")

    def _wrap(self, what, fn, *args):
        try:
            return fn(*args)
        except DriverError:
            raise
        except Exception as e:
            raise DriverError(f"{self.camera_id}: {what} failed on {self.uri}: {e}") from e

    def _check_frame(self, frame: Frame) -> None:
        img = frame.image
        s = self.settings
        if not isinstance(img, np.ndarray) or img.dtype not in (np.uint8, np.uint16):
            raise FrameError(f"{self.camera_id}: frame is not an 8/16-bit image ({self.uri})")
        want = np.dtype(FRAME_DTYPE.get(s.pixel_format, np.uint8))
        if frame.metadata.get(AVERAGED_FRAMES_KEY, 1) > 1:
            want = np.dtype(np.uint16)
        if img.ndim != 2 or img.dtype != want:
            raise FrameError(f"{self.camera_id}: frame is {img.dtype} with shape {img.shape}, but "
                             f"{s.pixel_format} gives (H, W) {want} ({self.uri})",
                             hint="check the camera's pixel format")
        w, h = (s.roi[2], s.roi[3]) if s.roi else (s.width, s.height)
        if img.shape[:2] != (h, w):
            raise FrameError(f"{self.camera_id}: frame is {img.shape[1]}x{img.shape[0]}, "
                             f"the camera is configured for {w}x{h}",
                             hint="check the resolution in the station configuration")
