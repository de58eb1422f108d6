"""The Station page's request: the cameras, the calibration's age and health, the PLC."""

from __future__ import annotations

import time
from datetime import datetime, timezone

from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Route

from station.errors import CODED_ERRORS
from station.ui.plc_probe import plc_view


def _calibration(config) -> dict:
    from calibration.calib_file import load_calibration

    try:
        calib = load_calibration(config.calibration_file, config)
    except CODED_ERRORS as e:
        return {"ok": False, "message": str(e), "hint": e.hint}
    try:
        created = datetime.fromisoformat(calib.created_utc)
        age_days = (datetime.now(timezone.utc) - created).total_seconds() / 86400
    except (TypeError, ValueError):
        age_days = None
    return {"ok": True, "id": calib.calibration_id, "created_utc": calib.created_utc,
            "age_days": None if age_days is None else round(age_days, 1), "file": str(config.calibration_file)}


def _drift(screen) -> dict:
    """The drift warnings of the newest stored cycle (a camera moved since its calibration)."""
    from station.records.history import History

    try:
        with History(screen.config.data_path("history.sqlite"), read_only=True) as h:
            rows = h.query(limit=1)
    except CODED_ERRORS as e:
        return {"cycle_id": None, "warnings": [], "message": str(e)}
    if not rows:
        return {"cycle_id": None, "warnings": [], "message": "no cycle measured yet"}
    result = rows[-1]["result"] or {}
    flags = result.get("warning_flags") or []
    drift_wheels = {f.get("wheel") for f in flags if f.get("kind") == "drift"}
    texts = [w for w in result.get("warnings", []) if "may have moved since calibration" in w]
    return {"cycle_id": rows[-1]["cycle_id"], "time_utc": rows[-1]["time_utc"], "drift_wheels": sorted(drift_wheels),
            "warnings": texts}


async def station(request: Request):
    import anyio

    screen = request.app.state.screen
    config = screen.config
    cameras = [{"id": cid, "wheel": c.wheel, "role": c.role, "uri": c.uri, "resolution": [c.width, c.height]}
               for cid, c in config.cameras.items()]
    calib = await anyio.to_thread.run_sync(_calibration, config)
    drift = await anyio.to_thread.run_sync(_drift, screen)
    plc = await anyio.to_thread.run_sync(plc_view, config.plc)  # `station serve` runs on its own: looked at from outside
    running = screen.runner.busy()
    return JSONResponse({
        "name": config.name, "config": str(config.path), "data_dir": str(config.data_path()),
        "cameras": cameras, "calibration": calib, "drift": drift,
        "plc": {**plc, "configured": f"{config.plc.transport} {config.plc.host}:{config.plc.port}"},
        "step": running.view(10 ** 9) if running else None,
        "live": screen.feed.status[1], "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "simulated_seed": screen.hardware.seed if screen.simulated else None})


routes = [Route("/api/station", station)]
