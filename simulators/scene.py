"""What stands in front of the simulated cameras: data, not code paths.

A :class:`Scene` is a vehicle (or none), textured planar quads (the calibration box's faces,
posters, ...) and the workshop. The renderer (simulators/render.py) draws any scene.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from simulators.vehicle import Vehicle


@dataclass(frozen=True)
class TexturedQuad:
    """A flat rectangle with a grey texture.

    corners_station: (4,3) metres, in texture order: texture (0,0) top-left, (w,0) top-right,
    (w,h) bottom-right, (0,h) bottom-left (a parallelogram: corner 3 = 0 + (2 - 1)).
    texture: (h, w) uint8, sampled bilinearly; albedo scales it (0..1).
    """

    corners_station: np.ndarray
    texture: np.ndarray
    albedo: float = 1.0


@dataclass(frozen=True)
class Lighting:
    """Per-camera lighting: ambient + a directional key light + vignetting + exposure gain."""

    ambient: float = 0.35
    key_direction_station: tuple[float, float, float] = (0.3, -0.4, -0.85)  # light travels along this
    key_strength: float = 0.75
    gain: float = 1.0            # exposure/aperture scale (a camera 20% darker: 0.8)
    vignetting: float = 0.25     # relative fall-off at the image corner
    background_level: float = 0.45


@dataclass(frozen=True)
class Scene:
    vehicle: Vehicle | None = None
    quads: tuple[TexturedQuad, ...] = ()
    floor_z_m: float = 0.0
    lighting: dict = field(default_factory=dict)  # camera id -> Lighting (missing: Lighting())
