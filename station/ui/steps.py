"""The steps of an alignment job, in order, as the Procedure page offers them.

Each runs the station's own procedure, as its command does (``station measure``,
``station measure --compensate``, ``station caster``); the technician's prompts and the guides'
live lines go to the page (station/ui/runner.py). On the simulated station its technician rolls
the car and steers when asked (``drivers.context.Simulation``), as on the command line.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from station.ui.views import measurement_view


@dataclass(frozen=True)
class Step:
    key: str
    title: str
    instruction: str
    command: str               # the same from the command line
    run: Callable              # (station, job, show, spec) -> Measurement


def _calibration_check(station, job, show, spec):
    return station.calibration_check()


def _runout(station, job, show, spec):
    from station.procedures.roll_guide import GuidedRolling

    guide = GuidedRolling(station, mover=station.context.simulation, show=show)
    return station.measure(job_id=job.job_id, vehicle_spec=job.vehicle, compensate=guide)


def _steering(station, job, show, spec):
    from station.procedures.steer_guide import GuidedSteering

    guide = GuidedSteering(station, mover=station.context.simulation, show=show)
    return station.caster(guide, job_id=job.job_id, vehicle_spec=job.vehicle)


def _measurement(station, job, show, spec):
    return station.measure(job_id=job.job_id, vehicle_spec=job.vehicle)


STEPS = (
    Step("calibration-check", "Calibration check",
         "Nothing on the lift needs to move. The station measures once and checks that every camera pair still "
         "fits its calibration (a camera knocked out of place shows as drift). Kept as job 'calibration-check'.",
         "station measure --job calibration-check", _calibration_check),
    Step("runout", "Runout compensation",
         "Release the brake, wheels straight. When asked, roll the car back about 15 cm, then forward in steps of "
         "7.5, 15 and 7.5 cm (15 cm past the start), then back to the start, slowly, following the bar; let it "
         "stand still at each position. The station finds each wheel's spin axis and keeps the runout with the job.",
         "station measure --compensate --job JOB", _runout),
    Step("steering", "Steering sweep (caster, SAI)",
         "Front wheels on the turn plates (pins out), brake held with the pedal depressor. When asked, steer left "
         "to 10 deg, right to 10 deg, then straight ahead, following the angle shown; hold still at each.",
         "station caster --job JOB", _steering),
    Step("measurement", "Measurement",
         "Car standing still, steering straight. The station measures toe and camber of all four wheels, "
         "checks them against the vehicle's specification and keeps the cycle with the job.",
         "station measure --job JOB", _measurement),
)
STEP_BY_KEY = {s.key: s for s in STEPS}


def step_work(step: Step, job, spec) -> Callable:
    """The runner's work for ``step`` on ``job`` (a copy taken when it starts: editing the job
    meanwhile does not change a running step)."""
    def work(station, show):
        result = step.run(station, job, show, spec)
        return result, measurement_view(result, spec if result.vehicle_spec else None)
    return work
