"""A simulated vehicle on the lift: wheel geometry, toe and camber, and its wheels' true poses.

Angles follow docs/conventions.md. The vehicle's own frame is the alignment frame of a
perfect measurement: all wheel centres at one height (so the wheel-centre plane is parallel to
the runway), x to the right, y forward along the geometric centreline. It is placed on the lift
by ``position_m`` (x, y of its centre) and ``yaw_deg`` about z.

Each wheel turns about its spin axis (toe and camber are the spin axis's). A real rim is not
square to its hub: its lip plane is tilted against the spin axis (``Runout``), so the rim the
cameras see wobbles as the wheel turns. The car rolls along the runways (``roll_m``: every wheel
turns by the distance over its rolling radius, the tyre radius here), and its front wheels steer
about their kingpin axes (``steer_deg``, ``Kingpin``: caster, steering axis inclination, scrub
radius; the inner wheel of a turn steers more, by ``ackermann``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from calibration.station_frame import SIDE, WHEELS



@dataclass(frozen=True)
class WheelGeometry:
    """Rim and tyre, shared by the four wheels. Lengths in metres.

    The rim-flange edge is the circle where the tyre meets the metal rim: radius
    ``rim_radius_m`` in the wheel plane through the wheel centre. The wheel's outer face is
    on the +w side (w = outward spin axis).
    """

    rim_radius_m: float = 0.2159      # 17 inch rim: flange edge radius
    tyre_radius_m: float = 0.3300
    tyre_width_m: float = 0.225
    flange_width_m: float = 0.012     # radial width of the bright flange lip inside the edge
    sidewall_bulge_m: float = 0.020   # how far the tyre sidewall stands out beyond the flange plane
    rim_face_depth_m: float = 0.045   # spoke face recessed inward (-w) from the flange plane
    hub_radius_m: float = 0.060
    spoke_count: int = 5
    spoke_width_frac: float = 0.35    # fraction of the angular period that is spoke
    rim_albedo: float = 0.75          # 0..1 reflectance of the metal
    tyre_albedo: float = 0.10


@dataclass(frozen=True)
class Runout:
    """How a rim's lip plane sits against its wheel's spin axis: tilted by ``tilt_deg`` toward
    the direction ``phase_deg`` of the wheel's own frame (from spoke 0, about the outward axis),
    its centre ``offset_m`` off the axis in that direction. The tilt turns with the wheel."""

    tilt_deg: float = 0.0
    phase_deg: float = 0.0
    offset_m: float = 0.0


@dataclass(frozen=True)
class Kingpin:
    """A front wheel's steering axis: its top leans rearward by ``caster_deg`` and inward by
    ``sai_deg`` (steering axis inclination); it meets the ground ``scrub_radius_m`` inboard of
    the tyre's contact centre (negative: outboard) and ``trail_m`` ahead of it."""

    caster_deg: float = 5.0
    sai_deg: float = 12.0
    scrub_radius_m: float = 0.02
    trail_m: float = 0.0


