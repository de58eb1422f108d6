"""Station errors: one root, one subclass per area, each with a stable numeric code.

The code is what the PLC sees in its fault register and what the technician sees beside a
sentence. Codes are grouped by area (hundreds); never renumber one, only add.
The full table is printed by ``station errors`` and documented in docs/plc.md.
"""

from __future__ import annotations


class StationError(Exception):
    """Root of every error the station reports to a user. ``str(e)`` is the sentence."""

    code = 1
    area = "station"

    def __init__(self, message: str, *, code: int | None = None, hint: str | None = None):
        super().__init__(message)
        if code is not None:
            self.code = code
        self.hint = hint

    def user_message(self) -> str:
        text = f"error {self.code} ({self.area}): {self}"
        if self.hint:
            text += f"\n  what to do: {self.hint}"
        return text


class ConfigError(StationError):
    code = 100
    area = "config"


class DriverError(StationError):
    code = 200
    area = "camera"


class CameraTimeout(DriverError):
    code = 201


class CameraMissing(DriverError):
    code = 202


class FrameError(DriverError):
    code = 203


class CalibrationError(StationError):
    code = 300
    area = "calibration"


class CalibrationMismatch(CalibrationError):
    code = 301


class CalibrationRejected(CalibrationError):
    code = 302


class MeasurementError(StationError):
    code = 400
    area = "measurement"


class RimNotFound(MeasurementError):
    code = 401


class ImageError(MeasurementError):
    code = 402


class PlcError(StationError):
    code = 500
    area = "plc"


class StorageError(StationError):
    code = 600
    area = "storage"


class OdometryError(StationError):
    code = 700
    area = "odometry"


def all_error_classes() -> list[type[StationError]]:
    """Every error class, sorted by code (for documentation and the PLC fault table)."""
    seen: list[type[StationError]] = []
    stack = [StationError]
    while stack:
        cls = stack.pop()
        seen.append(cls)
        stack.extend(cls.__subclasses__())
    return sorted(seen, key=lambda c: c.code)
