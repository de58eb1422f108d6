"""Every rim a shop sees (issue 37): named scenarios of bench/accuracy.py (not in "all").

Each is the seed's random vehicle (square rims, as bench/outside_envelope.py's) with one thing
changed, drawn per vehicle from the scenario's own stream ([seed, 137]; the sun's from
[seed, 138], so both sun scenarios have the same sun): one seed is the same car in every
scenario. Ranges are uniform; the random vehicles' own values in brackets. Albedo: the lip's
and spokes' (rim_albedo, spoke_albedo); finish: Phong strength and exponent of the metal and
its mirror reflectance of the workshop at normal incidence (simulators.scene.Appearance).

- silver: the random vehicle as it is (rim albedo 0.45-0.9, Phong 0.2-1.0, exponent 24, no
  mirror); its images are sigma2's;
- polished: albedo 0.7-0.85, Phong 0.8-1.0, exponent 60-120, mirror 0.25-0.45;
- gunmetal: albedo 0.22-0.38, Phong 0.3-0.6, exponent 16-40, mirror 0.02-0.06 (anthracite);
- gloss-black: albedo 0.03-0.06, Phong 0.5-1.0, exponent 80-200, mirror 0.04-0.07 (clear coat:
  the lip mirrors the dark floor on one arc, the ceiling's lights on another);
- matt-black: albedo 0.04-0.08, Phong 0.02-0.08, exponent 6-12, no mirror;
- chrome: albedo 0.05-0.12, Phong 1.0-1.5, exponent 200-400, mirror 0.8-0.95;
- brake-dust: dust of albedo 0.18-0.3 over 60-170 deg of the lip's arc (anywhere), 60-95 % of
  the lip's colour replaced at the span's middle, its shine gone;
- dirt: blotches 15-50 mm across over the lip, 40-75 % darker inside;
- tyre-lettering: bright letters (albedo 0.55-0.85 [0.12-0.43]) in a band starting 6-15 % of
  the sidewall height beyond the lip [40 %], 15-25 % high [22 %];
- protector-ridge: a rib round the tyre 3-8 mm proud of the sidewall, its foot 5-12 mm beyond
  the lip, 6-12 mm wide;
- low-contrast: rim albedo 0.15-0.3, tyre albedo 0.75-1.0 x the rim's (a grey, dusty tyre);
- arch-shadow: harsh light (ambient 0.05-0.15 [0.2-0.45], key 1.0-1.5 [0.45-0.95]) and the
  arch's shadow over the wheel: the key light gone above a line -0.2..0.6 rim radii above the
  centre, tilted -25..25 deg, soft over 5-30 mm;
- sun-auto-exposure: a low sun through the door (one direction for all cameras, 5-20 deg
  above the horizon, from the front or rear +-50 deg), key 2.5-4.0, ambient 0.15-0.3, veiling
  glare 8-20 % of the light spread over a tenth of the frame; each camera on auto exposure (its
  99.5th percentile at grey 200-240);
- sun-fixed-exposure: the same sun with each camera's fixed gain: the lit lip goes to white;
- shop-reflections: gloss paint mirroring the workshop's lights in bands round the arches,
  reflectance 0.12-0.3;
- polished-, gunmetal-, gloss-black-, chrome-diffuse: those finishes with the station's
  diffuse light panels round each wheel: the metal mirrors a smooth surround of radiance
  0.3-0.6 (+/-20 % top to bottom, a dark slot at the cameras' height for them to look
  through) instead of the workshop's lamps, windows and floor; the light on the wheel as
  before.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bench import outside_envelope
from simulators.scene import Appearance

FINISHES = {  # Appearance ranges; rim_albedo (the vehicle's) and spoke_albedo drawn once for both
    "polished": {"rim_albedo": (0.7, 0.85), "rim_specular": (0.8, 1.0), "rim_shininess": (60, 120), "rim_mirror": (0.25, 0.45)},
    "gunmetal": {"rim_albedo": (0.22, 0.38), "rim_specular": (0.3, 0.6), "rim_shininess": (16, 40), "rim_mirror": (0.02, 0.06)},
    "gloss-black": {"rim_albedo": (0.03, 0.06), "rim_specular": (0.5, 1.0), "rim_shininess": (80, 200), "rim_mirror": (0.04, 0.07)},
    "matt-black": {"rim_albedo": (0.04, 0.08), "rim_specular": (0.02, 0.08), "rim_shininess": (6, 12)},
    "chrome": {"rim_albedo": (0.05, 0.12), "rim_specular": (1.0, 1.5), "rim_shininess": (200, 400), "rim_mirror": (0.8, 0.95)},
}
LOOKS = {  # Appearance ranges of the other scenarios (angles in rad)
    "brake-dust": {"dust": (0.6, 0.95), "dust_albedo": (0.18, 0.3), "dust_center_rad": (-np.pi, np.pi),
                   "dust_span_rad": (np.radians(60), np.radians(170))},
    "dirt": {"dirt": (0.4, 0.75)},
    "protector-ridge": {"ridge_height_m": (0.003, 0.008), "ridge_offset_m": (0.005, 0.012), "ridge_width_m": (0.006, 0.012)},
    "arch-shadow": {"shadow_height": (-0.2, 0.6), "shadow_tilt_rad": (np.radians(-25), np.radians(25)),
                    "shadow_soft_m": (0.005, 0.03)},
    "shop-reflections": {"body_mirror": (0.12, 0.3)},
}
SUN = {"elevation_deg": (5, 20), "azimuth_off_deg": (-50, 50), "key_strength": (2.5, 4.0), "ambient": (0.15, 0.3),
       "veiling_glare": (0.08, 0.2), "auto_exposure": (200, 240)}
UNDER_PANELS = {f"{k}-diffuse": k for k in ("polished", "gunmetal", "gloss-black", "chrome")}  # kind: its finish
PANEL_SURROUND = (0.3, 0.6)   # the panels' radiance, as the metal mirrors it
KINDS = ("silver", *FINISHES, "brake-dust", "dirt", "tyre-lettering", "protector-ridge", "low-contrast",
         "arch-shadow", "sun-auto-exposure", "sun-fixed-exposure", "shop-reflections", *UNDER_PANELS)


def _draw(r: np.random.Generator, ranges: dict) -> dict:
    return {k: float(r.uniform(*span)) for k, span in ranges.items()}


def _sun(seed: int) -> tuple[tuple[float, float, float], dict]:
    """The sun of vehicle ``seed``: the unit direction its light travels along (station frame)
    and the other draws of SUN."""
    s = _draw(np.random.default_rng([seed, 138]), SUN)
    side = 1.0 if np.random.default_rng([seed, 139]).uniform() < 0.5 else -1.0   # the door ahead or behind
    el = np.radians(s["elevation_deg"])
    az = np.radians(90.0 * side + s["azimuth_off_deg"])     # where the sun stands, seen from the car
    toward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return tuple(float(x) for x in -toward), s


def scene_for(world, kind: str, seed: int, nominal, **overrides):
    """The scene of vehicle ``seed`` in scenario ``kind`` (one of KINDS)."""
    if kind not in KINDS:
        raise ValueError(f"unknown rim scenario {kind!r}; known: {', '.join(KINDS)}")
    scene = outside_envelope.scene_for(world, None, seed, nominal, **overrides)
    if kind == "silver":
        return scene
    r = np.random.default_rng([seed, 137])
    wheel, look, light = {}, {}, {}
    if kind in FINISHES or kind in UNDER_PANELS:   # under the panels: the finish's own draws
        look = _draw(r, FINISHES[UNDER_PANELS.get(kind, kind)])
        wheel["rim_albedo"] = look.pop("rim_albedo")
        look["spoke_albedo"] = wheel["rim_albedo"]
        if kind in UNDER_PANELS:
            look["surround"] = float(np.random.default_rng([seed, 140]).uniform(*PANEL_SURROUND))
    elif kind in LOOKS:
        look = _draw(r, LOOKS[kind])
        if kind == "arch-shadow":
            light = _draw(r, {"ambient": (0.05, 0.15), "key_strength": (1.0, 1.5)})
        if kind == "dirt":
            look["dirt_seed"] = int(r.integers(1 << 30))
    elif kind == "tyre-lettering":
        s = _draw(r, {"letter_albedo": (0.55, 0.85), "band_start": (0.06, 0.15), "band_height": (0.15, 0.25)})
        look = {"letter_albedo": s["letter_albedo"], "letter_band": (s["band_start"], s["band_start"] + s["band_height"])}
    elif kind == "low-contrast":
        wheel["rim_albedo"] = float(r.uniform(0.15, 0.3))
        wheel["tyre_albedo"] = wheel["rim_albedo"] * float(r.uniform(0.75, 1.0))
    else:  # the sun
        direction, s = _sun(seed)
        light = {"key_direction_station": direction, "key_strength": s["key_strength"], "ambient": s["ambient"]}
        look = {"veiling_glare": s["veiling_glare"]}
        if kind == "sun-auto-exposure":
            look["auto_exposure"] = s["auto_exposure"]
    vehicle = replace(scene.vehicle, wheel=replace(scene.vehicle.wheel, **wheel)) if wheel else scene.vehicle
    lighting = {c: replace(l, **light) for c, l in scene.lighting.items()} if light else scene.lighting
    return replace(scene, vehicle=vehicle, lighting=lighting, appearance=replace(Appearance(), **look))


def images_of(kind: str) -> str:
    """The scenario whose cached images this one's are: silver renders exactly sigma2's."""
    return "sigma2" if kind == "silver" else kind
