"""The calibration's errors: one root, a stable numeric code per kind (the 3xx area).

A sentence (``str(e)``), a ``code`` the PLC sees in its fault register, an ``area`` and an
optional ``hint`` saying what to do. The calibration imports nothing of the station, so its
errors live here; the station reports them beside its own and the drivers', and
``station errors`` lists every code.
"""

from __future__ import annotations


# The root: no docstring, so the fault-code table of docs/plc.md keeps an empty meaning here.
class CalibrationError(Exception):
    code = 300
    area = "calibration"

    def __init__(self, message: str, *, hint: str | None = None):
        super().__init__(message)
        self.hint = hint


class CalibrationMismatch(CalibrationError):
    code = 301


class CalibrationRejected(CalibrationError):
    code = 302
