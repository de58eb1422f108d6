"""Synchronised capture of one cycle from the station's eight cameras.

    cameras = open_station_cameras(config, context)          # all open, or ONE error listing all
    frames = capture_cycle(cameras, config.capture.timeout_s, trigger_board)
    path = save_capture(frames, config.data_path("captures", new_cycle_id()))

A cycle: every camera is armed (concurrently), then one trigger - the trigger board fires
every hardware trigger input and the strobes at once, and software-triggered cameras get
their trigger from threads released together - then every camera's frame is collected
concurrently within ONE deadline. Timestamps are checked (no frame older than the trigger,
none after the deadline, no repeated frame, optional skew limit). A missing, late or broken
camera fails the cycle with one error naming every such camera; the frames that did arrive
ride on the error (``e.frames``) so ``capture_and_save`` can keep them: nothing is lost.
With ``capture.frames_averaged`` N > 1 a cycle takes N such sets and keeps each camera's mean
(``capture_averaged``, station/frame_average.py).
"""

from __future__ import annotations

import datetime as _dt
import itertools
import logging
import threading
import time
from pathlib import Path
from typing import Callable

from drivers.base import Camera, CameraSettings, Frame
from drivers.frame_store import save_cycle
from drivers.registry import create_camera, uri_address
from station.errors import CameraMissing, CameraTimeout, DriverError, FrameError, StationError
from station.frame_average import averaged_frames

log = logging.getLogger("station.capture")

STALE_TOLERANCE_NS = 5_000_000  # a frame stamped >5 ms before the trigger is a leftover
OPEN_TIMEOUT_S = 15.0  # a GigE camera that does not answer takes ~2.5 s to give up
_cycle_counter = itertools.count(1)


# --- errors that carry what is known ----------------------------------------------------------
def _failure_error(what: str, failures: dict[str, BaseException], frames: dict | None = None) -> StationError:
    """One error naming every failed camera; its class follows the kind of failure."""
    kinds = [type(e) for e in failures.values()]
    if len(set(kinds)) == 1 and issubclass(kinds[0], StationError):
        cls = kinds[0]
    elif any(issubclass(k, CameraMissing) for k in kinds):
        cls = CameraMissing
    elif all(issubclass(k, CameraTimeout) for k in kinds):
        cls = CameraTimeout
    elif all(issubclass(k, FrameError) for k in kinds):
        cls = FrameError
    else:
        cls = DriverError
    names = ", ".join(sorted(failures))
    detail = "; ".join(f"{cid}: {_reason(cid, e)}" for cid, e in sorted(failures.items()))
    hints = sorted({e.hint for e in failures.values() if getattr(e, "hint", None)})
    err = cls(f"{what} failed for {len(failures)} camera(s) ({names}): {detail}",
              hint="; ".join(hints) or None)
    err.failures = {cid: _reason(cid, e) for cid, e in failures.items()}
    err.frames = dict(frames or {})
    return err


def _reason(cam_id: str, e: BaseException) -> str:
    text = str(e)
    return text[len(cam_id) + 2:] if text.startswith(cam_id + ": ") else text


def _run_parallel(items: dict[str, Callable[[], object]], deadline: float, what: str):
    """Run each callable in its own thread; (results, failures) by key, all within ``deadline``."""
    results: dict[str, object] = {}
    failures: dict[str, BaseException] = {}

    def work(key, fn):
        try:
            results[key] = fn()
        except BaseException as e:  # noqa: BLE001 - reported per camera below
            failures[key] = e if isinstance(e, StationError) else DriverError(f"{key}: {what}: {e}")

    threads = {k: threading.Thread(target=work, args=(k, fn), daemon=True, name=f"{what}-{k}")
               for k, fn in items.items()}
    for t in threads.values():
        t.start()
    for key, t in threads.items():
        t.join(max(0.0, deadline - time.monotonic()))
        if t.is_alive():
            failures[key] = CameraTimeout(f"{key}: no answer before the deadline ({what} still waiting)",
                                          hint="check the camera's power and cable")
    return results, failures


