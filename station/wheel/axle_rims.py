"""The rims of an axle are one size: a wheel measured at another size than its axle partner
took another contour; it is paired again at the partner's size, or the cycle is refused.
A wheel whose two cameras found no one rim is paired again the same way, at another measured
wheel's size and orientation (:func:`pair_from_partner`).
(A rim a little off its partner's size is only warned of: station/wheel/rim_size.py.)
"""

from __future__ import annotations

import numpy as np

from calibration.station_frame import AXLE_PARTNER, SIDE, WHEELS
from station.config import StationConfig
from station.errors import MeasurementError, StationError
from station.result import Failure, Measurement, WarningFlag
from station.wheel.pair import WheelObservation, check_same_rim, reconstruct_wheel, resolve_pair
from station.wheel.rim_size import AXLE_RIM_TOLERANCE, odd_rims


def _rescued_to_size(wheel: str, observations: dict, outcomes: list, images: dict, cameras: dict,
                     config: StationConfig, calibration_cov: dict | None) -> tuple[WheelObservation, str] | None:
    """The odd wheel of :func:`axle_rim_mismatch` from its cameras' first choices and runner-up
    candidates, the combination that is one rim of its axle partner's size (with a warning
    naming what was taken); failing that, one camera's rim carried to the other
    (:func:`_carried_pair`); or None."""
    outcome = next(o for o in outcomes if o.wheel == wheel)
    cams = outcome.cams
    partner = AXLE_PARTNER[wheel]
    radius_m = observations[partner].circle.radius_m
    found = resolve_pair(wheel, cams, outcome.first_choices, {c: images[c] for c in cams},
                         {c: cameras[c] for c in cams}, config, (calibration_cov or {}).get(wheel), radius_m=radius_m)
    if found is None:
        found = _carried_pair(wheel, cams, [outcome.first_choices, dict(zip(cams, observations[wheel].detections))],
                              images, cameras, config, (calibration_cov or {}).get(wheel),
                              observations[wheel].circle.axis_station, radius_m)
    if found is None:
        return None
    obs, note = found
    return obs, note.replace("the first choices were not the same rim",
                             f"the first choices' rim was not the size of {partner}'s")


def _carried_pair(wheel: str, cams: tuple[str, str], detection_sets: list[dict], images: dict, cameras: dict,
                  config: StationConfig, calibration_cov: np.ndarray | None, axis_station: np.ndarray,
                  radius_m: float, reference: str = "its axle partner") -> tuple[WheelObservation, str] | None:
    """A pair made of one camera's detection and the rim searched again in the other camera
    from where that detection, at ``radius_m`` and in a plane across ``axis_station``, must
    appear there (station/wheel/rim_transfer.py): the best such pair (by the weaker score) that is one
    3-D rim of that size, with a warning saying what was done; None if there is none. Tried from
    each camera's detection in ``detection_sets`` (the first choices, the pairing taken);
    ``reference`` names whose size it is, for the warning. For when one camera's search ended
    between the flange and the lip's inner edge (a dark rim) and none of its candidates is the
    flange: carried from the other camera's first choice, the simulated rim was found 0.1 px
    from the true one and the wheel's centre 0.2 mm off."""
    from station.rim.detector import refine_candidate
    from station.wheel.rim_transfer import carried_prior

    best, tried = None, set()
    for detections in detection_sets:
        for src, dst in (cams, cams[::-1]):
            det = detections[src]
            if isinstance(det, StationError) or (src, id(det)) in tried:
                continue
            tried.add((src, id(det)))
            prior = carried_prior(det.ellipse, cameras[src], cameras[dst], axis_station, radius_m)
            if prior is None:
                continue
            try:
                found = refine_candidate(images[dst], prior, camera=cameras[dst], camera_id=dst)
                o = reconstruct_wheel(wheel, cams, {src: det, dst: found}, cameras, calibration_cov,
                                      other_contour_test=True)
                check_same_rim(o, config, allow_unchecked=False, images=images, cameras=cameras)
            except StationError:
                continue
            if abs(o.circle.radius_m - radius_m) > AXLE_RIM_TOLERANCE * radius_m:
                continue
            score = min(det.score, found.score)
            if best is None or score > best[0]:
                best = (score, o, src, dst)
    if best is None:
        return None
    _, o, src, dst = best
    return o, (f"{wheel} ({cams[0]}, {cams[1]}): the first choices were not the same rim; {dst}'s rim was searched "
               f"again where {src}'s rim, at {reference}'s size, must appear")


