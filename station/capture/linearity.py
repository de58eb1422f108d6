"""Is a camera's grey proportional to light? Its burst's noise tells (the photon transfer
test of EMVA 1288, the machine-vision cameras' standard).

The rim edge model takes grey proportional to light; a camera that encodes its grey with a
gamma (an sRGB webcam, a GenICam ``Gamma`` or LUT left on) and is not configured so
(``cameras.<id>.response_gamma``) moves every rim edge toward the tyre by about a third of its
blur: 17 of 40 wheels silently off by up to 0.08 deg on the simulator (docs/accuracy.md,
``gamma``). A linear sensor's temporal noise never falls as the light grows: its read noise
stays and its shot noise grows with the square root of the light. A compressive encoding read
as linear makes it fall: with the light L and the noise in grey levels g = L^gamma,
std_g ~ L^(gamma - 1) std_L. So the noise of a burst (``frame_average.noise_by_level``), its
configured response undone, is fitted as a power of the light: slope 0 (read noise) to 0.5
(shot noise) for a linear camera; an sRGB camera (gamma 0.45) read as linear gives -1.2 (read
noise) to -0.1 (shot noise), so this catches it where read noise has its share (a camera at
high gain or in a dim bay), and says nothing where shot noise dominates.
"""

from __future__ import annotations

import numpy as np

from station.capture.frame_average import FULL_SCALE_16, NOISE_KEY, SCALE_8_TO_16

LEVELS = (0.04, 0.9)     # of full scale: the bins judged (clipped at black, near the white)
MIN_STD_GREY = 0.6       # a bin's noise at least this (8-bit grey levels): below, quantisation is most of it
MIN_LIGHT_RATIO = 1.8    # the bins judged must span this ratio of light (an sRGB camera read as linear
#                          shows a 5x range of light as 2x: its grey)
FALLING_SLOPE = -0.3     # d log(noise) / d log(light) below this: the noise falls with the light


def noise_slope(noise_by_level: list, response_gamma: float) -> float | None:
    """The slope of log(noise) against log(light) over the bins ``noise_by_level`` ([[level,
    std], ...] on the 16-bit scale) with ``response_gamma`` undone, or None where too few bins
    can be judged (``LEVELS``, ``MIN_STD_GREY``, ``MIN_LIGHT_RATIO``)."""
    if not noise_by_level:
        return None
    level, std = np.asarray(noise_by_level, float).T               # (B,) each
    g = level / FULL_SCALE_16
    keep = (g >= LEVELS[0]) & (g <= LEVELS[1]) & (std >= MIN_STD_GREY * SCALE_8_TO_16)
    if keep.sum() < 3:
        return None
    g, std = g[keep], std[keep] / FULL_SCALE_16
    light = g ** (1.0 / response_gamma)                              # the configured response undone
    std_light = std * light / (response_gamma * g)                   # d light / d g = light / (gamma g)
    if light.max() / light.min() < MIN_LIGHT_RATIO:
        return None
    return float(np.polyfit(np.log(light), np.log(std_light), 1)[0])


def response_warnings(frames: dict, config) -> list[tuple[str, str]]:
    """[(camera id, the warning's sentence)] for each camera of ``frames`` ({id: Frame}) whose
    burst's noise falls with the light once its configured response is undone."""
    out = []
    for cid, frame in frames.items():
        levels = frame.metadata.get(NOISE_KEY)
        if cid not in config.cameras or not levels:
            continue
        gamma = config.cameras[cid].response_gamma
        slope = noise_slope(levels, gamma)
        if slope is not None and slope < FALLING_SLOPE:
            out.append((cid, f"{cid}: its noise falls as its light grows (slope {slope:+.2f}; a linear camera's "
                             f"lies between 0 and +0.5): its grey is not proportional to light as configured "
                             f"(response_gamma {gamma:g}): a gamma or a LUT is on, as on an sRGB webcam. Its rim "
                             f"edges lie toward the tyre and its wheel's angles may be off unwarned: switch the "
                             f"camera to linear grey, or set cameras.{cid}.response_gamma to the exponent it "
                             f"applies (0.45 for sRGB)"))
    return out
