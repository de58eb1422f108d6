"""Scenarios of bench/accuracy.py outside the random vehicles' envelope (not in "all").

Each probes one way a real station may differ from the simulated one. The vehicle is always
that of the seed; what the scenario changes comes from its own random stream, so one seed
gives the same car in every scenario:

- big-angles: toe and camber within +/-5 deg;
- odd-rims: 14, 20, 21 and 22-inch rims, 70-150 mm of sidewall;
- odd-body: wheelbase +/-0.2 m, tracks +/-0.08 m, offset +/-0.1 m, yaw +/-2 deg;
- soft-focus: every lens a little out of focus, PSF sigma 1.3-2.0 px (the station's: 0.6-0.9);
- narrow-lip: a rim flange lip 4-8 mm wide (8-16 mm), shaded as rounded across all of it;
- big-bulge: the tyre's sidewall standing 30-45 mm beyond the flange (10-30 mm);
- bright-tyre: tyre albedo 0.2-0.3 (0.05-0.18): a worn or dusty tyre;
- harsh-light: ambient 0.05-0.12 (0.2-0.45) and a key light 1.0-1.4 (0.45-0.95): one strong
  workshop lamp, deep shadows;
- diffuse-light: ambient 0.45-0.75 and a key light 0-0.15: the wheel lit by diffuse panels
  round it (as docs/accuracy.md recommends), what is left of a lamp's direction faint;
- vignette: lens vignetting 0.6-0.8 (0.1-0.4);
- gamma: every camera encodes its grey levels with gamma 1/2.2 (an sRGB webcam), not linearly,
  and the station is not told; gamma-known: the same images, the station configured with
  ``response_gamma`` (station/rim/camera_response.py).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibration.station_frame import WHEELS
from simulators.vehicle import Runout

SOFT_FOCUS_PX = (1.3, 2.0)
GAMMA = 1 / 2.2


def _geometry_overrides(kind: str, seed: int, nominal) -> dict:
    """vehicle_scene overrides of the first three scenarios (their stream: [seed, 77])."""
    r = np.random.default_rng([seed, 77])
    if kind == "big-angles":
        return {"toe_deg": {w: float(r.uniform(-5, 5)) for w in WHEELS},
                "camber_deg": {w: float(r.uniform(-5, 5)) for w in WHEELS}}
    if kind == "odd-rims":
        rim_r = float(r.choice([14, 20, 21, 22])) * 0.0254 / 2 + 0.0125
        return {"rim_radius_m": rim_r, "tyre_radius_m": rim_r + float(r.uniform(0.07, 0.15))}
    return {"wheelbase_m": nominal.wheelbase_m + float(r.uniform(-0.2, 0.2)),
            "track_front_m": nominal.track_m + float(r.uniform(-0.08, 0.08)),
            "track_rear_m": nominal.track_m + float(r.uniform(-0.08, 0.08)),
            "position_m": (float(r.uniform(-0.1, 0.1)), float(r.uniform(-0.1, 0.1))), "yaw_deg": float(r.uniform(-2, 2))}


WHEEL_RANGES = {"narrow-lip": ("flange_width_m", (0.004, 0.008)),
                "big-bulge": ("sidewall_bulge_m", (0.030, 0.045)),
                "bright-tyre": ("tyre_albedo", (0.2, 0.3))}
LIGHT_RANGES = {"harsh-light": {"ambient": (0.05, 0.12), "key_strength": (1.0, 1.4)},
                "diffuse-light": {"ambient": (0.45, 0.75), "key_strength": (0.0, 0.15)},
                "vignette": {"vignetting": (0.6, 0.8)}}
KINDS = ("big-angles", "odd-rims", "odd-body", "soft-focus", *WHEEL_RANGES, *LIGHT_RANGES, "gamma", "gamma-known")


def scene_for(world, kind: str | None, seed: int, nominal, **overrides):
    """The scene of vehicle ``seed`` in scenario ``kind`` (any other name, or None: the random
    vehicle as it is), and the world's lenses set for it (every camera's own PSF unless
    soft-focus). The other functions below take any scenario name the same way."""
    if not hasattr(world, "_own_blur"):
        world._own_blur = dict(world.blur_sigma)
    world.blur_sigma.update(world._own_blur)
    if kind in ("big-angles", "odd-rims", "odd-body"):
        overrides.update(_geometry_overrides(kind, seed, nominal))
    r = np.random.default_rng([seed, 123])
    if kind in WHEEL_RANGES:
        name, span = WHEEL_RANGES[kind]
        overrides[name] = float(r.uniform(*span))
    overrides.setdefault("runout", {w: Runout() for w in WHEELS})  # the rim planes: runout is bench/runout.py's
    scene = world.vehicle_scene(seed, **overrides)
    if kind in LIGHT_RANGES:
        scene = replace(scene, lighting={c: replace(light, **{k: float(r.uniform(*span)) for k, span in LIGHT_RANGES[kind].items()})
                                         for c, light in scene.lighting.items()})
    if kind == "soft-focus":
        rb = np.random.default_rng([seed, 99])
        for cam in world.blur_sigma:
            world.blur_sigma[cam] = float(rb.uniform(*SOFT_FOCUS_PX))
    return scene


def images_of(scenario: str) -> str:
    """The scenario whose images this one measures (and caches under its name)."""
    return "gamma" if scenario == "gamma-known" else scenario


def configured(kind: str | None, config):
    """The station's configuration for the scenario: gamma-known tells it its cameras' gamma."""
    if kind != "gamma-known":
        return config
    import copy
    out = copy.copy(config)
    out.cameras = {c: replace(cam, response_gamma=GAMMA) for c, cam in config.cameras.items()}
    return out


def encode(kind: str | None, images: dict) -> dict:
    """The images as the scenario's cameras deliver them (gamma: sRGB-like encoding)."""
    if kind not in ("gamma", "gamma-known"):
        return images
    lut = np.clip(np.round(255 * (np.arange(256) / 255) ** GAMMA), 0, 255).astype(np.uint8)
    return {c: lut[im] for c, im in images.items()}
