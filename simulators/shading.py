"""Shared pieces of the ray tracer: the nearest-hit buffer, the lighting model, texture lookup.

Radiance units: a white (albedo 1) surface facing the key light head-on under ``Lighting()``
has radiance ``ambient + key_strength`` (1.1); the image is ``255 * gain * vignetting *
radiance``, so values above ~1 saturate (glare).
"""

from __future__ import annotations

import numpy as np

from simulators.scene import Lighting

# label blocks: a label change between neighbouring pixels marks an edge to supersample
LABEL_SKY = 0
LABEL_WALL = 10         # + face index (0..4)
LABEL_FLOOR = 20        # + floor region (0 concrete, 1 runway plate, 2 runway edge strip)
LABEL_BODY = 30         # + part of the vehicle body
LABEL_QUAD = 1000       # + quad index
LABEL_WHEEL = 100       # + 40 * wheel index + part


class Hits:
    """Nearest hit so far for N rays: t (N,) metres along the ray, label (N,), value (N,)."""

    def __init__(self, n: int):
        self.t = np.full(n, np.inf)
        self.label = np.zeros(n, np.int32)
        self.value = np.zeros(n, np.float32)

    def take(self, idx: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Boolean mask over idx: where the new hit ``t`` is nearer than the stored one."""
        return t < self.t[idx]

    def store(self, idx: np.ndarray, t: np.ndarray, label, value) -> None:
        self.t[idx] = t
        self.label[idx] = label
        self.value[idx] = value


def rowmat(a: np.ndarray, M: np.ndarray) -> np.ndarray:
    """(N,k) @ (k,m) for tall arrays without BLAS: a multi-threaded BLAS call on a busy machine
    costs ~30x more than this single-threaded einsum."""
    return np.einsum("ij,jk->ik", a, M)


def key_direction(lighting: Lighting) -> np.ndarray:
    """(3,) unit direction the key light travels along (station frame)."""
    L = np.asarray(lighting.key_direction_station, float)
    return L / np.linalg.norm(L)


def shade(albedo, normals: np.ndarray, dirs: np.ndarray, lighting: Lighting,
          specular=0.0, shininess=24.0, key_scale=None) -> np.ndarray:
    """Radiance (N,) float32 of surfaces with unit normals seen along unit rays, any one frame.

    normals: (N,3), (3,) or a tuple of three (N,) components; dirs: (N,3) or three (N,).

    Lambert ``albedo * (ambient + key * max(0, -n.L))`` plus a Phong lobe for metal,
    ``specular * key * max(0, R.(-d))^shininess`` with R the key direction mirrored at the
    surface. albedo, specular, shininess: scalars or (N,). key_scale: None, or a scalar or (N,)
    share of the key light reaching each point (0: in shadow, ambient only). Normals are
    flipped to face the camera.
    """
    L = key_direction(lighting)
    if isinstance(normals, tuple):         # components (nx, ny, nz), (N,) each
        nx, ny, nz = normals
    else:                                  # (N,3), or (3,): one normal for all
        normals = np.asarray(normals)
        nx, ny, nz = normals[..., 0], normals[..., 1], normals[..., 2]
    dx, dy, dz = dirs if isinstance(dirs, tuple) else (dirs[:, 0], dirs[:, 1], dirs[:, 2])
    ndotd = nx * dx + ny * dy + nz * dz
    # camera-facing normal: n.L flips sign with n (no BLAS calls: see rowmat)
    ndotl = np.copysign(1.0, -ndotd) * (nx * L[0] + ny * L[1] + nz * L[2])
    alb = np.asarray(albedo, np.float32)
    key = np.float32(lighting.key_strength)
    if key_scale is not None:
        key = key * np.asarray(key_scale, np.float32)
    value = alb * np.float32(lighting.ambient) + alb * key * np.maximum(0.0, -ndotl).astype(np.float32)
    if np.any(specular):
        # R.(-d) = -(L.d) + 2 (L.n)(n.d) with the camera-facing normal (n.d = -|n.d|)
        cos_r = np.maximum(0.0, -(dx * L[0] + dy * L[1] + dz * L[2]) - 2.0 * ndotl * np.abs(ndotd)).astype(np.float32)
        value = value + np.asarray(specular, np.float32) * key * cos_r ** np.asarray(shininess, np.float32)
    return value.astype(np.float32, copy=False)


def workshop_environment(rx: np.ndarray, ry: np.ndarray, rz: np.ndarray) -> np.ndarray:
    """Radiance (N,) float32 of the workshop seen from the car along unit directions (rx, ry, rz)
    (station frame, (N,) each), as a mirror-like surface reflects it: a dark floor (0.06), walls
    (0.25) with a band of windows and doors at eye height, one every 0.5 rad (up to 1.55), a ceiling (0.4) with rows
    of light tubes along y, one every 0.7 rad across (up to 2.4). Broad and smooth in the
    direction: a rounded lip turns its reflected ray by ~0.2 rad per pixel, so finer features
    would alias into slivers the renderer does not supersample."""
    rx, ry, rz = (np.asarray(c, np.float32) for c in (rx, ry, rz))
    up = np.clip((rz + 0.1) / 0.2, 0.0, 1.0)                  # floor -> walls
    ceiling = np.clip((rz - 0.3) / 0.25, 0.0, 1.0)            # walls -> ceiling
    along = np.arctan2(ry, np.abs(rx))                         # angle along the side walls
    windows = np.clip(1.0 - np.abs(rz - 0.16) / 0.15, 0.0, 1.0) * (0.5 + 0.5 * np.cos(2 * np.pi * along / 0.5)) ** 2
    walls = 0.25 + 1.3 * windows
    across = np.arctan2(rx, np.maximum(rz, 0.0))               # angle across the tube rows
    tubes = (0.5 + 0.5 * np.cos(2 * np.pi * across / 0.7)) ** 3
    top = 0.4 + 2.0 * tubes
    value = 0.06 + up * (walls - 0.06) + ceiling * (top - walls)
    return value.astype(np.float32)


def mirror_reflection(normals: tuple, dirs: tuple, R_station_frame: np.ndarray, reflectance,
                      surround: float = 0.0) -> np.ndarray:
    """(N,) float32 radiance the surfaces reflect of the workshop (:func:`workshop_environment`),
    or with ``surround`` > 0 of diffuse light panels round the wheel (radiance ``surround``,
    20 % more straight up and less straight down) with a slot at the cameras' height, level
    with the wheel, for them to look through (a dark band to about 0.1 rad above and below),
    by Schlick's Fresnel weight ``F = m + (1 - m) (1 - |n.d|)^5`` with m = ``reflectance``
    (scalar or (N,)). normals, dirs: three (N,) components each, unit, in a frame that
    R_station_frame (3,3) turns into the station frame."""
    nx, ny, nz = normals
    dx, dy, dz = dirs
    ndotd = nx * dx + ny * dy + nz * dz
    r = [d - 2.0 * ndotd * n for d, n in ((dx, nx), (dy, ny), (dz, nz))]
    R = R_station_frame
    rs = [R[k, 0] * r[0] + R[k, 1] * r[1] + R[k, 2] * r[2] for k in range(3)]
    m = np.asarray(reflectance, np.float32)
    fresnel = m + (1.0 - m) * (1.0 - np.minimum(np.abs(ndotd), 1.0)).astype(np.float32) ** 5
    if surround > 0:
        seen = surround * (1.0 + 0.2 * rs[2]) * (1.0 - 0.85 * np.exp(-(rs[2] / 0.1) ** 2))
    else:
        seen = workshop_environment(*rs)
    return (fresnel * seen).astype(np.float32)


def bilinear(texture: np.ndarray, s: np.ndarray, t: np.ndarray, wrap: bool = False) -> np.ndarray:
    """Sample a (h, w) texture at texel coordinates s (columns), t (rows), (N,) each.

    Texel (i, j) covers [j, j+1) x [i, i+1): (0, 0) is the texture's outer corner, texel
    centres are at half-integers. Clamped at the border, or wrapped (tiling) if ``wrap``.
    """
    h, w = texture.shape
    x = np.asarray(s, float) - 0.5
    y = np.asarray(t, float) - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0).astype(np.float32)
    fy = (y - y0).astype(np.float32)
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    if wrap:
        x0 %= w
        y0 %= h
        x1 = (x0 + 1) % w
        y1 = (y0 + 1) % h
    else:
        x1 = np.clip(x0 + 1, 0, w - 1)
        y1 = np.clip(y0 + 1, 0, h - 1)
        x0 = np.clip(x0, 0, w - 1)
        y0 = np.clip(y0, 0, h - 1)
    flat = texture.ravel()
    a = flat[y0 * w + x0].astype(np.float32)
    b = flat[y0 * w + x1].astype(np.float32)
    c = flat[y1 * w + x0].astype(np.float32)
    d = flat[y1 * w + x1].astype(np.float32)
    top = a + (b - a) * fx
    bottom = c + (d - c) * fx
    return top + (bottom - top) * fy


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, int]) -> np.ndarray:
    """Tileable band-limited noise, (h, w) float32 with zero mean and unit-ish std.

    A random (cells) grid upsampled bicubically with wrap-around (Fourier resampling).
    """
    h, w = shape
    coarse = rng.standard_normal(cells)
    spec = np.fft.fft2(coarse)
    full = np.zeros((h, w), complex)
    ch, cw = cells
    hh, hw = ch // 2, cw // 2
    full[:hh, :hw] = spec[:hh, :hw]
    full[:hh, -hw:] = spec[:hh, -hw:]
    full[-hh:, :hw] = spec[-hh:, :hw]
    full[-hh:, -hw:] = spec[-hh:, -hw:]
    out = np.fft.ifft2(full).real
    out /= out.std() + 1e-12
    return out.astype(np.float32)
