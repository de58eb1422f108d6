"""Images damaged after the scene: what a camera, its cable or the shop does to a good frame.

The simulator renders a clean scene through a modelled sensor; real frames also arrive with a
hand or a hose in front of the rim, a camera knocked off its mount, an exposure set too long,
a lens out of focus, lines lost in transfer. ``damage(image, kind, rng)`` applies one of
``KINDS`` to a grey uint8 image (H,W); bench/perturbed_images.py measures what the station
reports for each, tests/test_image_damage.py that it never ends in a traceback.

Each kind is a fixed, plausible severity with a random placement (``rng``), not a sweep.
"""

from __future__ import annotations

import cv2
import numpy as np


def _occluder(im, rng):
    """A dark or bright bar across part of the picture (an arm, an air hose, a cable)."""
    h, w = im.shape
    p = rng.uniform([0.3 * w, 0.3 * h], [0.7 * w, 0.7 * h])
    d = rng.normal(size=2)
    d *= rng.uniform(150, 400) / np.linalg.norm(d)
    cv2.line(im, tuple(int(v) for v in p - d), tuple(int(v) for v in p + d), float(rng.choice([20.0, 200.0])),
             int(rng.integers(15, 40)), cv2.LINE_AA)
    return im


def _knocked(im, rng):
    """The camera moved on its mount after calibration: the picture shifts by 6-15 px."""
    h, w = im.shape
    d = rng.normal(size=2)
    d *= rng.uniform(6, 15) / np.linalg.norm(d)
    return cv2.warpAffine(im, np.float32([[1, 0, d[0]], [0, 1, d[1]]]), (w, h), borderMode=cv2.BORDER_REPLICATE)


def _lost_lines(im, rng):
    """A block of lines lost in transfer (zeros), as a GigE stream with dropped packets."""
    h, _ = im.shape
    y0 = int(rng.integers(0, h - 60))
    im[y0:y0 + int(rng.integers(20, 60))] = 0
    return im


KINDS = {
    # name: (what it stands for, function of (float image 0..255, rng) -> float image)
    "occluder": ("an arm or a hose in front of the wheel", _occluder),
    "knocked": ("a camera moved 6-15 px after calibration", _knocked),
    "over-exposed": ("exposure 2x too long", lambda im, rng: im * 2.0),
    "gamma": ("an sRGB-like response (gamma 0.45) not configured", lambda im, rng: 255.0 * (im / 255.0) ** 0.45),
    "soft-focus": ("a lens out of focus (Gaussian blur 2 px)", lambda im, rng: cv2.GaussianBlur(im, (0, 0), 2.0)),
    "noisy": ("a dim shop at high gain (noise sigma 10 grey levels)",
              lambda im, rng: im + rng.normal(0.0, 10.0, im.shape)),
    "uneven-light": ("a lamp to one side (brightness 0.4-1.4 across the picture)",
                     lambda im, rng: im * np.linspace(0.4, 1.4, im.shape[1])[None, :]),
    "hot-pixels": ("0.5 % of the pixels stuck at black or white",
                   lambda im, rng: np.where(rng.random(im.shape) < 0.005, rng.choice([0.0, 255.0], im.shape), im)),
    "lost-lines": ("20-60 lines lost in transfer", _lost_lines),
}


def damage(image: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    """``image`` (H,W) uint8 grey with the damage ``kind`` (one of KINDS), uint8 again."""
    if kind not in KINDS:
        raise ValueError(f"unknown damage {kind!r}: expected one of {', '.join(KINDS)}")
    out = KINDS[kind][1](image.astype(np.float32), rng)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)
