"""Grey levels back to light: undoing a camera's gamma encoding before rim detection.

The sub-pixel edge model (station/rim/subpixel.py) takes grey levels proportional to light:
a blurred edge's 50 % level is then where the edge is. A camera that encodes its output with
a gamma (an sRGB webcam, a GenICam camera with ``Gamma`` < 1 or a LUT) bends the profile and
moves that level toward the dark tyre by about a third of the blur: on the simulator, toe RMS
0.025 -> 0.050 deg with a +0.02 deg bias (docs/rim-detection.md, "Known limits").
``cameras.<id>.response_gamma`` (or ``camera_defaults``) states the exponent the camera
applies, grey = light^gamma (1: linear, the default; 0.45 for sRGB-like); the images are
decoded with 1/gamma into 16-bit grey, so no dark level is lost to rounding. The captured images are kept as delivered.
"""

from __future__ import annotations

import numpy as np

from station.compute.bounded_cache import BoundedCache

_LUTS = BoundedCache(16)  # per gamma: the 8-bit lookup table to linear 16-bit grey


def _lut8(gamma: float) -> np.ndarray:
    return _LUTS.get(("u8", gamma), lambda: np.round(65535 * (np.arange(256) / 255.0) ** (1.0 / gamma)).astype(np.uint16))


def linear(image: np.ndarray, gamma: float) -> np.ndarray:
    """``image`` (uint8 / uint16 / float on 0..255, grey or colour) encoded with exponent
    ``gamma``, as grey levels proportional to light: uint16 for integer input (float stays
    float on 0..255). gamma 1 returns the image itself."""
    if gamma == 1.0:
        return image
    if image.dtype == np.uint8:
        return _lut8(gamma)[image]
    if image.dtype == np.uint16:
        return np.round(65535 * (image / 65535.0) ** (1.0 / gamma)).astype(np.uint16)
    return (255.0 * (np.clip(image, 0, 255) / 255.0) ** (1.0 / gamma)).astype(image.dtype)


def linear_images(images: dict, config) -> dict:
    """{camera id: image} with each camera's ``response_gamma`` undone (docs/configuration.md)."""
    return {c: linear(im, config.cameras[c].response_gamma) if c in config.cameras else im
            for c, im in images.items()}
