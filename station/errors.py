"""Station errors: one root, one subclass per area, each with a stable numeric code.

The code is what the PLC sees in its fault register and what the technician sees beside a
sentence. Codes are grouped by area (hundreds); never renumber one, only add.
The drivers (2xx, ``drivers/errors.py``) and the calibration (3xx, ``calibration/errors.py``)
own their errors, since they import nothing of the station; :data:`CODED_ERRORS` names the
three roots for the places that report any of them, :func:`user_message` formats any of them.
The full table is printed by ``station errors`` and documented in docs/plc.md.
"""

from __future__ import annotations

from calibration import errors as calibration_errors
from drivers import errors as driver_errors


class StationError(Exception):
    """Root of every error the station reports to a user. ``str(e)`` is the sentence."""

    code = 1
    area = "station"

    def __init__(self, message: str, *, code: int | None = None, hint: str | None = None):
        super().__init__(message)
        if code is not None:
            self.code = code
        self.hint = hint


# Every error with a code, a sentence and a hint: the station's, the drivers', the calibration's.
CODED_ERRORS = (StationError, driver_errors.DriverError, calibration_errors.CalibrationError)
CodedError = StationError | driver_errors.DriverError | calibration_errors.CalibrationError


def user_message(error: CodedError) -> str:
    """The error as the terminal shows it: code, area, sentence, and what to do if known."""
    text = f"error {error.code} ({error.area}): {error}"
    if error.hint:
        text += f"\n  what to do: {error.hint}"
    return text


def sentence_without(subject: str, error: BaseException) -> str:
    """The error's sentence without its leading ``"<subject>: "`` (a camera's or an image's
    messages name it first), to quote after the subject is already named."""
    text = str(error)
    return text[len(subject) + 2:] if subject and text.startswith(subject + ": ") else text


class IllegalCommand(StationError):
    """A command the sequencer's current state does not accept (code 2, station area)."""

    code = 2


class ConfigError(StationError):
    code = 100
    area = "config"


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


class WheelUncertain(MeasurementError):
    """A wheel's toe or camber is less certain than ``measurement.uncertainty_limit_deg``: the
    cycle reports no angle; the message names the wheel and why, the hint what to do."""

    code = 404


class ProcedureError(MeasurementError):
    """A procedure of several captures (rolling the car, steering) cannot give its result.

    The message says what happened, the hint what to do."""

    code = 410


class RollTooShort(ProcedureError):
    """The car was rolled too little between the captures to find the wheels' spin axes."""

    code = 411


class WheelSlipped(ProcedureError):
    """A wheel turned by another amount than the car's travel over its rolling radius allows."""

    code = 412


class CarMovedSideways(ProcedureError):
    """The car moved across the runways, or turned, while it was rolled."""

    code = 413


class RimPatternLost(ProcedureError):
    """A rim's face could not be followed from one capture to the next (a plain or dirty face)."""

    code = 414


class RollNotConfirmed(ProcedureError):
    """The PLC did not confirm the car rolled into position within plc.roll_timeout_s (or the station stopped)."""

    code = 415


class SweepTooSmall(ProcedureError):
    """The front wheels were steered too little either way to find their steering axes."""

    code = 420


class SweepUneven(ProcedureError):
    """The front wheels were steered much farther one way than the other."""

    code = 421


class WheelRolledWhileSteered(ProcedureError):
    """A front wheel rolled (or slipped) while it was steered: its poses are no turn about one axis."""

    code = 422


class WheelLeftView(ProcedureError):
    """A wheel steered so far that a camera lost its rim."""

    code = 423


class SteerNotReached(ProcedureError):
    """The front wheels did not stand at a steer target in time."""

    code = 424


class RollNotReached(ProcedureError):
    """The car did not stand at a roll target in time (runout compensation at the station)."""

    code = 425


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


class PlcNoRollPending(PlcError):
    """In position (command 6) arrived while the station was not waiting for the car to be rolled."""
    code = 508


class StorageError(StationError):
    code = 600
    area = "storage"


class OdometryError(StationError):
    code = 700
    area = "odometry"


def all_error_classes() -> list[type[Exception]]:
    """Every error class of the three roots, sorted by code (for documentation and the PLC
    fault table)."""
    seen: list[type[Exception]] = []
    stack = list(CODED_ERRORS)
    while stack:
        cls = stack.pop()
        seen.append(cls)
        stack.extend(cls.__subclasses__())
    return sorted(seen, key=lambda c: c.code)
