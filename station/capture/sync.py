"""Synchronised capture of one cycle from the station's cameras.

    frames = capture_cycle(cameras, config.capture.timeout_s, trigger_board)

A cycle: every camera is armed (concurrently), then one trigger - the trigger board fires
every hardware trigger input and the strobes at once, and software-triggered cameras get
their trigger from threads released together - then every camera's frame is collected
concurrently within ONE deadline. Timestamps are checked (no frame older than the trigger,
none after the deadline, no repeated frame, optional skew limit). A missing, late or broken
camera fails the cycle with one error naming every such camera; the frames that did arrive
ride on the error (``e.frames``) so ``capture_and_save`` (station/capture/saving.py) can keep
them: nothing is lost. A set in which every failure is a damaged frame (a corrupt buffer from
packet loss, a stale or repeated frame: the cameras answered) is taken again once, all cameras
together, before the cycle fails. With ``capture.frames_averaged`` N > 1 a cycle takes N such sets and
keeps each camera's mean (``capture_averaged``, station/capture/frame_average.py).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable

from drivers.base import Camera, Frame
from drivers.errors import CameraMissing, CameraTimeout, DriverError, FrameError
from station.capture.frame_average import averaged_frames
from station.errors import CODED_ERRORS, CodedError, sentence_without

log = logging.getLogger("station.capture")

STALE_TOLERANCE_NS = 5_000_000  # a frame stamped >5 ms before the trigger is a leftover


# --- errors that carry what is known ----------------------------------------------------------
def failure_error(what: str, failures: dict[str, BaseException], frames: dict | None = None) -> CodedError:
    """One error naming every failed camera; its class follows the kind of failure."""
    kinds = [type(e) for e in failures.values()]
    if len(set(kinds)) == 1 and issubclass(kinds[0], CODED_ERRORS):
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
    detail = "; ".join(f"{cid}: {sentence_without(cid, e)}" for cid, e in sorted(failures.items()))
    hints = sorted({e.hint for e in failures.values() if getattr(e, "hint", None)})
    err = cls(f"{what} failed for {len(failures)} camera(s) ({names}): {detail}",
              hint="; ".join(hints) or None)
    err.failures = {cid: sentence_without(cid, e) for cid, e in failures.items()}
    err.frames = dict(frames or {})
    return err


def run_parallel(items: dict[str, Callable[[], object]], deadline: float, what: str):
    """Run each callable in its own thread; (results, failures) by key, all within ``deadline``."""
    results: dict[str, object] = {}
    failures: dict[str, BaseException] = {}

    def work(key, fn):
        try:
            results[key] = fn()
        except BaseException as e:  # noqa: BLE001 - reported per camera below
            failures[key] = e if isinstance(e, CODED_ERRORS) else DriverError(f"{key}: {what}: {e}")

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



# --- one cycle -------------------------------------------------------------------------------
def capture_cycle(cameras: dict[str, Camera], timeout_s: float, trigger_board=None,
                  max_skew_s: float | None = None) -> dict[str, Frame]:
    """One synchronised set: {camera id: Frame}, or one error naming every failed camera.

    A set lost only to damaged frames (FrameError: the cameras answered) is taken again once,
    with its own deadline; a missing or silent camera fails at once.
    """
    try:
        return capture_set(cameras, timeout_s, trigger_board, max_skew_s)
    except FrameError as e:
        log.warning("capture: %s; taking the set again", e)
    return capture_set(cameras, timeout_s, trigger_board, max_skew_s)


def capture_set(cameras: dict[str, Camera], timeout_s: float, trigger_board=None,
                max_skew_s: float | None = None) -> dict[str, Frame]:
    """One synchronised set, one attempt: {camera id: Frame}, or one error naming every failed camera.

    Every wait shares one deadline, ``timeout_s`` from the call. With ``trigger_board`` (a
    drivers.trigger_board.TriggerBoard) the board fires once after every camera is armed;
    cameras in software mode are triggered by software at the same moment. ``max_skew_s``
    bounds the spread of the frames' timestamps (None: only the deadline bounds it).
    The error's ``frames`` holds the frames that did arrive, ``failures`` the reasons.
    """
    if not cameras:
        raise DriverError("capture: no cameras to capture from")
    deadline = time.monotonic() + timeout_s
    _, failures = run_parallel({cid: c.arm for cid, c in cameras.items()}, deadline, "arm")
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
        box["r"] = run_parallel(threads_fns, deadline, "grab")

    collector = threading.Thread(target=collect, daemon=True)
    collector.start()
    trigger_ns = time.monotonic_ns()
    board_failures: dict[str, BaseException] = {}
    if trigger_board is not None:
        try:
            board_report = trigger_board.fire()
        except CODED_ERRORS as e:
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
        raise failure_error("capture", failures, {c: f for c, f in frames.items() if c not in failures})
    return {cid: frames[cid] for cid in cameras}


def capture_averaged(cameras: dict[str, Camera], timeout_s: float, trigger_board=None,
                     max_skew_s: float | None = None, frames: int = 1) -> dict[str, Frame]:
    """``frames`` synchronised sets (capture_cycle, each with its own deadline), averaged per
    camera (station/capture/frame_average.py): {camera id: Frame}. One set when ``frames`` is 1 or a
    camera replays saved frames (``Camera.exposes`` False): a kept burst is already averaged."""
    if frames <= 1 or not all(c.exposes for c in cameras.values()):
        return capture_cycle(cameras, timeout_s, trigger_board, max_skew_s)
    return averaged_frames([capture_cycle(cameras, timeout_s, trigger_board, max_skew_s) for _ in range(frames)])
