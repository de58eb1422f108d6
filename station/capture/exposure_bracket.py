"""A camera whose lit lip is at the sensor's white, taken again at a shorter exposure.

Where the lip is at the white, its edge profile is cut off and the edge is read toward the
tyre (station/rim/white_edge.py): a low sun through the door, or a lamp, on one camera's side
of the wheel. The cycle then takes those cameras again at half the exposure, and at a quarter
where half is still at the white, and measures with the shorter frames (the other cameras'
frames stay). ``capture.exposure_steps`` sets the steps; an empty list turns it off.

    result, images, exposures = measure_bracketed(images, measure, recapture, steps)

``measure(images) -> Measurement``; ``recapture(camera ids, factor) -> {camera id: image}``
takes those cameras at ``factor`` times their configured exposure. The station's cycle
(station/cycle.py) and the accuracy benchmark (bench/accuracy.py, with the simulator) run the
same loop.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from station.result import Measurement

def white_cameras(result: Measurement) -> list[str]:
    """The cameras the result flags as having their rim edge at the sensor's white (warning kind
    ``exposure``, station/measure.py), in order."""
    return list(dict.fromkeys(f.camera for f in result.warning_flags if f.kind == "exposure" and f.camera))


def measure_bracketed(images: dict[str, np.ndarray], measure: Callable[[dict], Measurement],
                      recapture: Callable[[list[str], float], dict[str, np.ndarray]],
                      steps: tuple[float, ...] | list[float]) -> tuple[Measurement, dict, dict[str, float]]:
    """(result, the images it was measured on, {camera id: exposure factor} of the cameras
    taken again). Each step takes again the cameras still at the white, at ``step`` times the
    configured exposure (steps descending, each in (0, 1)); a camera that finds no rim in the
    shorter frame where it found one in the longer keeps the longer. The result is the last
    measurement's, its ``exposures`` set and a note saying which cameras and why."""
    result = measure(images)
    exposures: dict[str, float] = {}
    for step in steps:
        white = white_cameras(result)
        if not white:
            break
        taken = recapture(white, step)
        if not taken:  # the cameras could not be taken again (the recapture says why)
            break
        trial = measure({**images, **taken})
        lost = [c for c in taken if _found(result, c) and not _found(trial, c)]
        if lost:  # too dark there now (a shaded half): those keep the longer frame
            taken = {c: im for c, im in taken.items() if c not in lost}
            if not taken:
                break
            trial = measure({**images, **taken})
        images = {**images, **taken}
        exposures.update({c: step for c in taken})
        result = trial
    if exposures:
        result.exposures = dict(exposures)
        names = ", ".join(f"{c} at {f:g}x" for c, f in exposures.items())
        result.warnings.append(f"measured on frames taken again at a shorter exposure ({names} the configured one): "
                               "the rim's lip was at the sensor's white there (the sun or a lamp on the wheel; if it "
                               "happens on every car, shorten that camera's exposure_us)")
    return result, images, exposures


def _found(result: Measurement, camera: str) -> bool:
    """Whether the result's detection of ``camera`` found a rim (True where it does not say:
    a cycle that stopped at a pair's check keeps no detection summary)."""
    d = (result.detections or {}).get(camera)
    return d is None or d.ok
