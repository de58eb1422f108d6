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


class IllegalCommand(StationError):
    """A command the sequencer's current state does not accept (code 2, station area)."""

    code = 2


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


class TriggerBoardError(DriverError):
    """A trigger-board fault (code 204: the camera area, next free code)."""

    code = 204


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


class WorkerFailure(MeasurementError):
    """A measurement worker process died (killed, out of memory): the cycle fails, the workers restart."""

    code = 403


class PlcError(StationError):
    code = 500
    area = "plc"


class PlcBusy(PlcError):
    """A command arrived while a cycle is running; it is refused, not queued."""
    code = 501


class PlcNotAcknowledged(PlcError):
    """A trigger arrived before the previous cycle's result (or fault) was acknowledged."""
    code = 502


class PlcNothingToAcknowledge(PlcError):
    """Acknowledge or reset arrived with no finished cycle or fault to clear."""
    code = 503


class PlcUnknownCommand(PlcError):
    """The command register was written with a value that is not a command."""
    code = 504


class PlcCycleTimeout(PlcError):
    """The cycle did not finish within the cycle timeout."""
    code = 505


class PlcBadJobId(PlcError):
    """The job id or vehicle spec registers do not hold printable ASCII."""
    code = 506


class PlcInternal(PlcError):
    """The station's own cycle reported an event the table does not allow (a late cycle)."""
    code = 507


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
