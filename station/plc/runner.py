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
  and the benchmark. Every ``fail_every``-th job fails on purpose (code 401; 412 for a cycle with
  runout compensation, after its rolls) so the PLC's fault branch gets exercised too.

A cycle with runout compensation (``measure_compensated``, PLC command 5) carries the PLC's
:class:`~station.plc.roll_operator.RollGate` in ``CycleRequest.roll``; both runners roll the car
through it (station/plc/roll_operator.py), the dry run without cameras. A steering sweep
(``measure_caster``, command 7) carries a :class:`~station.plc.steer_operator.SteerGate` in
``CycleRequest.steer``: the real runner's guide (``GuidedSteering``, the front wheels followed live)
and the dry run's synthetic wheels (station/plc/dry_steering.py) report through it.
"""

from __future__ import annotations

import math
import random
import re
import zlib
from dataclasses import dataclass
from typing import Callable

from calibration.errors import CalibrationError
from calibration.station_frame import AXLES, WHEELS
from station.errors import PlcError, RimNotFound, WheelRolledWhileSteered, WheelSlipped
from station.plc.dry_steering import SyntheticSteering, synthetic_steering
from station.plc.roll_operator import PlcRollOperator, RollGate, roll_plan
from station.plc.steer_operator import MakeGuide, PlcSteerOperator, SteerGate, steer_plan
from station.result import ANGLE_NAMES, AxleResult, Measurement, WheelResult

COMMANDS = ("measure", "calibration_check", "measure_compensated", "measure_caster")
LIP_DIAMETER_M = 0.432  # a 17-inch rim's lip: the dry run's runout in mm


@dataclass(frozen=True)
class CycleRequest:
    command: str  # "measure" | "calibration_check" | "measure_compensated" | "measure_caster" (COMMANDS)
    job_id: str | None  # None when the PLC left the job id empty
    vehicle_spec: str | None
    cycle: int  # the station's running cycle number (1, 2, ...), also the simulation seed
    roll: RollGate | None = None  # measure_compensated: who rolls the car (the PLC device)
    steer: SteerGate | None = None  # measure_caster: who shows each steer to the PLC (the PLC device)

    def roll_operator(self, simulation=None, steps: int | None = None) -> PlcRollOperator:
        """The operator that rolls the car ``steps`` times (default: the procedure's rolls) for
        this compensated cycle; PlcError without a gate (a compensated cycle started by something
        that cannot roll the car)."""
        if self.roll is None:
            raise PlcError(f"cycle {self.cycle}: runout compensation needs the PLC to roll the car, and "
                           "this request has no roll gate")
        return PlcRollOperator(self.roll, len(roll_plan()) if steps is None else steps, simulation)

    def steer_operator(self, make_guide: MakeGuide, steps: int | None = None) -> PlcSteerOperator:
        """The operator whose ``steps`` steers (default: the sweep's) the PLC sees, steered and
        watched by ``make_guide(on_reading)``; PlcError without a gate."""
        if self.steer is None:
            raise PlcError(f"cycle {self.cycle}: a steering sweep shows its steers to the PLC, and this request "
                           "has no steer gate")
        return PlcSteerOperator(self.steer, len(steer_plan()) if steps is None else steps, make_guide)


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
    import logging

    from station.cycle import Station
    from station.procedures.steer_guide import GuidedSteering

    holder: dict = {}
    guide_log = logging.getLogger("station.plc.steer")

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
            if request.command == "measure_compensated":  # the PLC rolls the (simulated) car
                return assembled.measure(job_id=request.job_id, vehicle_spec=request.vehicle_spec,
                                         compensate=request.roll_operator(assembled.context.simulation))
            if request.command == "measure_caster":  # the technician (simulated: the simulation) steers
                operator = request.steer_operator(lambda on_reading: GuidedSteering(
                    assembled, mover=assembled.context.simulation, show=guide_log.debug,
                    timeout_s=request.steer.timeout_s, on_reading=on_reading))
                return assembled.caster(operator, job_id=request.job_id, vehicle_spec=request.vehicle_spec)
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
    """A deterministic result for ``request``: the angles depend only on the job id (and the
    command), so a PLC simulator can check that it got the result of *its* job. Raises
    RimNotFound for every ``fail_every``-th job number (the cycle number when there is no job id;
    0: never); WheelSlipped instead for a cycle with runout compensation, whose result also holds
    each wheel's runout; WheelRolledWhileSteered for a steering sweep, whose result also holds
    the steering geometry (station/plc/dry_steering.py)."""
    n = job_number(request.job_id) if request.job_id else request.cycle
    compensate = request.command == "measure_compensated"
    if fail_every and n % fail_every == 0:
        if compensate:
            raise WheelSlipped(f"RL: its turn does not match the car's travel (dry run, job {n})")
        if request.command == "measure_caster":
            raise WheelRolledWhileSteered(f"FL: it rolled while steered (dry run, job {n})")
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
    if compensate:
        result.runout_compensated = True
        for w in WHEELS:
            runout = round(rng.uniform(0.0, 0.3), 4)
            wheels[w].runout_deg, wheels[w].runout_phase_deg = runout, round(rng.uniform(0.0, 360.0), 2)
            wheels[w].runout_mm = round(LIP_DIAMETER_M * 1000 * math.tan(math.radians(runout)), 3)
    if request.command == "measure_caster":
        result.steering = synthetic_steering(rng, camber, steer_plan())
    if request.vehicle_spec:
        limits = {"toe": 0.3, "camber": 1.2, "total_toe": 0.5, "thrust": 0.25}
        verdict = {name: abs(result.angle(name)) <= limits[name.split(".")[-1]] for name in ANGLE_NAMES}
        verdict["overall"] = all(verdict.values())
        result.verdicts = verdict
    return result


def dry_run_runner(fail_every: int = 10, delay_s: float = 0.0, reading_s: float = 0.1) -> CycleRunner:
    """A runner returning :func:`synthetic_result`, after ``delay_s`` seconds (a stand-in for the
    measurement time). A cycle with runout compensation first asks the PLC for every roll of the
    real procedure (station/procedures/runout.py), ``delay_s`` apart, as the station would between
    its captures, so a PLC programmer can commission the roll steps without cameras. A steering
    sweep first walks the sweep's steer targets (station/procedures/steering.py) with synthetic
    front wheels that turn to each target, one live reading every ``reading_s`` seconds, and stand
    still there (station/plc/dry_steering.py)."""
    import time

    plan = roll_plan()  # imported now, not in the first compensated cycle's time
    targets = steer_plan()

    def run(request: CycleRequest) -> Measurement:
        if request.command == "measure_compensated":
            operator = request.roll_operator(steps=len(plan))
            for distance_m in plan:
                if delay_s:
                    time.sleep(delay_s)  # a capture
                operator.roll_car(distance_m)
        if request.command == "measure_caster":
            timeout_s = request.steer.timeout_s if request.steer is not None else 300.0
            operator = request.steer_operator(
                lambda on_reading: SyntheticSteering(on_reading, reading_s, timeout_s=timeout_s), steps=len(targets))
            for target in targets:
                operator.steer(target)
                time.sleep(delay_s or reading_s)  # the capture where the wheels stand (the reading stays)
        if delay_s:
            time.sleep(delay_s)
        return synthetic_result(request, fail_every)

    return run


# --- keeping the dry run's results ----------------------------------------------------------------
def storing_runner(runner: CycleRunner, open_history: Callable) -> CycleRunner:
    """``runner`` whose valid results are also kept in the history ``open_history()`` opens, each
    under a new cycle id and the time it finished (``station serve --dry-run --store``: commissioning
    a shared history, and the shop benchmark). The result reaches the PLC only after the history
    (or, with the server away, the station's outbox) has it; a history that refuses it is a
    warning on the result, as in a measuring cycle."""
    import datetime as dt

    from station.capture.saving import new_cycle_id
    from station.errors import StorageError
    from station.result import WarningFlag

    def run(request: CycleRequest) -> Measurement:
        result = runner(request)
        if isinstance(result, Measurement) and result.valid:
            result.cycle_id = new_cycle_id()
            result.time_utc = dt.datetime.now(dt.timezone.utc).isoformat(timespec="milliseconds")
            try:
                with open_history() as history:
                    history.store(result)
                    if history.last_queued:
                        result.warn(f"the history server did not take this cycle now ({history.where}); it waits "
                                    "in the station's outbox and is sent once it answers")
            except StorageError as e:
                result.warn(f"{e}; the measurement is kept, this cycle is not in the history", WarningFlag("not_kept"))
        return result

    return run