@dataclass(frozen=True)
class Vehicle:
    wheelbase_m: float = 2.70
    track_front_m: float = 1.56
    track_rear_m: float = 1.56
    position_m: tuple[float, float] = (0.0, 0.0)  # vehicle centre on the lift (station x, y)
    yaw_deg: float = 0.0
    toe_deg: dict = field(default_factory=lambda: {w: 0.0 for w in WHEELS})
    camber_deg: dict = field(default_factory=lambda: {w: 0.0 for w in WHEELS})
    spin_phase_deg: dict = field(default_factory=lambda: {w: 0.0 for w in WHEELS})
    wheel: WheelGeometry = field(default_factory=WheelGeometry)
    runout: dict = field(default_factory=lambda: {w: Runout() for w in WHEELS})
    roll_m: float = 0.0         # how far the car has rolled forward since it was placed (m)
    steer_deg: float = 0.0      # the steering: the angle of a wheel midway between the front wheels (left +)
    ackermann: float = 1.0      # share of the Ackermann difference between the inner and outer wheel
    kingpin: dict = field(default_factory=lambda: {"FL": Kingpin(), "FR": Kingpin()})

    # --- truth ------------------------------------------------------------------------------
    @property
    def R_station_vehicle(self) -> np.ndarray:
        a = np.radians(self.yaw_deg)
        return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])

    def wheel_center_vehicle(self, wheel: str) -> np.ndarray:
        """(3,) wheel (rim-flange circle) centre in the vehicle frame (m)."""
        front = wheel.startswith("F")
        track = self.track_front_m if front else self.track_rear_m
        y = self.wheelbase_m / 2 if front else -self.wheelbase_m / 2
        return np.array([SIDE[wheel] * track / 2, y, self.wheel.tyre_radius_m])

    def wheel_axis_vehicle(self, wheel: str) -> np.ndarray:
        """(3,) outward unit spin axis in the vehicle frame, exactly from toe and camber.

        Inverts toe = atan2(wy, s wx), camber = atan2(-wz, s wx): w ~ (s, tan toe, -tan camber).
        """
        s = SIDE[wheel]
        w = np.array([s, np.tan(np.radians(self.toe_deg[wheel])), -np.tan(np.radians(self.camber_deg[wheel]))])
        return w / np.linalg.norm(w)

    def forward_station(self) -> np.ndarray:
        """(3,) the car's forward direction (its y) in the station frame."""
        return self.R_station_vehicle @ np.array([0.0, 1.0, 0.0])

    def offset_station(self) -> np.ndarray:
        """(3,) where the vehicle frame's origin stands in the station frame: placed at
        ``position_m``, then rolled ``roll_m`` forward."""
        offset = np.array([self.position_m[0], self.position_m[1], 0.0])
        return offset + self.roll_m * self.forward_station() if self.roll_m else offset

    def steer_angles_deg(self) -> dict[str, float]:
        """Each front wheel's steer angle (deg, left +) for ``steer_deg``: the wheel inside the
        turn more, by the share ``ackermann`` of the difference that makes both wheels roll
        about one centre on the rear axle's line; 0 for the rear wheels."""
        out = {w: 0.0 for w in WHEELS}
        if self.steer_deg == 0.0:
            return out
        t = np.tan(np.radians(abs(self.steer_deg)))
        turn = self.wheelbase_m / t                                  # the turn's radius at the middle
        inner, outer = ("FL", "FR") if self.steer_deg > 0 else ("FR", "FL")
        for wheel, sign in ((inner, -1.0), (outer, 1.0)):
            exact = np.degrees(np.arctan(self.wheelbase_m / (turn + sign * self.track_front_m / 2)))
            out[wheel] = float(np.sign(self.steer_deg) * (abs(self.steer_deg) + self.ackermann
                                                          * (exact - abs(self.steer_deg))))
        return out

    def kingpin_axis_vehicle(self, wheel: str) -> tuple[np.ndarray, np.ndarray]:
        """(a point (3,), the unit upward direction (3,)) of a front wheel's steering axis in the
        vehicle frame, at straight ahead."""
        k = self.kingpin[wheel]
        s = SIDE[wheel]
        direction = np.array([-s * np.tan(np.radians(k.sai_deg)), -np.tan(np.radians(k.caster_deg)), 1.0])
        contact = self.wheel_center_vehicle(wheel) * np.array([1.0, 1.0, 0.0])   # under the wheel centre
        return contact + np.array([-s * k.scrub_radius_m, k.trail_m, 0.0]), direction / np.linalg.norm(direction)

    def spin_frame_station(self, wheel: str) -> tuple[np.ndarray, np.ndarray]:
        """(hub centre (3,), R_station_spin (3,3)) of a wheel as it stands now: columns u, v, w,
        w the outward spin axis, u the direction of spoke 0 (``spin_phase_deg``, turned by the
        roll), v = w x u; the car rolled by ``roll_m``, a front wheel steered about its kingpin."""
        R = self.R_station_vehicle
        offset = self.offset_station()
        center = R @ self.wheel_center_vehicle(wheel) + offset
        w = R @ self.wheel_axis_vehicle(wheel)
        up = np.array([0.0, 0.0, 1.0])
        u0 = up - w * (w @ up)
        u0 /= np.linalg.norm(u0)
        v0 = np.cross(w, u0)
        phase = np.radians(self.spin_phase_deg[wheel])
        if self.roll_m:  # rolling forward turns every wheel about the car's -x: about w by -s d / r
            phase = phase - SIDE[wheel] * self.roll_m / self.wheel.tyre_radius_m
        u = np.cos(phase) * u0 + np.sin(phase) * v0
        v = np.cross(w, u)
        frame = np.stack([u, v, w], axis=1)
        steer = self.steer_angles_deg()[wheel]
        if steer:
            point, k = self.kingpin_axis_vehicle(wheel)
            turn = _rotation(R @ k, np.radians(steer))
            point = R @ point + offset
            center = point + turn @ (center - point)
            frame = turn @ frame
        return center, frame

    def knuckle_turn_station(self, wheel: str) -> np.ndarray:
        """(3,3) how the wheel's knuckle (and the brake caliper on it) is turned by the steering
        about its kingpin, in the station frame; the identity for a wheel not steered."""
        steer = self.steer_angles_deg()[wheel]
        if not steer:
            return np.eye(3)
        _, k = self.kingpin_axis_vehicle(wheel)
        return _rotation(self.R_station_vehicle @ k, np.radians(steer))

    def wheel_frame_station(self, wheel: str) -> tuple[np.ndarray, np.ndarray]:
        """(center (3,), R_station_wheel (3,3)) of the wheel as the cameras see it (the rim, the
        tyre, the spokes): the spin frame, tilted and offset by the rim's runout. Columns u, v,
        w; w = the rim's outward axis (the lip plane's normal)."""
        center, frame = self.spin_frame_station(wheel)
        r = self.runout[wheel]
        if r.tilt_deg == 0.0 and r.offset_m == 0.0:
            return center, frame
        phi = np.radians(r.phase_deg)
        toward = np.array([np.cos(phi), np.sin(phi), 0.0])          # in the spin frame
        tilt = _rotation(np.array([-np.sin(phi), np.cos(phi), 0.0]), np.radians(r.tilt_deg))
        return center + r.offset_m * (frame @ toward), frame @ tilt

    def roll_angle_deg(self, wheel: str) -> float:
        """How far the wheel has turned about its outward spin axis since it was placed (deg)."""
        return float(np.degrees(-SIDE[wheel] * self.roll_m / self.wheel.tyre_radius_m))


    def truth(self) -> dict:
        """Ground truth for a measurement, in the documented JSON schema's units. Per wheel:
        ``toe_deg``/``camber_deg`` the alignment set on the car (its spin axis at straight ahead),
        ``rim_toe_deg``/``rim_camber_deg`` those of the rim's plane as it stands now (with runout),
        ``center_station_m``/``axis_station`` the rim as the cameras see it now (with runout,
        steered, rolled), ``spin_center_station_m``/``spin_axis_station`` the hub's,
        ``roll_deg`` how far it has turned, ``steer_deg`` how far it is steered."""
        wheels = {}
        steer = self.steer_angles_deg()
        for wname in WHEELS:
            c, Rw = self.wheel_frame_station(wname)
            hub, Rs = self.spin_frame_station(wname)
            r = self.runout[wname]
            w_vehicle = self.R_station_vehicle.T @ Rw[:, 2]
            side = SIDE[wname] * w_vehicle[0]
            wheels[wname] = {
                "toe_deg": float(self.toe_deg[wname]),
                "camber_deg": float(self.camber_deg[wname]),
                "rim_toe_deg": float(np.degrees(np.arctan2(w_vehicle[1], side))),
                "rim_camber_deg": float(np.degrees(np.arctan2(-w_vehicle[2], side))),
                "center_station_m": c.tolist(),
                "axis_station": Rw[:, 2].tolist(),
                "rim_radius_m": self.wheel.rim_radius_m,
                "spin_center_station_m": hub.tolist(),
                "spin_axis_station": Rs[:, 2].tolist(),
                "roll_deg": self.roll_angle_deg(wname),
                "steer_deg": steer[wname],
                "runout_deg": float(r.tilt_deg),
                "runout_phase_deg": float(r.phase_deg),
                "runout_mm": float(2 * self.wheel.rim_radius_m * np.sin(np.radians(r.tilt_deg)) * 1000),
            }
        for wname, k in self.kingpin.items():
            point, direction = self.kingpin_axis_vehicle(wname)
            s = SIDE[wname]
            wheels[wname].update({
                "caster_deg": float(np.degrees(np.arctan2(-direction[1], direction[2]))),
                "sai_deg": float(np.degrees(np.arctan2(-s * direction[0], direction[2]))),
                "included_angle_deg": float(np.degrees(np.arctan2(-s * direction[0], direction[2]))
                                            + self.camber_deg[wname]),
                "kingpin_point_station_m": (self.R_station_vehicle @ point + self.offset_station()).tolist(),
                "kingpin_axis_station": (self.R_station_vehicle @ direction).tolist(),
            })
        t = self.toe_deg
        return {
            "wheels": wheels,
            "total_toe_front_deg": t["FL"] + t["FR"],
            "total_toe_rear_deg": t["RL"] + t["RR"],
            "thrust_deg": (t["RL"] - t["RR"]) / 2,
            "vehicle": {k: v for k, v in asdict(self).items() if k != "wheel"},
            "wheel_geometry": asdict(self.wheel),
        }