def pair_from_partner(outcomes: list, images: dict, cameras: dict, config: StationConfig,
                      calibration_cov: dict | None) -> None:
    """Each wheel whose cameras found no one rim (``WheelOutcome.error``; each camera found some
    contour), paired again with one camera's rim searched again in the other where, at the
    size of a measured wheel's rim and in a plane across that wheel's axis (mirrored from the
    other side), it must appear (:func:`_carried_pair`): its axle partner's, else its
    neighbour's on the same side, else the diagonal one's, each wheel paired so counting as
    measured for the next. A pair that passes every check, the size included, replaces the
    error (its outcome gets the detections and a warning saying what was done); else the error
    stands. For a camera whose edge, shaded or dirty on part of the lip, settled between two
    contours (a dirty lip: 6 of its points on the pair's circle), or took another contour."""
    measured = {o.wheel: o.observation for o in outcomes if o.observation is not None}
    # (an outcome has an error only where both cameras found a contour: station/wheel/pair.py)
    for o in sorted((o for o in outcomes if o.error is not None), key=lambda o: AXLE_PARTNER[o.wheel] not in measured):
        for ref in _references(o.wheel):
            if ref not in measured:
                continue
            # the station's x runs across the car: the other side's axis mirrors in it
            axis = measured[ref].circle.axis_station * np.array([SIDE[ref] * SIDE[o.wheel], 1.0, 1.0])
            found = _carried_pair(o.wheel, o.cams, [o.first_choices], images, cameras, config,
                                  (calibration_cov or {}).get(o.wheel), axis, measured[ref].circle.radius_m, ref)
            if found is None:
                continue
            o.observation, o.note = found
            o.error = None
            o.detections.update(dict(zip(o.cams, o.observation.detections)))
            measured[o.wheel] = o.observation
            break


def _references(wheel: str) -> list[str]:
    """The wheels whose rim ``wheel``'s is carried from, nearest first: its axle partner, its
    neighbour on the same side, the diagonal one."""
    same_side = next(w for w in WHEELS if w != wheel and SIDE[w] == SIDE[wheel])
    return [AXLE_PARTNER[wheel], same_side, AXLE_PARTNER[same_side]]


def settle_axles(result: Measurement, observations: dict, outcomes: list, images: dict, cameras: dict,
                 config: StationConfig, calibration_cov: dict | None) -> Failure | None:
    """Where :func:`axle_rim_mismatch` finds an odd wheel, pair it again at its partner's size
    (``observations`` and the result's warnings updated); the cycle's failure if that fails."""
    mismatch = axle_rim_mismatch(observations)
    if mismatch is None:
        return None
    wheel, text = mismatch
    rescued = _rescued_to_size(wheel, observations, outcomes, images, cameras, config, calibration_cov)
    if rescued is not None:
        observations[wheel], note = rescued
        stale = next(o.note for o in outcomes if o.wheel == wheel)  # (a runner-up pairing of the wheel's own)
        result.warnings = [w for w in result.warnings if w != stale] + [note]
        if not result.has_flag("runner_up", wheel):
            result.warning_flags.append(WarningFlag("runner_up", wheel))
        mismatch = axle_rim_mismatch(observations)
        if mismatch is None:
            return None
        wheel, text = mismatch
    cams = observations[wheel].cams
    return Failure(MeasurementError.code, f"{wheel} ({cams[0]}, {cams[1]}): {text}",
                   f"look at both cameras' images of {wheel} (station review); if another wheel is fitted "
                   "there (a spare), fit the matching one before aligning", wheel, f"{cams[0]}+{cams[1]}")


def axle_rim_mismatch(observations: dict) -> tuple[str, str] | None:
    """(wheel, why) when the two rims of an axle differ in radius by more than
    AXLE_RIM_TOLERANCE: the rims of an axle are the same size, so one pair measured another
    contour (both its cameras on the tyre's outline, say, which a 3-D circle fits as well as
    the rim) or another wheel is fitted. The wheel named is the one farther from the median
    radius of the four (station.wheel.rim_size.odd_rims). None when they agree."""
    radius = {w: o.circle.radius_m for w, o in observations.items()}
    odd = odd_rims(radius, AXLE_PARTNER, AXLE_RIM_TOLERANCE)
    if not odd:
        return None
    wheel, other = odd[0]
    return wheel, (f"the rim found is {radius[wheel] * 1000:.0f} mm in radius, {other}'s "
                   f"{radius[other] * 1000:.0f} mm: the rims of an axle are the same size, so this "
                   "pair measured another contour (the tyre, the hub) or another wheel is fitted")
