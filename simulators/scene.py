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
class Appearance:
    """How a scenario's wheels, body and cameras look beyond the random vehicle; the defaults
    render the random vehicles exactly (bench/rim_scenarios.py sets the others).

    Albedos and reflectances 0..1, lengths in metres, angles in radians in the wheel frame
    (docs/conventions.md: from the wheel's u axis, spoke 0, about its outward axis w).
    """

    # rim finish of the lip, barrel and spokes (None: the vehicle's own, render_wheel.wheel_finish)
    rim_specular: float | None = None   # Phong strength
    rim_shininess: float = 24.0         # Phong exponent
    rim_mirror: float = 0.0             # reflectance of the workshop at normal incidence (Schlick
                                        # Fresnel: more at grazing angles); chrome ~0.9, clear coat ~0.05
    surround: float = 0.0               # what the rim's metal mirrors: 0 the workshop (lamps, windows,
                                        # floor); > 0 the station's diffuse light panels round the
                                        # wheel, a smooth surround of this radiance (+/-20 % top to bottom)
                                        # with a dark slot at the cameras' height (shading.mirror_reflection)
    spoke_albedo: float | None = None   # None: the vehicle's own
    # brake dust (a span of the lip's arc) and dirt (blotches) on the lip
    dust: float = 0.0                   # weight of dust_albedo at the span's middle (0: no dust)
    dust_albedo: float = 0.25
    dust_center_rad: float = 0.0
    dust_span_rad: float = 2.0          # full angular width of the dusted span
    dirt: float = 0.0                   # darkening of the lip inside the blotches (0: clean)
    dirt_seed: int = 0
    # tyre: lettering (letter_albedo 0: the tyre's own rule) in a radial band given as fractions
    # of the sidewall height above the flange edge; a protector rib standing off the sidewall
    letter_albedo: float = 0.0
    letter_band: tuple[float, float] = (0.4, 0.62)
    ridge_height_m: float = 0.0         # 0: no rib
    ridge_offset_m: float = 0.008       # its inner foot this far beyond the flange edge (radially)
    ridge_width_m: float = 0.008
    # light on the wheel and the body: the arch's shadow over the wheel (None: none), its
    # boundary a line across the wheel plane ``shadow_height`` x rim radius above the centre,
    # turned by ``shadow_tilt_rad``, soft over ``shadow_soft_m``: the key light fades to nothing
    # above it; the gloss paint's reflection of the workshop
    shadow_height: float | None = None
    shadow_tilt_rad: float = 0.0
    shadow_soft_m: float = 0.01
    body_mirror: float = 0.0
    # the camera: veiling glare (this share of the image's widely blurred light added) and
    # auto exposure (0: the lighting's fixed gain; else the gain that puts the image's
    # ``auto_exposure_percentile`` at this grey level)
    veiling_glare: float = 0.0
    auto_exposure: float = 0.0
    auto_exposure_percentile: float = 99.5


@dataclass(frozen=True)
class Scene:
    vehicle: Vehicle | None = None
    quads: tuple[TexturedQuad, ...] = ()
    floor_z_m: float = 0.0
    lighting: dict = field(default_factory=dict)  # camera id -> Lighting (missing: Lighting())
    appearance: Appearance = field(default_factory=Appearance)