def _rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """(3,3) rotation by ``angle_rad`` about the unit ``axis`` (3,), right-handed (Rodrigues)."""
    k = np.asarray(axis, float)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)



def random_vehicle(rng: np.random.Generator, nominal_wheelbase_m: float = 2.70,
                   nominal_track_m: float = 1.56, toe_range_deg: float = 2.0,
                   camber_range_deg: float = 3.0) -> Vehicle:
    """A random vehicle within the station's working envelope (see bench/accuracy.py)."""
    rim_inch = rng.choice([15, 16, 17, 18, 19])
    rim_r = rim_inch * 0.0254 / 2 + 0.0125  # flange edge sits ~12 mm outside the bead seat
    tyre_r = rim_r + rng.uniform(0.09, 0.13)
    geometry = WheelGeometry(
        rim_radius_m=float(rim_r), tyre_radius_m=float(tyre_r),
        tyre_width_m=float(rng.uniform(0.19, 0.25)),
        flange_width_m=float(rng.uniform(0.008, 0.016)),
        sidewall_bulge_m=float(rng.uniform(0.010, 0.030)),
        rim_face_depth_m=float(rng.uniform(0.02, 0.07)),
        hub_radius_m=float(rng.uniform(0.05, 0.08)),
        spoke_count=int(rng.integers(4, 11)),
        spoke_width_frac=float(rng.uniform(0.2, 0.6)),
        rim_albedo=float(rng.uniform(0.45, 0.9)),
        tyre_albedo=float(rng.uniform(0.05, 0.18)),
    )
    track = nominal_track_m + rng.uniform(-0.05, 0.05)
    return Vehicle(
        wheelbase_m=float(nominal_wheelbase_m + rng.uniform(-0.06, 0.06)),
        track_front_m=float(track + rng.uniform(-0.02, 0.02)),
        track_rear_m=float(track + rng.uniform(-0.02, 0.02)),
        position_m=(float(rng.uniform(-0.04, 0.04)), float(rng.uniform(-0.04, 0.04))),
        yaw_deg=float(rng.uniform(-0.8, 0.8)),
        toe_deg={w: float(rng.uniform(-toe_range_deg, toe_range_deg)) for w in WHEELS},
        camber_deg={w: float(rng.uniform(-camber_range_deg, camber_range_deg)) for w in WHEELS},
        spin_phase_deg={w: float(rng.uniform(0, 360)) for w in WHEELS},
        wheel=geometry,
    )


def random_runout(rng: np.random.Generator, max_tilt_deg: float = 0.3, max_offset_m: float = 0.0005) -> dict:
    """A runout per wheel: tilt U(0, ``max_tilt_deg``), phase U(0, 360) deg, the lip centre
    U(0, ``max_offset_m``) off the axis (a 0.3 deg tilt of a 17-inch lip is 2.3 mm of lateral
    runout across it)."""
    return {w: Runout(float(rng.uniform(0, max_tilt_deg)), float(rng.uniform(0, 360)),
                      float(rng.uniform(0, max_offset_m))) for w in WHEELS}


def random_kingpins(rng: np.random.Generator) -> tuple[dict, float]:
    """({front wheel: Kingpin}, ackermann share): caster U(2, 8) deg, SAI U(8, 15) deg, scrub
    radius U(-10, 60) mm, trail U(0, 30) mm, each front wheel its own; Ackermann U(0.5, 1)."""
    kingpins = {w: Kingpin(float(rng.uniform(2, 8)), float(rng.uniform(8, 15)), float(rng.uniform(-0.01, 0.06)),
                           float(rng.uniform(0.0, 0.03))) for w in ("FL", "FR")}
    return kingpins, float(rng.uniform(0.5, 1.0))
