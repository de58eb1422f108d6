"""The drivers' errors: one root, a stable numeric code per kind (the 2xx "camera" area).

A sentence (``str(e)``), a ``code`` the PLC sees in its fault register, an ``area`` and an
optional ``hint`` saying what to do. The drivers import nothing of the station, so their
errors live here; the station reports them beside its own and the calibration's, and
``station errors`` lists every code.
"""

from __future__ import annotations


# The root: no docstring, so the fault-code table of docs/plc.md keeps an empty meaning here.
class DriverError(Exception):
    code = 200
    area = "camera"

    def __init__(self, message: str, *, hint: str | None = None):
        super().__init__(message)
        self.hint = hint


class CameraTimeout(DriverError):
    code = 201


class CameraMissing(DriverError):
    code = 202


class FrameError(DriverError):
    code = 203


class TriggerBoardError(DriverError):
    """A trigger-board fault (code 204: the camera area, next free code)."""

    code = 204
