"""The wheels in the station frame: their names, axles and sides (docs/conventions.md).

The station frame is the one the calibration box on its fixtures defines: x to the car's right,
y forward, z up. Every layer names wheels and axles with these; nothing else defines them.
"""

from __future__ import annotations

WHEELS = ("FL", "FR", "RL", "RR")
AXLES = {"front": ("FL", "FR"), "rear": ("RL", "RR")}   # axle -> (left wheel, right wheel)
SIDE = {"FL": -1.0, "FR": 1.0, "RL": -1.0, "RR": 1.0}   # the sign of x on the wheel's side
AXLE_PARTNER = {"FL": "FR", "FR": "FL", "RL": "RR", "RR": "RL"}
