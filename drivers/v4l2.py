"""V4L2Camera: UVC and other V4L2 cameras through OpenCV's V4L2 backend.

URI: ``v4l2:///dev/videoN``. OpenCV (already a dependency) rather than linuxpy: it does the
buffer queueing and format conversion we need, and one small ioctl (VIDIOC_QUERYCAP, below)
tells "no such device", "not a V4L2 capture device" and "busy" apart before OpenCV hides the
reason behind ``isOpened() == False``.

Formats: Mono8 asks for GREY (grey camera) and otherwise converts the camera's colour to grey;
Mono16 asks for Y16; Bayer is refused (OpenCV's V4L2 backend demosaics internally). Exposure:
V4L2's ``exposure_time_absolute`` counts 100 us steps, so exposure_us / 100; gain is the
driver's raw gain value (UVC has no dB unit), documented in docs/cameras.md. UVC cameras have
no trigger input: software trigger = the first frame exposed after ``trigger()``; hardware
trigger is refused.
"""

from __future__ import annotations

import errno
import fcntl
import os
import struct
import threading
import time

import cv2
import numpy as np

from drivers.base import Camera, CameraIdentity, CameraSettings, Frame
from drivers.context import DriverContext
from drivers.errors import CameraMissing, DriverError, FrameError

VIDIOC_QUERYCAP = 0x80685600  # _IOR('V', 0, struct v4l2_capability), 104 bytes
V4L2_CAP_VIDEO_CAPTURE = 0x00000001
V4L2_CAP_DEVICE_CAPS = 0x80000000
FOURCC = {"Mono8": "GREY", "Mono16": "Y16 "}


def querycap(path: str) -> dict:
    """VIDIOC_QUERYCAP on ``path``: {'driver', 'card', 'bus', 'caps'}; OSError as the kernel says."""
    fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
    try:
        buf = bytearray(104)
        fcntl.ioctl(fd, VIDIOC_QUERYCAP, buf)
    finally:
        os.close(fd)
    driver, card, bus, _version, caps, device_caps = struct.unpack_from("16s32s32sIII", buf)
    text = lambda b: b.split(b"\0", 1)[0].decode("ascii", "replace")  # noqa: E731
    return {"driver": text(driver), "card": text(card), "bus": text(bus),
            "caps": device_caps if caps & V4L2_CAP_DEVICE_CAPS else caps}


class V4L2Camera(Camera):
    scheme = "v4l2"

    def __init__(self, camera_id: str, uri: str, settings: CameraSettings | None = None,
                 context: DriverContext | None = None):
        super().__init__(camera_id, uri, settings, context)
        self.path = uri.split("://", 1)[1].partition("?")[0]
        self._cap = None
        self._info: dict = {}
        self._trigger_ns = 0
        self._n = 0
        self._lock = threading.Lock()

    def _open(self) -> None:
        if not os.path.exists(self.path):
            raise CameraMissing(f"{self.camera_id}: no device {self.path} ({self.uri})",
                                hint="check the USB cable; `ls /dev/video*` lists the connected cameras")
        try:
            self._info = querycap(self.path)
        except OSError as e:
            if e.errno in (errno.EACCES, errno.EPERM):
                raise DriverError(f"{self.camera_id}: no permission to open {self.path}",
                                  hint="add the station's user to the 'video' group") from None
            if e.errno in (errno.ENOTTY, errno.EINVAL):
                raise DriverError(f"{self.camera_id}: {self.path} is not a V4L2 device") from None
            if e.errno == errno.EBUSY:
                raise DriverError(f"{self.camera_id}: {self.path} is busy (another program uses it)") from None
            raise CameraMissing(f"{self.camera_id}: cannot open {self.path} ({e.strerror})") from None
        if not self._info["caps"] & V4L2_CAP_VIDEO_CAPTURE:
            raise DriverError(f"{self.camera_id}: {self.path} ({self._info['card']}) is not a video capture "
                              "node (a UVC camera has several /dev/video*; use the first)")
        cap = cv2.VideoCapture(self.path, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise DriverError(f"{self.camera_id}: {self.path} ({self._info['card']}) cannot stream: busy "
                              "(another program uses it) or no format OpenCV can read",
                              hint="close other camera programs (fuser /dev/videoN)")
        self._cap = cap

    def _configure(self, s: CameraSettings) -> None:
        cap = self._cap
        if s.pixel_format not in FOURCC:
            raise DriverError(f"{self.camera_id}: unsupported pixel format {s.pixel_format} for a V4L2 camera "
                              f"(Mono8 or Mono16)")
        if s.trigger == "hardware":
            raise DriverError(f"{self.camera_id}: V4L2 cameras have no hardware trigger input; "
                              "use trigger: software or free-run")
        if s.roi is not None:
            raise DriverError(f"{self.camera_id}: V4L2 cameras take no ROI here; set the resolution instead")
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*FOURCC[s.pixel_format]))
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, s.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, s.height)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        got = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        if got != (s.width, s.height):
            raise DriverError(f"{self.camera_id}: {self.path} does not offer {s.width}x{s.height} "
                              f"(it set {got[0]}x{got[1]})", hint="fix the resolution in the station configuration")
        self._native = int(cap.get(cv2.CAP_PROP_FOURCC)) == cv2.VideoWriter_fourcc(*FOURCC[s.pixel_format])
        if s.pixel_format == "Mono16" and not self._native:
            raise DriverError(f"{self.camera_id}: {self.path} does not offer Y16 (16-bit grey)")
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0 if self._native else 1)
        cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2_EXPOSURE_MANUAL
        cap.set(cv2.CAP_PROP_EXPOSURE, s.exposure_us / 100.0)
        cap.set(cv2.CAP_PROP_GAIN, s.gain_db)

    def _arm(self) -> None:
        self._trigger_ns = time.monotonic_ns()

    def _trigger(self) -> None:
        self._trigger_ns = time.monotonic_ns()

    def _grab(self, timeout_s: float) -> Frame | None:
        deadline = time.monotonic() + timeout_s
        while True:
            image, t_ns = self._read(max(0.0, deadline - time.monotonic()))
            if image is None:
                return None
            # A frame exposed before the trigger sat in the driver's queue: take the next one.
            if t_ns >= self._trigger_ns or time.monotonic() >= deadline:
                break
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        elif self.settings.pixel_format == "Mono16":
            image = image.view(np.uint16).reshape(image.shape[0], -1) if image.dtype == np.uint8 else image
        self._n += 1
        return Frame(self.camera_id, np.ascontiguousarray(image), t_ns, self._n,
                     {"pixel_format": self.settings.pixel_format, "device": self.path})

    def _read(self, timeout_s: float):
        """cap.read() bounded by ``timeout_s`` (OpenCV's own V4L2 timeout is 10 s)."""
        box = {}

        def read():
            with self._lock:
                ok, img = self._cap.read()
            box["r"] = (img if ok else None, time.monotonic_ns())

        t = threading.Thread(target=read, daemon=True)
        t.start()
        t.join(timeout_s)
        if t.is_alive() or "r" not in box:
            return None, 0
        image, t_ns = box["r"]
        if image is None:
            raise FrameError(f"{self.camera_id}: {self.path} gave no frame (unplugged, or busy?)")
        return image, t_ns

    def _identity(self) -> CameraIdentity:
        s = self.settings
        return CameraIdentity(self._info.get("driver", ""), self._info.get("card", ""),
                              self._info.get("bus", ""), s.width, s.height)

    def _close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