def board_line(cam_id: str, cam: Camera) -> int | None:
    """The trigger board output wired to a camera: the camera's ``line`` if its driver has an
    integer one (sim://camN?line=K), else the documented default: camN on output N-1."""
    line = getattr(cam, "line", None)
    if isinstance(line, int):
        return line
    digits = "".join(ch for ch in cam_id if ch.isdigit())
    return int(digits) - 1 if digits else None


# --- opening ---------------------------------------------------------------------------------
def settings_for(cam_cfg) -> CameraSettings:
    """CameraSettings from a station.config.CameraConfig."""
    return CameraSettings(width=cam_cfg.width, height=cam_cfg.height, pixel_format=cam_cfg.pixel_format,
                          exposure_us=float(cam_cfg.exposure_us), gain_db=float(cam_cfg.gain_db),
                          trigger=cam_cfg.trigger, response_gamma=float(cam_cfg.response_gamma))


def check_unique_addresses(uris: dict[str, str]) -> None:
    """DriverError if two cameras name the same device (after normalising the URIs)."""
    seen: dict[str, str] = {}
    clashes = []
    for cam_id, uri in uris.items():
        addr = uri_address(uri, cam_id)
        if addr in seen:
            clashes.append(f"{cam_id} and {seen[addr]} both use {addr}")
        seen.setdefault(addr, cam_id)
    if clashes:
        raise DriverError("two cameras cannot share an address: " + "; ".join(clashes),
                          hint="give every camera its own URI in the station configuration")


def open_cameras(specs: dict[str, tuple[str, CameraSettings]], context: dict | None = None,
                 timeout_s: float = OPEN_TIMEOUT_S) -> tuple[dict[str, Camera], dict[str, str]]:
    """Open cameras concurrently: (the open ones, {camera id: why it failed}). Never raises."""
    check_unique_addresses({cid: uri for cid, (uri, _) in specs.items()})
    cams: dict[str, Camera] = {}
    failures: dict[str, BaseException] = {}
    for cam_id, (uri, settings) in specs.items():
        try:
            cams[cam_id] = create_camera(cam_id, uri, settings, context)
        except StationError as e:
            failures[cam_id] = e
    _, open_fail = _run_parallel({cid: c.open for cid, c in cams.items()},
                                 time.monotonic() + timeout_s, "open")
    failures.update(open_fail)
    for cid in open_fail:
        cams.pop(cid).close()
    return cams, failures


def open_station_cameras(config, context: dict | None = None,
                         ids: list[str] | None = None) -> dict[str, Camera]:
    """Open the configured cameras (all, or ``ids``); ONE error listing every camera that failed.

    ``context`` reaches the drivers: ``{"sim_world": world}`` for sim://, plus
    ``{"trigger_lines": lines}`` for simulated hardware triggers.
    """
    ids = list(ids or config.cameras)
    specs = {cid: (config.cameras[cid].uri, settings_for(config.cameras[cid])) for cid in ids}
    cams, failures = open_cameras(specs, context)
    if failures:
        for c in cams.values():
            c.close()
        raise _failure_error("opening the cameras", failures)
    return {cid: cams[cid] for cid in ids}


def open_trigger_board(config, context: dict | None = None):
    """The configured trigger board, open (drivers.trigger_board.TriggerBoard), or None when the
    cameras trigger themselves (``trigger_board.port: null``). ``trigger_board.port: sim`` uses
    the simulated board that ``build_context`` started (``context["trigger_board_port"]``)."""
    port = (context or {}).get("trigger_board_port", config.trigger_board.port)
    if not port:
        return None
    if port == "sim":
        raise DriverError("trigger_board.port is 'sim' but no simulated board was started",
                          hint="sim needs sim:// cameras (drivers.registry.build_context starts the board)")
    from drivers.trigger_board import TriggerBoard
    return TriggerBoard(port, config.trigger_board.baudrate).open()


def close_cameras(cameras: dict[str, Camera]) -> None:
    for c in cameras.values():
        c.close()


