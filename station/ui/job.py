"""The job on the lift: its id (VIN or the shop's number) and the vehicle's specification.

One car stands on the lift at a time, so the screen has one current job, kept in memory (what
each step measured is in the history under the job id). Bad input is refused with a sentence:
an empty id, an id with control characters (station/records/printable.py), a vehicle that is
not in the vehicles file (with the close names).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from station.config import StationConfig
from station.errors import ConfigError
from station.records.printable import escaped, unprintable
from station.records.vehicle_specs import VehicleSpec, get_spec, load_vehicle_specs
from station.ui.refused import Refused

MAX_JOB_ID = 64


@dataclass(frozen=True)
class Job:
    job_id: str
    vehicle: str | None   # the key in the vehicles file


def check_job_id(text) -> str:
    if not isinstance(text, str) or not text.strip():
        raise Refused(400, "the job id / VIN is empty", "type the VIN or the shop's job number")
    text = text.strip()
    if len(text) > MAX_JOB_ID:
        raise Refused(400, f"the job id is {len(text)} characters long; at most {MAX_JOB_ID}",
                      "type the VIN or the shop's job number")
    bad = unprintable(text)
    if bad:
        raise Refused(400, f"the job id holds {' '.join(escaped(c) for c in bad)}: control characters would forge "
                           "or hide lines in the history and the report", "type the job id without them")
    return text


class Jobs:
    """The current job and the vehicles file (read again when it changes on disk)."""

    def __init__(self, config: StationConfig):
        self.config = config
        self.current: Job | None = None
        self._lock = threading.Lock()
        self._specs: tuple[float, dict] | None = None

    def specs(self) -> dict[str, VehicleSpec]:
        """{key: VehicleSpec} of the vehicles file; ConfigError if it is broken."""
        path = self.config.vehicle_specs_path
        try:
            mtime = path.stat().st_mtime
        except OSError as e:
            raise ConfigError(f"{path}: cannot read the vehicles file: {e.strerror or e}",
                              hint="check the vehicle_specs setting of the station configuration") from e
        if self._specs is None or self._specs[0] != mtime:
            self._specs = (mtime, load_vehicle_specs(path))
        return self._specs[1]

    def search(self, query: str = "") -> list[dict]:
        """The vehicles whose key or name holds every word of ``query`` (case-insensitive)."""
        words = query.lower().split()
        return [{"key": k, "name": s.name} for k, s in sorted(self.specs().items(), key=lambda kv: kv[1].name)
                if all(w in f"{k} {s.name}".lower() for w in words)]

    def spec(self, key: str | None) -> VehicleSpec | None:
        if key is None:
            return None
        try:
            return get_spec(self.specs(), key, self.config.vehicle_specs_path)
        except ConfigError as e:
            raise Refused(400, str(e).replace(str(self.config.vehicle_specs_path) + ": ", ""), e.hint) from e

    def set(self, job_id, vehicle) -> Job:
        job_id = check_job_id(job_id)
        if vehicle in (None, ""):
            vehicle = None
        elif not isinstance(vehicle, str):
            raise Refused(400, "the vehicle must be a name from the list", None)
        self.spec(vehicle)  # an unknown vehicle is refused here
        with self._lock:
            self.current = Job(job_id, vehicle)
        return self.current
