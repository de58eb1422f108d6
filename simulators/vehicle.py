"""A simulated vehicle on the lift: wheel geometry, toe and camber, and its wheels' true poses.

Angles follow docs/conventions.md. The vehicle's own frame is the alignment frame of a
perfect measurement: all wheel centres at one height (so the wheel-centre plane is parallel to
the runway), x to the right, y forward along the geometric centreline. It is placed on the lift
by ``position_m`` (x, y of its centre) and ``yaw_deg`` about z.
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

    def wheel_frame_station(self, wheel: str) -> tuple[np.ndarray, np.ndarray]:
        """(center (3,), R_station_wheel (3,3)) with columns u, v, w; w = outward axis.

        u is the in-plane direction of spoke 0 (set by ``spin_phase_deg``), v = w x u.
        """
        R = self.R_station_vehicle
        offset = np.array([self.position_m[0], self.position_m[1], 0.0])
        center = R @ self.wheel_center_vehicle(wheel) + offset
        w = R @ self.wheel_axis_vehicle(wheel)
        up = np.array([0.0, 0.0, 1.0])
        u0 = up - w * (w @ up)
        u0 /= np.linalg.norm(u0)
        v0 = np.cross(w, u0)
        phase = np.radians(self.spin_phase_deg[wheel])
        u = np.cos(phase) * u0 + np.sin(phase) * v0
        v = np.cross(w, u)
        return center, np.stack([u, v, w], axis=1)

    def truth(self) -> dict:
        """Ground truth for a measurement, in the documented JSON schema's units."""
        wheels = {}
        for wname in WHEELS:
            c, Rw = self.wheel_frame_station(wname)
            wheels[wname] = {
                "toe_deg": float(self.toe_deg[wname]),
                "camber_deg": float(self.camber_deg[wname]),
                "center_station_m": c.tolist(),
                "axis_station": Rw[:, 2].tolist(),
                "rim_radius_m": self.wheel.rim_radius_m,
            }
        t = self.toe_deg
        return {
            "wheels": wheels,
            "total_toe_front_deg": t["FL"] + t["FR"],
            "total_toe_rear_deg": t["RL"] + t["RR"],
            "thrust_deg": (t["RL"] - t["RR"]) / 2,
            "vehicle": {k: v for k, v in asdict(self).items() if k != "wheel"},
            "wheel_geometry": asdict(self.wheel),
        }


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
