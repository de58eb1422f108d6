"""AravisCamera: GigE Vision / USB3 Vision cameras through Aravis 0.8 (PyGObject).

URI: ``aravis://ADDRESS[?line=Line0&buffers=4&packet_resend=1]``. ADDRESS is the camera's IP
(opened by unicast, never by discovery: discovery broadcasts on every interface, see
docs/cameras.md) or an Aravis device id (which makes Aravis search, i.e. broadcast for GigE:
use IP addresses for GigE cameras). Options: ``line`` the hardware trigger input used
in hardware-trigger mode (default Line0), ``buffers`` the size of the buffer pool (default 4),
``packet_resend=0`` to switch GigE Vision packet resend off (a lossy link then gives corrupt
buffers, reported as FrameError, instead of late ones), ``frame_retention_ms`` how long Aravis
waits for a frame's missing packets (default 1000).

Recovery: any timeout, lost control or failed GVCP command marks the camera suspect; the next
``arm()`` closes and reopens it (3 ms on a live camera), so the cycle after a camera comes
back works. If it is still gone, ``arm()`` raises CameraMissing naming it.

PyGObject and the Aravis typelib are imported only when such a camera is opened; if they are
missing the error says what to install.
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from urllib.parse import parse_qs

import cv2
import numpy as np

from drivers.base import CameraIdentity, CameraSettings, Frame, Camera
from drivers.context import DriverContext
from drivers.errors import CameraMissing, CameraTimeout, DriverError, FrameError

log = logging.getLogger("station.drivers.aravis")

# GenICam PFNC codes of the formats we accept (arv.h: ARV_PIXEL_FORMAT_*).
PFNC = {"Mono8": 0x01080001, "Mono16": 0x01100007, "BayerGR8": 0x01080008,
        "BayerRG8": 0x01080009, "BayerGB8": 0x0108000A, "BayerBG8": 0x0108000B}
# GenICam names the Bayer tile by its top-left 2x2; OpenCV's short names (BayerRG) are shifted
# by one pixel, its four-letter names (BayerRGGB) are not: use those.
DEBAYER = {"BayerRG8": cv2.COLOR_BayerRGGB2GRAY, "BayerGR8": cv2.COLOR_BayerGRBG2GRAY,
           "BayerGB8": cv2.COLOR_BayerGBRG2GRAY, "BayerBG8": cv2.COLOR_BayerBGGR2GRAY}
BUFFER_STATUS = {"timeout": "incomplete: packets still missing when the frame-retention time ran out",
                 "missing-packets": "packets missing", "wrong-packet-id": "packets out of sequence",
                 "size-mismatch": "image larger than the buffer", "filling": "still being filled",
                 "aborted": "acquisition aborted"}
INSTALL_HINT = ("install the Aravis typelib and PyGObject: apt-get install gir1.2-aravis-0.8 "
                "libgirepository1.0-dev libcairo2-dev pkg-config, then pip install 'pygobject<3.51' "
                "(or pip install '.[aravis]')")

_gi_lock = threading.Lock()
_gi_modules: tuple | None = None


def load_aravis():
    """(Aravis, GLib) from PyGObject, or DriverError naming what to install."""
    global _gi_modules
    with _gi_lock:
        if _gi_modules is None:
            try:
                import gi
                gi.require_version("Aravis", "0.8")
                from gi.repository import Aravis, GLib
            except (ImportError, ValueError) as e:
                raise DriverError(f"the aravis:// driver needs PyGObject and Aravis 0.8 ({e})",
                                  hint=INSTALL_HINT) from e
            _gi_modules = (Aravis, GLib)
    return _gi_modules


def parse_aravis_uri(uri: str) -> tuple[str, dict[str, str]]:
    rest = uri.split("://", 1)[1]
    address, _, query = rest.partition("?")
    address = address.rstrip("/")
    if not address:
        raise DriverError(f"{uri!r}: an aravis URI needs the camera's address, e.g. aravis://192.168.10.11")
    return address, {k: v[-1] for k, v in parse_qs(query).items()}


def _is_ipv4(address: str) -> bool:
    parts = address.split(".")
    return len(parts) == 4 and all(p.isdigit() and int(p) < 256 for p in parts)


def gvcp_ping(address: str, timeout_s: float = 0.3) -> bool:
    """Does a GigE Vision device answer a READREG of its version register (unicast, UDP 3956)?

    Cheap liveness check before reconnecting: Aravis itself needs ~2.5 s to give up on a dead
    camera. Packet layout: GigE Vision 2.0 spec, section 15 (GVCP header + READREG_CMD 0x0080).
    """
    request = struct.pack(">BBHHHI", 0x42, 0x01, 0x0080, 4, 0x7A11, 0x0000)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout_s)
        try:
            sock.sendto(request, (address, 3956))
            reply = sock.recv(64)
        except OSError:
            return False
    return len(reply) >= 8 and struct.unpack(">H", reply[2:4])[0] == 0x0081


# GenICam features that bend a camera's grey levels, and their linear setting (SFNC names).
LINEAR_RESPONSE = (("LUTEnable", False), ("GammaEnable", False), ("Gamma", 1.0))


def make_linear(cam, camera_id: str, address: str) -> list[str]:
    """Switch off what makes the camera's grey levels other than proportional to light, where
    the camera has it (``LINEAR_RESPONSE``); returns the features changed. The rim edge model
    assumes linear grey: an sRGB-like gamma (0.45) put wheels 0.17 deg off, unwarned
    (bench/perturbed_images.py). A camera that offers such a feature but refuses the linear
    value raises DriverError: make it linear by its own tool, or state its exponent
    (``response_gamma``), and the station decodes its images. ``cam``: an ArvCamera."""
    changed = []
    for name, linear in LINEAR_RESPONSE:
        if not cam.is_feature_available(name):
            continue
        if name == "Gamma" and cam.is_feature_available("GammaEnable") and not cam.get_boolean("GammaEnable"):
            continue  # switched off: its value no longer applies (and may be locked)
        get, put = (cam.get_boolean, cam.set_boolean) if isinstance(linear, bool) else (cam.get_float, cam.set_float)
        try:
            value = get(name)
        except Exception as e:  # GLib.Error: a node of another type, or not readable: nothing known to undo
            log.warning("%s: cannot read %s (%s); its grey response is assumed linear", camera_id, name, e)
            continue
        if np.isclose(value, linear):
            continue
        try:
            put(name, linear)
            ok = bool(np.isclose(get(name), linear))
        except Exception:  # GLib.Error: a read-only or locked feature
            ok = False
        if not ok:
            raise DriverError(f"{camera_id}: the camera at {address} does not let {name} be set to {linear} "
                              f"(its grey levels are then not proportional to light)",
                              hint=f"make the camera linear with its own tool, or set cameras.{camera_id}."
                                   f"response_gamma to the exponent it applies (docs/configuration.md)")
        changed.append(name)
    if changed:
        log.info("%s: %s set for a linear grey response", camera_id, ", ".join(changed))
    return changed


def _dispose(handles: list) -> None:
    """Stop and drop [camera, stream] of a dead camera (runs in a background thread)."""
    cam = handles[0]
    try:
        if cam is not None:
            cam.stop_acquisition()
            dev = cam.get_device()
            if hasattr(dev, "leave_control"):
                dev.leave_control()
    except Exception:  # noqa: BLE001 - the camera is gone; only the handle is left to drop
        pass
    del cam
    handles.clear()


class AravisCamera(Camera):
    scheme = "aravis"

    def __init__(self, camera_id: str, uri: str, settings: CameraSettings | None = None,
                 context: DriverContext | None = None):
        super().__init__(camera_id, uri, settings, context)
        self.address, opts = parse_aravis_uri(uri)
        self.trigger_line = opts.get("line", "Line0")
        self.n_buffers = max(2, int(opts.get("buffers", 4)))
        self.packet_resend = opts.get("packet_resend", "1") not in ("0", "false", "no")
        self.frame_retention_us = int(float(opts.get("frame_retention_ms", 1000)) * 1000)
        self._cam = None
        self._handler = None
        self._stream = None
        self._payload = 0
        self._suspect = False
        self._lock = threading.RLock()
        self.reconnects = 0

    # --- open / close -----------------------------------------------------------------------
    def _open(self) -> None:
        Aravis, GLib = load_aravis()
        try:
            cam = Aravis.Camera.new(self.address)
        except GLib.Error as e:
            raise CameraMissing(f"{self.camera_id}: no camera answers at {self.address} ({e.message})",
                                hint="check the camera's power, cable and IP address") from None
        self._handler = cam.get_device().connect("control-lost", self._on_control_lost)
        self._cam, self._stream, self._suspect = cam, None, False

    def _close(self) -> None:
        with self._lock:
            self._stop()
            self._release()

    def _release(self) -> None:
        """Drop the camera, giving GigE Vision control back at once: a camera grants control to
        one client, and waiting for the garbage collector would lock out the next open."""
        cam, self._cam = self._cam, None
        if cam is None:
            return
        try:
            dev = cam.get_device()
            if self._handler is not None:
                dev.disconnect(self._handler)
            if hasattr(dev, "leave_control"):
                dev.leave_control()
        except Exception as e:  # the camera may be gone already
            log.debug("%s: releasing %s: %s", self.camera_id, self.address, e)
        self._handler = None

    def _stop(self) -> None:
        if self._stream is not None and self._cam is not None:
            try:
                self._cam.stop_acquisition()
            except Exception as e:  # the camera may be gone; the stream goes anyway
                log.debug("%s: stop_acquisition: %s", self.camera_id, e)
        self._stream = None

    def _on_control_lost(self, *_):  # runs in Aravis' heartbeat thread
        log.warning("%s: control of %s lost", self.camera_id, self.address)
        self._suspect = True

    def _on_fault(self, reason: str) -> None:
        # A camera that rebooted accepts GVCP writes from our old handle but streams nowhere:
        # after any failed cycle, reconnect rather than trust the handle.
        self._suspect = True

    def _reopen(self) -> None:
        log.info("%s: reconnecting to %s", self.camera_id, self.address)
        if _is_ipv4(self.address) and not gvcp_ping(self.address):
            # Every GVCP command to a dead camera blocks ~2.5 s: let the old handle go in the
            # background rather than stopping it here.
            # Dropping the last reference to a stream joins its thread (seconds): that too.
            handles = [self._cam, self._stream]
            self._cam, self._stream, self._handler = None, None, None
            threading.Thread(target=_dispose, args=(handles,), daemon=True).start()
            del handles
            raise CameraMissing(f"{self.camera_id}: the camera at {self.address} does not answer",
                                hint="check the camera's power and cable; the next cycle retries")
        self._stop()
        self._release()
        self._open()
        self._configure(self.settings)
        self.reconnects += 1

    # --- configuration ----------------------------------------------------------------------
    def _configure(self, s: CameraSettings) -> None:
        _, GLib = load_aravis()
        with self._lock:
            self._stop()
            cam = self._cam
            try:
                available = list(cam.dup_available_pixel_formats_as_strings() or [])
                if s.pixel_format not in available:
                    raise DriverError(f"{self.camera_id}: pixel format {s.pixel_format} is not offered by "
                                      f"the camera at {self.address} (it offers {', '.join(available)})",
                                      hint="fix pixel_format in the station configuration")
                cam.set_pixel_format_from_string(s.pixel_format)
                sensor = cam.get_sensor_size()
                if (s.width, s.height) != (sensor.width, sensor.height):
                    wb, hb = cam.get_width_bounds(), cam.get_height_bounds()
                    if not (wb.min <= s.width <= min(wb.max, sensor.width)
                            and hb.min <= s.height <= min(hb.max, sensor.height)):
                        raise DriverError(f"{self.camera_id}: {s.width}x{s.height} does not fit the camera's "
                                          f"{sensor.width}x{sensor.height} sensor ({self.address})")
                x, y, w, h = s.roi if s.roi else (0, 0, s.width, s.height)
                cam.set_region(x, y, w, h)
                got = cam.get_region()
                if (got.x, got.y, got.width, got.height) != (x, y, w, h):
                    raise DriverError(f"{self.camera_id}: asked for region {(x, y, w, h)}, the camera set "
                                      f"{(got.x, got.y, got.width, got.height)}")
                self._set_bounded("exposure", cam.get_exposure_time_bounds(), s.exposure_us,
                                  cam.set_exposure_time, "us")
                if cam.is_gain_available():
                    self._set_bounded("gain", cam.get_gain_bounds(), s.gain_db, cam.set_gain, "dB")
                self._set_trigger(s.trigger)
                if s.response_gamma == 1.0:
                    make_linear(cam, self.camera_id, self.address)
                self._payload = cam.get_payload()
            except GLib.Error as e:
                raise DriverError(f"{self.camera_id}: configuring {self.address} failed: {e.message}") from None

    def _set_bounded(self, what, bounds, value, setter, unit):
        if not bounds.min <= value <= bounds.max:
            raise DriverError(f"{self.camera_id}: {what} {value:g} {unit} is outside the camera's range "
                              f"{bounds.min:g}..{bounds.max:g} {unit}")
        setter(value)

    def _set_trigger(self, mode: str) -> None:
        cam = self._cam
        Aravis, _ = load_aravis()
        cam.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
        if cam.is_feature_available("TriggerSelector"):
            cam.set_string("TriggerSelector", "FrameStart")
        if mode == "free-run":
            cam.set_string("TriggerMode", "Off")
            return
        source = "Software" if mode == "software" else self.trigger_line
        sources = list(cam.dup_available_trigger_sources() or [])
        if source not in sources:
            raise DriverError(f"{self.camera_id}: trigger source {source} is not offered by {self.address} "
                              f"(it offers {', '.join(sources)})",
                              hint="set ?line=LineN in the camera URI to the wired trigger input")
        cam.set_string("TriggerMode", "On")
        cam.set_string("TriggerSource", source)
        if mode == "hardware" and cam.is_feature_available("TriggerActivation"):
            cam.set_string("TriggerActivation", "RisingEdge")

    # --- GenICam features -------------------------------------------------------------------
    def get_feature(self, name: str):
        """Read any GenICam feature (int, float, bool or enum/string), by its name."""
        _, GLib = load_aravis()
        self._require_open()
        with self._lock:
            dev = self._cam.get_device()
            try:
                node = dev.get_feature(name)
                if node is None:
                    raise DriverError(f"{self.camera_id}: the camera has no feature {name!r}")
                kind = type(node).__name__
                if "Integer" in kind:
                    return dev.get_integer_feature_value(name)
                if "Float" in kind:
                    return dev.get_float_feature_value(name)
                if "Boolean" in kind:
                    return dev.get_boolean_feature_value(name)
                return dev.get_string_feature_value(name)
            except GLib.Error as e:
                raise DriverError(f"{self.camera_id}: reading {name} failed: {e.message}") from None

    def set_feature(self, name: str, value) -> None:
        """Write a GenICam feature; the type follows ``value`` (bool, int, float or str)."""
        _, GLib = load_aravis()
        self._require_open()
        with self._lock:
            dev = self._cam.get_device()
            try:
                if dev.get_feature(name) is None:
                    raise DriverError(f"{self.camera_id}: the camera has no feature {name!r}")
                if isinstance(value, bool):
                    dev.set_boolean_feature_value(name, value)
                elif isinstance(value, int):
                    dev.set_integer_feature_value(name, value)
                elif isinstance(value, float):
                    dev.set_float_feature_value(name, value)
                else:
                    dev.set_string_feature_value(name, str(value))
            except GLib.Error as e:
                raise DriverError(f"{self.camera_id}: setting {name} = {value!r} failed: {e.message}") from None

    # --- acquisition ------------------------------------------------------------------------
    def _arm(self) -> None:
        Aravis, GLib = load_aravis()
        with self._lock:
            if self._suspect or self._cam is None:
                self._reopen()
            try:
                if self._stream is None:
                    stream = self._cam.create_stream(None, None)
                    if stream is None:
                        raise DriverError(f"{self.camera_id}: could not open a stream from {self.address}")
                    if hasattr(Aravis, "GvStream") and isinstance(stream, Aravis.GvStream):
                        self._tune_gv_stream(stream, Aravis)
                    for _ in range(self.n_buffers):
                        stream.push_buffer(Aravis.Buffer.new_allocate(self._payload))
                    self._cam.start_acquisition()
                    self._stream = stream
                # Drop frames that arrived before this arm (free-run, stray triggers).
                while (buf := self._stream.try_pop_buffer()) is not None:
                    self._stream.push_buffer(buf)
            except GLib.Error as e:
                self._suspect = True
                raise CameraMissing(f"{self.camera_id}: arming {self.address} failed: {e.message}") from None

    def _tune_gv_stream(self, stream, Aravis) -> None:
        """GigE Vision stream settings for eight cameras on one busy host.

        Aravis drops a frame whose packets are not all in within ``frame-retention`` (default
        100 ms) and marks it TIMEOUT; on a loaded host eight 1.3 MB frames arriving together
        exceed that, so keep frames for up to 1 s (our own deadline still bounds every wait),
        and let Aravis size the socket buffer to the payload.
        """
        stream.set_property("frame-retention", self.frame_retention_us)
        stream.set_property("socket-buffer", Aravis.GvStreamSocketBuffer.AUTO)
        if not self.packet_resend:
            stream.set_property("packet-resend", Aravis.GvStreamPacketResend.NEVER)

    def _trigger(self) -> None:
        _, GLib = load_aravis()
        with self._lock:
            try:
                self._cam.software_trigger()
            except GLib.Error as e:
                self._suspect = True
                raise CameraMissing(f"{self.camera_id}: software trigger to {self.address} failed "
                                    f"({e.message})", hint="check the camera's power and cable") from None

    def _grab(self, timeout_s: float) -> Frame | None:
        Aravis, _ = load_aravis()
        stream = self._stream
        if stream is None:
            raise DriverError(f"{self.camera_id}: grab before arm")
        buf = stream.timeout_pop_buffer(max(1, int(timeout_s * 1e6)))
        t_ns = time.monotonic_ns()
        if buf is None:
            self._suspect = True  # cheap to check: the next arm reconnects
            raise CameraTimeout(f"{self.camera_id}: no frame within {timeout_s:.3g} s from {self.address}",
                                hint="check the camera's cable, power and trigger wiring")
        try:
            status = buf.get_status()
            if status != Aravis.BufferStatus.SUCCESS:
                nick = getattr(status, "value_nick", str(status))
                raise FrameError(f"{self.camera_id}: corrupt buffer from {self.address} "
                                 f"({BUFFER_STATUS.get(nick, nick)})",
                                 hint="check the network link (packet loss) and the camera's packet size")
            image = self._to_numpy(buf)
            md = {"camera_timestamp_ns": int(buf.get_timestamp()), "pixel_format": self.settings.pixel_format,
                  "system_timestamp_ns": int(buf.get_system_timestamp()), "address": self.address}
            return Frame(self.camera_id, image, t_ns, int(buf.get_frame_id()), md)
        finally:
            stream.push_buffer(buf)

    def _to_numpy(self, buf) -> np.ndarray:
        """(H, W) uint8 / uint16 copy of a buffer; FrameError if it does not match the settings."""
        fmt = self.settings.pixel_format
        code = buf.get_image_pixel_format()
        if code != PFNC[fmt]:
            names = {v: k for k, v in PFNC.items()}
            raise FrameError(f"{self.camera_id}: the camera sent {names.get(code, hex(code))}, "
                             f"configured for {fmt} ({self.address})")
        w, h = buf.get_image_width(), buf.get_image_height()
        dtype = np.dtype("<u2") if fmt == "Mono16" else np.dtype(np.uint8)
        data = buf.get_image_data()
        if data is None or len(data) < w * h * dtype.itemsize:
            raise FrameError(f"{self.camera_id}: corrupt buffer from {self.address}: "
                             f"{0 if data is None else len(data)} bytes for a {w}x{h} {fmt} image")
        image = np.frombuffer(data, dtype, count=w * h).reshape(h, w)
        if fmt in DEBAYER:
            return cv2.cvtColor(image, DEBAYER[fmt])
        return image.astype(np.uint16) if fmt == "Mono16" else image.copy()

    def _identity(self) -> CameraIdentity:
        _, GLib = load_aravis()
        with self._lock:
            try:
                cam = self._cam
                region = cam.get_region()
                return CameraIdentity(cam.get_vendor_name() or "", cam.get_model_name() or "",
                                      cam.get_device_serial_number() or "", region.width, region.height)
            except GLib.Error as e:
                self._suspect = True
                raise CameraMissing(f"{self.camera_id}: {self.address} does not answer ({e.message})") from None
