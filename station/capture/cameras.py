"""Opening and closing the station's cameras and its trigger board.

    cameras = open_station_cameras(config, context)          # all open, or ONE error listing all

Cameras open concurrently; any that fail are named together in one error (the ones that did
open are closed again). Two cameras naming one device are refused before anything opens.
"""

from __future__ import annotations

import time

from drivers.base import Camera, CameraSettings
from drivers.context import DriverContext
from drivers.errors import DriverError
from drivers.registry import create_camera, uri_address
from station.capture.sync import failure_error, run_parallel
from station.errors import CODED_ERRORS

OPEN_TIMEOUT_S = 15.0  # a GigE camera that does not answer takes ~2.5 s to give up


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


def open_cameras(specs: dict[str, tuple[str, CameraSettings]], context: DriverContext | None = None,
                 timeout_s: float = OPEN_TIMEOUT_S) -> tuple[dict[str, Camera], dict[str, str]]:
    """Open cameras concurrently: (the open ones, {camera id: why it failed}). Never raises."""
    check_unique_addresses({cid: uri for cid, (uri, _) in specs.items()})
    cams: dict[str, Camera] = {}
    failures: dict[str, BaseException] = {}
    for cam_id, (uri, settings) in specs.items():
        try:
            cams[cam_id] = create_camera(cam_id, uri, settings, context)
        except CODED_ERRORS as e:
            failures[cam_id] = e
    _, open_fail = run_parallel({cid: c.open for cid, c in cams.items()},
                                 time.monotonic() + timeout_s, "open")
    failures.update(open_fail)
    for cid in open_fail:
        cams.pop(cid).close()
    return cams, failures


def open_station_cameras(config, context: DriverContext | None = None,
                         ids: list[str] | None = None) -> dict[str, Camera]:
    """Open the configured cameras (all, or ``ids``); ONE error listing every camera that failed.

    ``context`` reaches the drivers (drivers/context.py: sim:// cameras find their simulated
    station there).
    """
    ids = list(ids or config.cameras)
    specs = {cid: (config.cameras[cid].uri, settings_for(config.cameras[cid])) for cid in ids}
    cams, failures = open_cameras(specs, context)
    if failures:
        for c in cams.values():
            c.close()
        raise failure_error("opening the cameras", failures)
    return {cid: cams[cid] for cid in ids}


def open_trigger_board(config, context: DriverContext | None = None):
    """The configured trigger board, open (drivers.trigger_board.TriggerBoard), or None when the
    cameras trigger themselves (``trigger_board.port: null``). ``trigger_board.port: sim`` uses
    the simulated board that ``build_context`` started (``context.trigger_board_port``)."""
    started = context.trigger_board_port if context is not None else None
    port = started or config.trigger_board.port
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