# --- one cycle -------------------------------------------------------------------------------
def capture_cycle(cameras: dict[str, Camera], timeout_s: float, trigger_board=None,
                  max_skew_s: float | None = None) -> dict[str, Frame]:
    """One synchronised set: {camera id: Frame}, or one error naming every failed camera.

    Every wait shares one deadline, ``timeout_s`` from the call. With ``trigger_board`` (a
    drivers.trigger_board.TriggerBoard) the board fires once after every camera is armed;
    cameras in software mode are triggered by software at the same moment. ``max_skew_s``
    bounds the spread of the frames' timestamps (None: only the deadline bounds it).
    The error's ``frames`` holds the frames that did arrive, ``failures`` the reasons.
    """
    if not cameras:
        raise DriverError("capture: no cameras to capture from")
    deadline = time.monotonic() + timeout_s
    _, failures = _run_parallel({cid: c.arm for cid, c in cameras.items()}, deadline, "arm")
    ready = {cid: c for cid, c in cameras.items() if cid not in failures}
    previous_ids = {cid: (c.last_frame.frame_id if c.last_frame else None) for cid, c in ready.items()}

    go = threading.Event()
    trigger_ns = time.monotonic_ns()

    def take(cam: Camera) -> Frame:
        go.wait(max(0.0, deadline - time.monotonic()))
        cam.trigger()  # no-op unless the camera is in software-trigger mode
        frame = cam.grab(max(0.0, deadline - time.monotonic()))
        # A free-running camera: skip frames exposed before the trigger.
        while cam.settings.trigger == "free-run" and frame.timestamp_ns < trigger_ns - STALE_TOLERANCE_NS:
            frame = cam.grab(max(0.0, deadline - time.monotonic()))
        return frame

    board_report = None
    threads_fns = {cid: (lambda c=c: take(c)) for cid, c in ready.items()}
    box: dict = {}

    def collect():
        box["r"] = _run_parallel(threads_fns, deadline, "grab")

    collector = threading.Thread(target=collect, daemon=True)
    collector.start()
    trigger_ns = time.monotonic_ns()
    board_failures: dict[str, BaseException] = {}
    if trigger_board is not None:
        try:
            board_report = trigger_board.fire()
        except StationError as e:
            dead = getattr(e, "dead_lines", None)
            hw = {cid: c for cid, c in ready.items() if c.settings.trigger == "hardware"}
            if dead is None:  # the board did not fire at all: every hardware-triggered camera
                board_failures = {cid: e for cid in hw}
            else:  # it fired, but not on every output: name the cameras on the dead lines
                board_failures = {cid: type(e)(f"trigger line {board_line(cid, c)} did not fire (cut trigger "
                                               "cable?)", hint=e.hint)
                                  for cid, c in hw.items() if board_line(cid, c) in dead}
    go.set()
    collector.join(max(0.0, deadline - time.monotonic()) + 0.5)
    frames, grab_fail = box.get("r", ({}, {cid: CameraTimeout(f"{cid}: no frame") for cid in ready}))
    failures.update(grab_fail)
    failures.update(board_failures)  # the board's reason beats "no frame"

    deadline_ns = trigger_ns + int(timeout_s * 1e9)
    for cid, f in list(frames.items()):
        problem = None
        if f.timestamp_ns < trigger_ns - STALE_TOLERANCE_NS:
            problem = FrameError(f"{cid}: stale frame, stamped {(trigger_ns - f.timestamp_ns) / 1e6:.1f} ms "
                                 "before the trigger (a leftover buffer)")
        elif f.timestamp_ns > deadline_ns + 50_000_000:
            problem = CameraTimeout(f"{cid}: late frame, {(f.timestamp_ns - trigger_ns) / 1e9:.3f} s after the trigger")
        elif previous_ids.get(cid) is not None and f.frame_id == previous_ids[cid] and f.frame_id != 0:
            problem = FrameError(f"{cid}: the camera repeated frame {f.frame_id} of the previous cycle")
        if problem:
            failures[cid] = problem
            continue
        f.metadata["trigger_ns"] = trigger_ns
        f.metadata["latency_ms"] = round((f.timestamp_ns - trigger_ns) / 1e6, 3)
        if board_report is not None:
            f.metadata["board_seq"] = board_report.seq
            f.metadata["board_time_us"] = board_report.board_time_us
    good = {cid: f for cid, f in frames.items() if cid not in failures}
    if max_skew_s is not None and len(good) > 1:
        first = min(f.timestamp_ns for f in good.values())
        for cid, f in good.items():
            if f.timestamp_ns - first > max_skew_s * 1e9:
                failures[cid] = CameraTimeout(f"{cid}: frame {(f.timestamp_ns - first) / 1e6:.1f} ms after the "
                                              f"first camera's (limit {max_skew_s * 1e3:.0f} ms)")
    for cid, e in failures.items():
        cameras[cid].fault(str(e))
    if failures:
        raise _failure_error("capture", failures, {c: f for c, f in frames.items() if c not in failures})
    return {cid: frames[cid] for cid in cameras}


