"""How a PLC command runs a cycle: an injected callable, chosen once where the station is built.

``CycleRunner = Callable[[CycleRequest], Measurement]`` returns a result (station/result.py) or
raises one of :data:`station.errors.CODED_ERRORS` (its ``code`` becomes the PLC's fault code, its
sentence the fault reason). The server runs it in a worker thread, so
the heartbeat and Modbus serving go on during a cycle.

Two runners:

* :func:`measurement_runner` - the real station (``station.cycle.Station``), assembled
  only when built, with a clear error when the pipeline is not installed;
* :func:`dry_run_runner` - synthetic, deterministic results computed from the job id, for
  commissioning the PLC program without cameras (``station serve --dry-run``), for the tests
  and the benchmark. Every ``fail_every``-th job fails on purpose (code 401) so the PLC's fault
  branch gets exercised too.
"""

from __future__ import annotations

import random
import re
import zlib
from dataclasses import dataclass
from typing import Callable

from calibration.errors import CalibrationError
from calibration.station_frame import AXLES, WHEELS
from station.errors import PlcError, RimNotFound
from station.result import ANGLE_NAMES, AxleResult, Measurement, WheelResult



@dataclass(frozen=True)
class CycleRequest:
    command: str  # "measure" | "calibration_check"
    job_id: str | None  # None when the PLC left the job id empty
    vehicle_spec: str | None
    cycle: int  # the station's running cycle number (1, 2, ...), also the simulation seed


CycleRunner = Callable[[CycleRequest], Measurement]


# --- the real station ---------------------------------------------------------------------------
def measurement_runner(config, seed: int | None = None) -> CycleRunner:
    """The runner for ``station serve``: the measurement pipeline on the configured station.

    The station (cameras, calibration) is assembled once, at the first command, and kept; a
    failure to assemble it (no calibration, a missing camera) faults that cycle with its code,
    and the next command tries again. On a simulated station (sim://) each measuring cycle
    measures the random vehicle of its cycle number; ``seed`` keeps that one vehicle on the lift
    for every cycle instead.
    """
    from station.cycle import Station

    holder: dict = {}

    def station() -> Station:
        if "station" not in holder:
            holder["station"] = Station(config, seed=seed, progress=lambda msg: None)
        return holder["station"]

    def run(request: CycleRequest) -> Measurement:
        if request.command == "calibration_check":
            return station().calibration_check()
        try:
            assembled = station()
            if seed is None and assembled.context.simulation is not None:
                assembled.context.simulation.place_vehicle(request.cycle)
            return assembled.measure(job_id=request.job_id, vehicle_spec=request.vehicle_spec)
        except CalibrationError:
            holder.pop("station", None)
            raise

    run.close = lambda: holder.pop("station").close() if "station" in holder else None  # type: ignore[attr-defined]
    return run


# --- synthetic results (dry run) ----------------------------------------------------------------
def job_number(job_id: str | None) -> int:
    """The trailing decimal number of a job id ("JOB-000123" -> 123), else a CRC of it."""
    m = re.search(r"(\d+)$", job_id or "")
    return int(m.group(1)) if m else zlib.crc32((job_id or "").encode())


def synthetic_result(request: CycleRequest, fail_every: int = 10) -> Measurement:
    """A deterministic result for ``request``: the angles depend only on the job id, so a PLC
    simulator can check that it got the result of *its* job. Raises RimNotFound for every
    ``fail_every``-th job number (the cycle number when there is no job id; 0: never)."""
    n = job_number(request.job_id) if request.job_id else request.cycle
    if fail_every and n % fail_every == 0:
        raise RimNotFound(f"RR cam7: no closed rim contour (dry run, job {n})")
    rng = random.Random(zlib.crc32(f"{request.job_id}|{request.command}".encode()))
    toe = {w: round(rng.uniform(-0.3, 0.3), 4) for w in WHEELS}
    camber = {w: round(rng.uniform(-1.5, 0.5), 4) for w in WHEELS}
    thrust = (toe["RL"] - toe["RR"]) / 2
    wheels = {w: WheelResult(toe[w], camber[w]) for w in WHEELS}
    wheels["FL"].toe_thrust_deg = toe["FL"] - thrust
    wheels["FR"].toe_thrust_deg = toe["FR"] + thrust
    result = Measurement(station="dry run", valid=True, cycle_id=f"dry-run-{request.cycle:06d}",
                         job_id=request.job_id, vehicle_spec=request.vehicle_spec,
                         warnings=["dry run: synthetic result, no cameras"], wheels=wheels,
                         axles={axle: AxleResult(toe[left] + toe[right]) for axle, (left, right) in AXLES.items()},
                         thrust_deg=thrust)
    if request.vehicle_spec:
        limits = {"toe": 0.3, "camber": 1.2, "total_toe": 0.5, "thrust": 0.25}
        verdict = {name: abs(result.angle(name)) <= limits[name.split(".")[-1]] for name in ANGLE_NAMES}
        verdict["overall"] = all(verdict.values())
        result.verdicts = verdict
    return result


def dry_run_runner(fail_every: int = 10, delay_s: float = 0.0) -> CycleRunner:
    """A runner returning :func:`synthetic_result`, after ``delay_s`` seconds (a stand-in for the
    measurement time)."""
    import time

    def run(request: CycleRequest) -> Measurement:
        if delay_s:
            time.sleep(delay_s)
        return synthetic_result(request, fail_every)

    return run
