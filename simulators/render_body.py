"""A plain vehicle body around the wheels: a box with wheel arches, and the floor's shadows.

The body makes the images look like a car on a lift rather than four loose wheels: the fender
panel and its arch edge (a circle not concentric with the rim) sit above each wheel, the
far wheels hide behind the body, the floor under the car is in shadow. Box in the vehicle
frame (see simulators/vehicle.py): x across, y forward, z up. Arrays: rays (N,3), station frame.
"""

from __future__ import annotations

import numpy as np

from calibration.station_frame import WHEELS
from simulators.scene import Appearance, Lighting
from simulators.shading import LABEL_BODY, Hits, mirror_reflection, rowmat, shade
from simulators.vehicle import Vehicle

SILL_Z_M = 0.20          # lowest edge of the body panel (ground clearance)
ROOF_Z_M = 1.45
FRONT_OVERHANG_M = 0.85
REAR_OVERHANG_M = 0.95
ARCH_CLEARANCE_M = 0.045  # arch radius = tyre radius + this
WELL_DEPTH_M = 0.38       # the wheel-well liner behind the arch opening
PANEL, WELL, END, UNDER, CREASE, SILL = range(6)


def body_box(vehicle: Vehicle) -> tuple[np.ndarray, np.ndarray]:
    """(lo (3,), hi (3,)) corners of the body box in the vehicle frame (m)."""
    g = vehicle.wheel
    half_x = max(vehicle.track_front_m, vehicle.track_rear_m) / 2 + g.sidewall_bulge_m + 0.045
    lo = np.array([-half_x, -vehicle.wheelbase_m / 2 - REAR_OVERHANG_M, SILL_Z_M])
    hi = np.array([half_x, vehicle.wheelbase_m / 2 + FRONT_OVERHANG_M, ROOF_Z_M])
    return lo, hi


def paint_albedo(vehicle: Vehicle) -> float:
    """Body colour as a grey level, varied between vehicles (hash of the geometry)."""
    h = abs(np.modf(np.sin(vehicle.wheelbase_m * 97.1 + vehicle.wheel.tyre_radius_m * 53.3) * 43758.5453)[0])
    return float(0.12 + 0.7 * h)


def trace_body(o: np.ndarray, d: np.ndarray, idx: np.ndarray, hits: Hits, lighting: Lighting,
               vehicle: Vehicle, look: Appearance = Appearance()) -> None:
    """Intersect rays d[idx] (N,3) with the body box minus the wheel arches (camera outside).
    look.body_mirror: the gloss paint mirrors the workshop (bright bands of its lights)."""
    if idx.size == 0:
        return
    Rv = vehicle.R_station_vehicle
    offset = vehicle.offset_station()
    ov = Rv.T @ (o - offset)
    dirs = d[idx]
    # direction components in the vehicle frame, (N,) each (explicit: no BLAS, see rowmat)
    dv = [dirs[:, 0] * Rv[0, k] + dirs[:, 1] * Rv[1, k] + dirs[:, 2] * Rv[2, k] for k in range(3)]
    lo, hi = body_box(vehicle)
    paint = paint_albedo(vehicle)
    r_arch = vehicle.wheel.tyre_radius_m + ARCH_CLEARANCE_M
    arches = [vehicle.wheel_center_vehicle(name) for name in WHEELS]
    # a convex box seen from outside: only the faces turned toward the camera can be entered,
    # each a plane test; they do not overlap in the image
    for k in range(3):
        for bound, sign in ((hi[k], 1.0), (lo[k], -1.0)):
            if not sign * (ov[k] - bound) > 0:
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (bound - ov[k]) / dv[k]
            ok = (t > 1e-6) & (t < hits.t[idx])
            j1, j2 = [j for j in range(3) if j != k]
            c1 = ov[j1] + t * dv[j1]
            c2 = ov[j2] + t * dv[j2]
            ok &= (c1 >= lo[j1]) & (c1 <= hi[j1]) & (c2 >= lo[j2]) & (c2 <= hi[j2])
            sel = np.flatnonzero(ok)
            if sel.size == 0:
                continue
            t, c1, c2 = t[sel], c1[sel], c2[sel]
            if k == 0:   # side panel: (c1, c2) = (y, z); wheel arches open onto the dark well
                part = np.full(sel.size, PANEL, np.int32)
                in_arch = np.zeros(sel.size, bool)
                for c in arches:
                    if np.sign(c[0]) == sign:
                        in_arch |= (c1 - c[1]) ** 2 + (c2 - c[2] - 0.03) ** 2 < r_arch ** 2
                part[np.abs(c2 - 0.78) < 0.012] = CREASE
                part[c2 < 0.30] = SILL
                part[in_arch] = WELL
                t = np.where(in_arch, t + WELL_DEPTH_M / np.maximum(np.abs(dv[0][sel]), 1e-9), t)
                nearer = t < hits.t[idx[sel]]
                sel, t, part = sel[nearer], t[nearer], part[nearer]
            else:
                part = np.full(sel.size, END if k == 1 else UNDER, np.int32)
            albedo = np.select([part == WELL, part == SILL, part == CREASE, part == UNDER],
                               [0.035, 0.06, paint * 0.55, 0.05], paint)
            spec = np.where((part == PANEL) | (part == END), 0.35, 0.0)
            normal = sign * Rv[:, k]
            value = shade(albedo, normal, dirs[sel], lighting, specular=spec, shininess=40.0)
            if look.body_mirror > 0:
                gloss = np.flatnonzero(spec > 0)
                n = gloss.size
                value[gloss] += mirror_reflection((np.full(n, normal[0]), np.full(n, normal[1]), np.full(n, normal[2])),
                                                  tuple(dirs[sel[gloss], k] for k in range(3)), np.eye(3),
                                                  look.body_mirror)
            hits.store(idx[sel], t, LABEL_BODY + part, value)


def floor_shadow(vehicle: Vehicle):
    """f(points (N,3) station) -> (N,) float32 light factor on the floor: the car's shadow."""
    Rv = vehicle.R_station_vehicle
    offset = vehicle.offset_station()
    lo, hi = body_box(vehicle)
    contacts = np.array([vehicle.wheel_center_vehicle(w)[:2] for w in WHEELS])
    g = vehicle.wheel

    def factor(p: np.ndarray) -> np.ndarray:
        q = rowmat(p - offset, Rv)
        # soft-edged box shadow under the body: 0.45 of the light inside, 1 far outside
        dx = np.maximum(np.abs(q[:, 0]) - hi[0], 0.0)
        dy = np.maximum(np.maximum(lo[1] - q[:, 1], q[:, 1] - hi[1]), 0.0)
        out = np.hypot(dx, dy)
        f = 1.0 - 0.55 * np.exp(-(out / 0.12) ** 2)
        # contact shadows: dark where the tyre meets the runway
        for c in contacts:
            r2 = ((q[:, 0] - c[0]) / (0.6 * g.tyre_width_m)) ** 2 + ((q[:, 1] - c[1]) / (0.35 * g.tyre_radius_m)) ** 2
            f = f * (1.0 - 0.75 * np.exp(-r2))
        return f.astype(np.float32)

    return factor
