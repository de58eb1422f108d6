"""The simulated station: the TRUE cameras (as built, not as designed) and what stands before them.

``SimWorld.from_config(config)`` starts from each camera's designed mount (``nominal`` in
config/station.yaml) and perturbs it with a generator seeded by ``simulation.station_seed``:
mount position +-5 mm, orientation +-0.5 deg, focal length +-3 %, principal point +-15 px, lens
distortion k1 in [-0.25, 0.05], k2 in [-0.05, 0.15], k3 in [-0.02, 0.02], p1, p2 in +-5e-4, and
a PSF blur of 0.6..0.9 px. The calibration must recover these; ``truth()`` writes them down.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, fields, replace

import numpy as np

from calibration.camera_model import CameraModel, look_at, rodrigues_to_matrix
from simulators.render import render_clean, sensor_frame
from simulators.scene import Appearance, Lighting, Scene
from simulators.vehicle import Vehicle, WheelGeometry, random_kingpins, random_runout, random_vehicle

_VEHICLE_FIELDS = {f.name for f in fields(Vehicle)}
_WHEEL_FIELDS = {f.name for f in fields(WheelGeometry)}


def perturbed_camera(name: str, width: int, height: int, position_m, look_at_m, focal_px: float,
                     rng: np.random.Generator) -> CameraModel:
    """A camera as built: the nominal mount and lens plus manufacturing/mounting scatter."""
    R_nom, _ = look_at(np.asarray(position_m, float), np.asarray(look_at_m, float))
    C = np.asarray(position_m, float) + rng.uniform(-0.005, 0.005, 3)
    R = rodrigues_to_matrix(np.radians(rng.uniform(-0.5, 0.5, 3))) @ R_nom
    fx = focal_px * (1 + rng.uniform(-0.03, 0.03))
    fy = fx * (1 + rng.uniform(-0.001, 0.001))
    cx = (width - 1) / 2 + rng.uniform(-15, 15)
    cy = (height - 1) / 2 + rng.uniform(-15, 15)
    k1 = rng.uniform(-0.25, 0.05)
    k2 = rng.uniform(-0.05, 0.15)
    k3 = rng.uniform(-0.02, 0.02)
    p1, p2 = rng.uniform(-5e-4, 5e-4, 2)
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    return CameraModel(name, width, height, K, np.array([k1, k2, p1, p2, k3]), R, -R @ C)


class SimWorld:
    """Eight true cameras and a scene. Same seeds give bit-identical images."""

    def __init__(self, config, cameras: dict[str, CameraModel], blur_sigma: dict[str, float],
                 noise_sigma: float | None = None, gain_override: dict[str, float] | None = None,
                 body: bool = True, supersample: int = 34):
        self.config = config
        self.body = body
        self.supersample = int(supersample)
        self.cameras = cameras
        self.blur_sigma = blur_sigma
        self.noise_sigma = float(config.simulation.noise_sigma if noise_sigma is None else noise_sigma)
        self.gain_override = dict(gain_override or {})
        unknown = set(self.gain_override) - set(cameras)
        if unknown:
            raise ValueError(f"gain_override names unknown cameras: {', '.join(sorted(unknown))}")
        self.scene = Scene()
        # camera id -> (scene, camera model, blur, lighting, clean image): the latest still
        # scene's clean image, so that a burst of frames renders it once (render_clean)
        self._clean: dict[str, tuple] = {}

    @classmethod
    def from_config(cls, config, noise_sigma: float | None = None,
                    gain_override: dict[str, float] | None = None, body: bool = True,
                    supersample: int = 34) -> "SimWorld":
        """The true station for ``config``. noise_sigma: grey levels (default from the config);
        gain_override: {camera id: factor} (0.8 = a camera 20 % darker); body: draw the car's
        body around the wheels (False: four wheels alone, as in a bare test scene);
        supersample: samples per edge pixel near measured features (34: ~1/68 px; fewer is
        faster and coarser, 1 switches anti-aliasing off)."""
        rng = np.random.default_rng(config.simulation.station_seed)
        cameras, blur = {}, {}
        for cam_id, cam in config.cameras.items():
            nom = cam.nominal
            cameras[cam_id] = perturbed_camera(cam_id, cam.width, cam.height, nom.position_m,
                                               nom.look_at_m, nom.focal_px, rng)
            blur[cam_id] = float(rng.uniform(0.6, 0.9))
        return cls(config, cameras, blur, noise_sigma, gain_override, body, supersample)

    def fingerprint(self) -> str:
        """16 hex digits naming what every image depends on besides the scene and the noise
        draw: each true camera (size, K, distortion, pose) and its blur, the sensor noise, the
        gains, the body and the supersampling. Caches of rendered images keyed by seed keep it
        and render again where it differs: images rendered for another camera layout, lens or
        station seed are never measured as if they were this station's."""
        parts = []
        for cam_id in sorted(self.cameras):
            m = self.cameras[cam_id]
            parts.append([cam_id, m.width, m.height, *np.round(m.K.ravel(), 9), *np.round(m.dist, 12),
                          *np.round(m.R_cam_station.ravel(), 12), *np.round(m.t_cam_station, 12),
                          round(self.blur_sigma[cam_id], 12), self.gain_override.get(cam_id, 1.0)])
        parts.append([self.noise_sigma, self.body, self.supersample])
        return hashlib.sha1(json.dumps(parts, default=float).encode()).hexdigest()[:16]

    # --- scenes -----------------------------------------------------------------------------
    def set_scene(self, scene: Scene) -> None:
        self.scene = scene

    def lighting_for(self, cam_id: str, scene: Scene | None = None) -> Lighting:
        scene = scene or self.scene
        lighting = scene.lighting.get(cam_id, Lighting())
        if cam_id in self.gain_override:
            lighting = replace(lighting, gain=lighting.gain * self.gain_override[cam_id])
        return lighting

    def random_lighting(self, rng: np.random.Generator) -> dict[str, Lighting]:
        """Per-camera lighting: each camera's illuminator, exposure and lens differ."""
        out = {}
        for cam_id, cam in self.cameras.items():
            target = np.asarray(self.config.cameras[cam_id].nominal.look_at_m, float)
            if rng.uniform() < 0.7:   # a lamp near the camera bar, above or beside it
                lamp = cam.center_station + np.array([0.0, rng.uniform(-0.8, 0.8), rng.uniform(0.3, 1.5)])
            else:                     # the workshop's ceiling light
                lamp = target + np.array([rng.uniform(-1.5, 1.5), rng.uniform(-2, 2), 3.0])
            direction = target - lamp
            out[cam_id] = Lighting(
                ambient=float(rng.uniform(0.2, 0.45)),
                key_direction_station=tuple(float(x) for x in direction / np.linalg.norm(direction)),
                key_strength=float(rng.uniform(0.45, 0.95)),
                gain=float(rng.uniform(0.8, 1.15)),
                vignetting=float(rng.uniform(0.1, 0.4)),
                background_level=float(rng.uniform(0.3, 0.6)))
        return out

    def vehicle_scene(self, seed: int, **overrides) -> Scene:
        """A random vehicle (around the configured nominal one) under random per-camera light.

        Its front wheels' kingpins are random (simulators.vehicle.random_kingpins), and so is
        each rim's runout up to ``simulation.runout_max_deg`` (0: square rims), each from a
        stream of its own, so that the rest of the vehicle stays that of the seed.
        overrides: Vehicle fields (toe_deg=..., yaw_deg=..., runout=...), WheelGeometry fields
        (rim_radius_m=...), or ``lighting`` / ``quads`` / ``floor_z_m`` / ``appearance`` for the Scene.
        """
        rng = np.random.default_rng(seed)
        nominal = self.config.nominal_vehicle
        vehicle = random_vehicle(rng, nominal_wheelbase_m=nominal.wheelbase_m, nominal_track_m=nominal.track_m)
        lighting = self.random_lighting(rng)
        kingpins, ackermann = random_kingpins(np.random.default_rng([seed, 33]))
        vehicle = replace(vehicle, kingpin=kingpins, ackermann=ackermann)
        runout_max = float(getattr(self.config.simulation, "runout_max_deg", 0.0))
        if runout_max > 0:
            vehicle = replace(vehicle, runout=random_runout(np.random.default_rng([seed, 32]), runout_max))
        v_over = {k: v for k, v in overrides.items() if k in _VEHICLE_FIELDS}
        w_over = {k: v for k, v in overrides.items() if k in _WHEEL_FIELDS}
        s_over = {k: v for k, v in overrides.items() if k in ("lighting", "quads", "floor_z_m", "appearance")}
        unknown = set(overrides) - set(v_over) - set(w_over) - set(s_over)
        if unknown:
            raise ValueError(f"vehicle_scene: unknown override(s) {', '.join(sorted(unknown))}; "
                             "expected Vehicle or WheelGeometry fields, lighting, quads, floor_z_m or appearance")
        if w_over:
            v_over["wheel"] = replace(vehicle.wheel, **w_over)
        for key in ("toe_deg", "camber_deg", "spin_phase_deg"):
            if key in v_over and not isinstance(v_over[key], dict):
                v_over[key] = {w: float(v_over[key]) for w in ("FL", "FR", "RL", "RR")}
        vehicle = replace(vehicle, **v_over)
        return Scene(vehicle=vehicle, quads=s_over.get("quads", ()), floor_z_m=s_over.get("floor_z_m", 0.0),
                     lighting=s_over.get("lighting", lighting), appearance=s_over.get("appearance", Appearance()))

    # --- images -----------------------------------------------------------------------------
    def render(self, cam_id: str, rng: np.random.Generator | None = None, scene: Scene | None = None,
               exposure: float = 1.0) -> np.ndarray:
        """(H,W) uint8 image of the current scene (or ``scene``) from camera ``cam_id``.

        rng: the sensor-noise stream; default one seeded by (station_seed, camera index).
        exposure: the exposure time as a factor of the camera's own (the light scales with it,
        the read noise does not).
        """
        if cam_id not in self.cameras:
            raise KeyError(f"no camera {cam_id!r} in this station; cameras: {', '.join(self.cameras)}")
        scene = scene or self.scene
        if rng is None:
            rng = np.random.default_rng([self.config.simulation.station_seed, list(self.cameras).index(cam_id)])
        clean = self.clean_image(cam_id, scene)
        return sensor_frame(clean if exposure == 1.0 else clean * np.float32(exposure), rng, self.noise_sigma)

    def clean_image(self, cam_id: str, scene: Scene | None = None) -> np.ndarray:
        """(H,W) float32: what camera ``cam_id`` receives of the scene before read noise and
        quantisation. Rendered once per still scene and camera (a burst of frames of a car on
        the lift differs only in its sensor noise); the same as ``render`` computed it inline."""
        scene = scene or self.scene
        cam, blur, lighting = self.cameras[cam_id], self.blur_sigma[cam_id], self.lighting_for(cam_id, scene)
        kept = self._clean.get(cam_id)
        if kept is not None and kept[0] is scene and kept[1] is cam and kept[2] == blur and kept[3] == lighting:
            return kept[4]
        clean = render_clean(cam, scene, lighting, blur, supersample=self.supersample, body=self.body)
        self._clean[cam_id] = (scene, cam, blur, lighting, clean)
        return clean

    def render_all(self, rng: np.random.Generator | None = None, scene: Scene | None = None) -> dict[str, np.ndarray]:
        """{camera id: image} for every camera; one child noise stream per camera."""
        rng = rng if rng is not None else np.random.default_rng(self.config.simulation.station_seed)
        streams = rng.spawn(len(self.cameras))
        return {cam_id: self.render(cam_id, s, scene) for cam_id, s in zip(self.cameras, streams)}

    # --- ground truth -----------------------------------------------------------------------
    def truth(self, scene: Scene | None = None) -> dict:
        """vehicle.truth() (if any) plus the true cameras, their blur and lighting."""
        scene = scene or self.scene
        out = scene.vehicle.truth() if scene.vehicle is not None else {}
        out["cameras"] = {cam_id: cam.to_dict() for cam_id, cam in self.cameras.items()}
        out["simulation"] = {
            "station_seed": int(self.config.simulation.station_seed),
            "noise_sigma": self.noise_sigma,
            "blur_sigma_px": dict(self.blur_sigma),
            "lighting": {cam_id: asdict(self.lighting_for(cam_id, scene)) for cam_id in self.cameras},
        }
        if scene.appearance != Appearance():
            out["simulation"]["appearance"] = asdict(scene.appearance)
        return out
