"""Pick a camera driver from its URI scheme; drivers are imported only when used.

Adding a driver is one module and one line here. A missing optional system library (Aravis'
typelib, PyGObject, ...) is reported only when a camera with that scheme is opened.
"""

from __future__ import annotations

import importlib
import os
from urllib.parse import urlparse

from drivers.base import Camera, CameraSettings
from drivers.context import DriverContext, Simulation
from drivers.errors import DriverError

DRIVERS = {
    "sim": "simulators.sim_camera:SimCamera",
    "replay": "drivers.replay:ReplayCamera",
    "aravis": "drivers.aravis:AravisCamera",
    "v4l2": "drivers.v4l2:V4L2Camera",
}


def driver_class(uri: str) -> type[Camera]:
    scheme = urlparse(uri).scheme
    if scheme not in DRIVERS or "://" not in uri:
        raise DriverError(f"unknown camera URI scheme in {uri!r}; expected one of "
                          + ", ".join(f"{s}://" for s in DRIVERS))
    module_name, cls_name = DRIVERS[scheme].split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as e:
        raise DriverError(f"the {scheme}:// driver is not available: {e}") from e
    return getattr(module, cls_name)


def create_camera(camera_id: str, uri: str, settings: CameraSettings | None = None,
                  context: DriverContext | None = None) -> Camera:
    """Instantiate (not open) the driver for ``uri``."""
    return driver_class(uri)(camera_id, uri, settings, context)


def uri_address(uri: str, camera_id: str | None = None) -> str:
    """The physical thing a URI names, normalised, so two spellings of one camera compare equal.

    ``aravis://127.0.0.2`` and ``aravis://127.0.0.2/`` -> ``aravis://127.0.0.2``;
    ``v4l2:///dev/video0`` -> ``v4l2:///dev/video0`` (symlinks resolved);
    ``replay://DIR?camera=cam3`` keeps the camera (by default the camera's own ``camera_id``,
    since eight replay cameras share one directory); query options that do not change the device
    (timeouts, ...) are dropped.
    """
    scheme, _, rest = uri.partition("://")
    rest, _, query = rest.partition("?")
    rest = rest.rstrip("/") or rest
    if scheme == "v4l2":
        rest = os.path.realpath(rest)
    elif scheme == "aravis":
        rest = rest.lower()
    elif scheme == "replay":
        cam = [kv for kv in query.split("&") if kv.startswith("camera=")]
        cam = cam[0].split("=", 1)[1] if cam else camera_id
        rest = os.path.realpath(rest) + (f"?camera={cam}" if cam else "")
    return f"{scheme}://{rest}"


def build_context(uris, config, **options) -> DriverContext:
    """What the drivers in use bring to the assembled station (drivers/context.py), built once.

    A driver module may define ``build_context(config, **options) -> DriverContext`` (the sim://
    driver builds the simulated station there); it is called only if a camera uses that scheme,
    so the station never imports a simulator unless its configuration names one.
    """
    context = DriverContext()
    for scheme in sorted({urlparse(u).scheme for u in uris}):
        module = importlib.import_module(driver_class(f"{scheme}://x").__module__)
        provider = getattr(module, "build_context", None)
        if provider is not None:
            context.add(provider(config, **options))
    return context


def simulation(config, vehicle_seed: int | None = None) -> Simulation:
    """The simulated station of ``config`` (the sim:// driver's), whatever its cameras are:
    for commands that render it (``station simulate``)."""
    return build_context(["sim://"], config, seed=vehicle_seed).simulation
