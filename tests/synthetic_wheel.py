"""Synthetic wheel photographs with a known rim ellipse (for tests and benchmarks only).

The rim-flange edge and the tyre outline are drawn with exact area coverage of the pixel
(a linear ramp over the signed distance, then a Gaussian lens blur), so the true edge is the
50 % level of the step at the ellipse: an unbiased ground truth for sub-pixel tests. The rest
(spokes, hub, brake disc, clutter, glare, uneven light, noise) is there to confuse the detector.
Runtime code never imports this module.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from station.rim.ellipse import Ellipse


@dataclass(frozen=True)
class WheelSpec:
    center_px: tuple[float, float] = (640.3, 512.7)
    rim_a_px: float = 300.0
    axis_ratio: float = 1.0          # b / a
    angle_rad: float = 0.3
    tyre_scale: float = 1.5          # tyre outline / rim flange
    tyre_level: float = 35.0
    rim_level: float = 190.0
    face_level: float = 150.0        # spokes and hub
    window_level: float = 45.0       # between spokes
    disc_level: float = 95.0         # brake disc seen through the windows
    background_level: float = 120.0
    spokes: int = 5
    blur_sigma_px: float = 0.8
    noise_sigma: float = 2.0
    clutter: int = 12
    glare: bool = True
    light_gradient: float = 0.35     # relative brightness change across the image


def _coverage(e: Ellipse, uu: np.ndarray, vv: np.ndarray) -> np.ndarray:
    """Area coverage (0..1) of each pixel by the filled ellipse (exact distance near the edge)."""
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1)
    rr = e.radius_ratio(pts)
    cov = (rr < 1).astype(np.float32)
    band = np.nonzero(np.abs(rr - 1) * e.axes_px[1] < 3)[0]
    d, _ = e.distance(pts[band], iterations=5)
    cov[band] = np.clip(0.5 - d, 0, 1)
    return cov.reshape(uu.shape)


def _wheel_polar(e: Ellipse, uu: np.ndarray, vv: np.ndarray):
    """Wheel-plane polar coordinates (r in units of the rim radius, phi) of every pixel."""
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1)
    le = e.to_local(pts)
    x, y = le[:, 0] / e.axes_px[0], le[:, 1] / e.axes_px[1]
    return np.hypot(x, y).reshape(uu.shape), np.arctan2(y, x).reshape(uu.shape)


def render_wheel(spec: WheelSpec, shape: tuple[int, int] = (1024, 1280), seed: int = 0,
                 extra: list[WheelSpec] | None = None) -> tuple[np.ndarray, Ellipse]:
    """(H,W) uint8 image and the true rim-flange ellipse. ``extra``: more wheels (no truth)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.full(shape, spec.background_level, np.float32)
    # clutter: random rectangles and thick lines (floor marks, lift, tools)
    for _ in range(spec.clutter):
        p = rng.uniform([0, 0], [w, h])
        q = p + rng.uniform(-250, 250, 2)
        level = float(rng.uniform(20, 230))
        if rng.random() < 0.5:
            cv2.rectangle(img, tuple(int(x) for x in p), tuple(int(x) for x in q), level, -1, cv2.LINE_AA)
        else:
            cv2.line(img, tuple(int(x) for x in p), tuple(int(x) for x in q), level, int(rng.integers(2, 12)), cv2.LINE_AA)
    truth = None
    for k, s in enumerate([spec] + list(extra or [])):
        rim = Ellipse(s.center_px, (s.rim_a_px, s.rim_a_px * s.axis_ratio), s.angle_rad)
        if k == 0:
            truth = rim
        tyre = Ellipse(rim.center_px, rim.axes_px * s.tyre_scale, rim.angle_rad)
        r, phi = _wheel_polar(rim, uu, vv)
        c_tyre = _coverage(tyre, uu, vv)
        c_rim = _coverage(rim, uu, vv)
        # tyre: dark, a little radial shading and lettering-like texture on the sidewall
        tyre_tex = s.tyre_level * (1 + 0.15 * np.cos(3 * phi) * np.clip((r - 1.1) / 0.3, 0, 1))
        img = img * (1 - c_tyre) + tyre_tex * c_tyre
        # rim face: flange lip (r > 0.93), then spokes / windows / disc / hub
        spoke_phase = float(rng.uniform(0, 2 * np.pi))
        dphi = (phi - spoke_phase) % (2 * np.pi / s.spokes) - np.pi / s.spokes
        half_w = 0.09 + 0.05 * (1 - r)  # spokes widen toward the hub
        spoke = np.clip((half_w - np.abs(r * np.sin(dphi))) * rim.axes_px[1] + 0.5, 0, 1)
        disc = np.clip((0.72 - r) * rim.axes_px[1] + 0.5, 0, 1)
        window = s.window_level * (1 - disc) + s.disc_level * disc
        face = window * (1 - spoke) + s.face_level * spoke
        hub = np.clip((0.22 - r) * rim.axes_px[1] + 0.5, 0, 1)
        face = face * (1 - hub) + (s.face_level + 20) * hub
        lip = np.clip((r - 0.93) * rim.axes_px[1] + 0.5, 0, 1)
        face = face * (1 - lip) + s.rim_level * (1 + 0.08 * np.cos(phi - 1.0)) * lip
        img = img * (1 - c_rim) + face * c_rim
        if s.glare:  # a specular highlight on the rim face
            gc = rim.point_at(np.array([rng.uniform(0, 2 * np.pi)]))[0] * 0.35 + rim.center_px * 0.65
            img += 60 * np.exp(-((uu - gc[0]) ** 2 + (vv - gc[1]) ** 2) / (2 * (0.12 * s.rim_a_px) ** 2)) * c_rim
    # uneven light: a smooth multiplicative gradient
    g = 1 + spec.light_gradient * ((uu / w - 0.5) * 0.8 + (vv / h - 0.5) * 0.6)
    img *= g
    if spec.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), spec.blur_sigma_px)
    img += rng.normal(0, spec.noise_sigma, img.shape).astype(np.float32)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), truth


def random_spec(rng: np.random.Generator, shape: tuple[int, int] = (1024, 1280)) -> WheelSpec:
    """A random wheel within a station camera's range of views (for accuracy benchmarks)."""
    h, w = shape
    a = float(rng.uniform(0.22, 0.32) * h)
    return WheelSpec(center_px=(float(w / 2 + rng.uniform(-80, 80)), float(h / 2 + rng.uniform(-60, 60))),
                     rim_a_px=a, axis_ratio=float(rng.choice([rng.uniform(0.97, 1.0), rng.uniform(0.82, 0.92)])),
                     angle_rad=float(rng.uniform(-np.pi / 2, np.pi / 2)),
                     tyre_scale=float(rng.uniform(1.35, 1.6)), tyre_level=float(rng.uniform(20, 50)),
                     rim_level=float(rng.uniform(130, 220)), face_level=float(rng.uniform(110, 200)),
                     window_level=float(rng.uniform(20, 70)), disc_level=float(rng.uniform(60, 130)),
                     background_level=float(rng.uniform(70, 200)), spokes=int(rng.integers(4, 11)),
                     blur_sigma_px=float(rng.uniform(0.6, 1.2)), noise_sigma=2.0,
                     clutter=int(rng.integers(0, 20)), glare=bool(rng.random() < 0.5),
                     light_gradient=float(rng.uniform(0, 0.5)))
