"""The rims of an axle are one size: a rim measured larger or smaller than its axle partner's.

The two rims of an axle are the same size, and on every benchmark set a well-measured pair gives
its rim's radius to 0.05 % (0.1 mm at sigma 2). A rim that comes out larger or smaller than its
partner's by more than ``RIM_SIZE_WARNING`` (but within ``AXLE_RIM_TOLERANCE``, beyond which
it is another contour, paired again or refused: station/wheel/axle_rims.py) had part of its edge
found off the flange: on a lit tyre bead or a tyre brighter than the lip (larger), or where the flange is hidden or
shaded (smaller). The circle's radius and its tilt are tied (a circle tilted toward a camera 13
deg off its axis looks narrower), so such a wheel's angles are off by tenths of a degree: on
the simulated sets every wheel 0.25 % or more off its partner was 0.3-0.7 deg off in toe or
camber, several of them stating +/-0.1 or less (docs/history/accuracy.md, "A rim a little
larger or smaller than its partner's is warned of").

This only warns; it changes no value. Holding such a wheel's radius at its partner's in the
fit corrected the simulated ones (whose rims are exactly equal), but the same tie makes it
unsafe on real cars: held 0.1 % off its true size (0.25 mm, within what two rims of one
nominal size may differ by), exact rim points gave an axis 0.3 deg off; 0.2 %, 0.75 deg.
"""
from __future__ import annotations

import statistics

AXLE_RIM_TOLERANCE = 0.015  # the two rims of an axle agree in radius to 0.7 % on every benchmark set (dark
                            # rims; 0.05 % at sigma 2); another contour differs by 2-6 % (a lip's inner edge,
                            # a ring inside the barrel) to 30 % and more (the tyre)
RIM_SIZE_WARNING = 0.002  # relative radius difference between the rims of an axle that warns


def odd_rims(radius_m: dict[str, float], partner: dict[str, str], tolerance: float) -> list[tuple[str, str]]:
    """[(odd wheel, its axle partner)] for each axle (once, in wheel-name order) whose two rims'
    radii (m, per wheel) differ by more than ``tolerance`` of their mean; the odd wheel is the
    one farther from the median of all the rims measured (the odd one when the other axle
    agrees). A wheel without its partner is not judged. ``partner``: wheel -> the other wheel of
    its axle."""
    median = statistics.median(radius_m.values()) if radius_m else 0.0
    out = []
    for wheel in sorted(radius_m):
        other = partner.get(wheel)
        if other not in radius_m or wheel > other:  # each axle once
            continue
        a, b = radius_m[wheel], radius_m[other]
        if abs(a - b) > tolerance * 0.5 * (a + b):
            out.append((wheel, other) if abs(a - median) >= abs(b - median) else (other, wheel))
    return out


def size_mismatches(radius_m: dict[str, float], partner: dict[str, str]) -> list[tuple[str, str]]:
    """[(wheel, warning text)] for each axle whose two rims' radii (m, per wheel) differ by more
    than ``RIM_SIZE_WARNING`` (:func:`odd_rims`), the text saying by how much and what to check."""
    out = []
    for odd, even in odd_rims(radius_m, partner, RIM_SIZE_WARNING):
        d = radius_m[odd] - radius_m[even]
        out.append((odd, f"its rim came out {abs(d) * 1000:.1f} mm {'larger' if d > 0 else 'smaller'} in radius "
                         f"than {even}'s ({abs(d) / radius_m[even]:.2%}): the rims of an axle are one size, so part "
                         f"of its edge was likely found {'on the tyre' if d > 0 else 'inside the flange'}, and its "
                         "toe and camber may be off by tenths of a degree; look at its images (station review)"))
    return out