def capture_averaged(cameras: dict[str, Camera], timeout_s: float, trigger_board=None,
                     max_skew_s: float | None = None, frames: int = 1) -> dict[str, Frame]:
    """``frames`` synchronised sets (capture_cycle, each with its own deadline), averaged per
    camera (station/frame_average.py): {camera id: Frame}. One set when ``frames`` is 1 or a
    camera replays saved frames (``Camera.exposes`` False): a kept burst is already averaged."""
    if frames <= 1 or not all(c.exposes for c in cameras.values()):
        return capture_cycle(cameras, timeout_s, trigger_board, max_skew_s)
    return averaged_frames([capture_cycle(cameras, timeout_s, trigger_board, max_skew_s) for _ in range(frames)])


# --- saving ----------------------------------------------------------------------------------
def new_cycle_id() -> str:
    """A sortable, unique id: UTC time to the millisecond + a process counter."""
    now = _dt.datetime.now(_dt.timezone.utc)
    return f"{now:%Y%m%dT%H%M%S}{now.microsecond // 1000:03d}Z-{next(_cycle_counter):04d}"


def save_capture(frames: dict[str, Frame], directory, *, cycle_id: str | None = None,
                 failures: dict[str, str] | None = None, truth: dict | None = None,
                 extra: dict | None = None) -> Path:
    """Save a (possibly partial) set losslessly with its metadata (docs/replay-format.md)."""
    directory = Path(directory)
    meta = {"cycle_id": cycle_id or directory.name,
            "saved_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"),
            "complete": not failures, "failures": dict(failures or {}), **(extra or {})}
    return save_cycle(directory, frames, extra=meta, truth=truth)


def capture_and_save(cameras: dict[str, Camera], timeout_s: float, out_dir, *, trigger_board=None,
                     max_skew_s: float | None = None, truth: dict | None = None,
                     extra: dict | None = None, frames_averaged: int = 1) -> tuple[dict[str, Frame], Path]:
    """capture_averaged, then save; a failed cycle's partial frames are saved too, then it raises.

    The error then has ``saved_to`` (the directory) besides ``frames`` and ``failures``.
    """
    out_dir = Path(out_dir)
    try:
        frames = capture_averaged(cameras, timeout_s, trigger_board, max_skew_s, frames_averaged)
    except StationError as e:
        partial = getattr(e, "frames", {})
        if partial:
            e.saved_to = save_capture(partial, out_dir, failures=getattr(e, "failures", {}),
                                      truth=truth, extra=extra)
            log.warning("cycle failed; %d frame(s) kept in %s", len(partial), e.saved_to)
        raise
    return frames, save_capture(frames, out_dir, truth=truth, extra=extra)


def capture_station_cycle(cameras: dict[str, Camera], config, *, trigger_board=None, context: dict | None = None,
                          truth: dict | None = None, extra: dict | None = None) -> tuple[dict[str, Frame], Path | None]:
    """The station's cycle: capture with ``capture.timeout_s`` (or the simulated cameras' own
    deadline from ``context``) and, if ``capture.keep_captures``, save under
    ``<data_dir>/captures/<cycle id>`` (a failed cycle's partial set too). (frames, path or None)."""
    timeout = max(config.capture.timeout_s, (context or {}).get("capture_timeout_s", 0.0))
    n = config.capture.frames_averaged
    if not config.capture.keep_captures:
        return capture_averaged(cameras, timeout, trigger_board, frames=n), None
    cycle_id = new_cycle_id()
    return capture_and_save(cameras, timeout, config.data_path("captures", cycle_id), trigger_board=trigger_board,
                            truth=truth, extra={"station": config.name, **(extra or {})}, frames_averaged=n)
