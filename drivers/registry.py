"""Pick a camera driver from its URI scheme; drivers are imported only when used.

Adding a driver is one module and one line here. A missing optional system library (Aravis'
typelib, PyGObject, ...) is reported only when a camera with that scheme is opened.
"""

from __future__ import annotations

import importlib
from urllib.parse import urlparse

from drivers.base import Camera, CameraSettings
from station.errors import DriverError

DRIVERS = {
    "sim": "simulators.sim_camera:SimCamera",
    "replay": "drivers.replay:ReplayCamera",
    "aravis": "drivers.aravis:AravisCamera",
    "v4l2": "drivers.v4l2:V4L2Camera",
}


def driver_class(uri: str) -> type[Camera]:
    scheme = urlparse(uri).scheme
    if scheme not in DRIVERS:
        raise DriverError(f"unknown camera URI scheme in {uri!r}; expected one of "
                          + ", ".join(f"{s}://" for s in DRIVERS))
    module_name, cls_name = DRIVERS[scheme].split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as e:
        raise DriverError(f"the {scheme}:// driver is not available: {e}") from e
    return getattr(module, cls_name)


def create_camera(camera_id: str, uri: str, settings: CameraSettings | None = None,
                  context: dict | None = None) -> Camera:
    """Instantiate (not open) the driver for ``uri``."""
    return driver_class(uri)(camera_id, uri, settings, context)
