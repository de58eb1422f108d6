"""The workshop around the lift: floor with runway plates, walls with clutter, textured quads.

Everything here is fixed by ``WORKSHOP_SEED`` so that both cameras of a pair (and every cycle)
see the same room. Ray arrays: origin (3,), directions (N,3) unit, station frame.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from simulators.scene import Lighting, TexturedQuad
from simulators.shading import LABEL_FLOOR, LABEL_QUAD, LABEL_WALL, Hits, bilinear, shade, smooth_noise

WORKSHOP_SEED = 20240611
ROOM_HALF_X_M = 4.5       # walls at x = +-4.5 m
ROOM_HALF_Y_M = 7.0       # walls at y = +-7 m
ROOM_HEIGHT_M = 4.0       # ceiling
WALL_TEXEL_M = 0.02
FLOOR_TEXEL_M = 0.004
RUNWAY_CENTER_X_M = 0.78  # lift runway plates under each wheel track
RUNWAY_HALF_WIDTH_M = 0.30
RUNWAY_HALF_LENGTH_M = 2.60
RUNWAY_EDGE_M = 0.04      # yellow-painted (bright) safety strip along the plate's outer edge


@lru_cache(maxsize=1)
def wall_textures() -> tuple[np.ndarray, ...]:
    """Five (h, w) float32 textures: walls x+, x-, y+, y-, ceiling. Reflectance-like, 0..1.7."""
    rng = np.random.default_rng(WORKSHOP_SEED)
    h = int(ROOM_HEIGHT_M / WALL_TEXEL_M)
    out = []
    for face in range(4):
        length = 2 * (ROOM_HALF_Y_M if face < 2 else ROOM_HALF_X_M)
        w = int(length / WALL_TEXEL_M)
        tex = 0.72 + 0.06 * smooth_noise(rng, (h, w), (8, 32)) + 0.03 * smooth_noise(rng, (h, w), (40, 160))
        rows = np.arange(h)[:, None]
        tex = np.where(rows > h - int(1.1 / WALL_TEXEL_M), tex * 0.62, tex)  # darker lower band
        for _ in range(int(rng.integers(10, 18))):  # cabinets, shelves, machines standing on the floor
            bw = int(rng.uniform(0.3, 1.6) / WALL_TEXEL_M)
            bh = int(rng.uniform(0.4, 2.2) / WALL_TEXEL_M)
            x0 = int(rng.integers(0, max(1, w - bw)))
            level = rng.choice([rng.uniform(0.08, 0.3), rng.uniform(0.5, 0.95)])
            tex[h - bh:, x0:x0 + bw] = level + 0.04 * rng.standard_normal()
            tex[h - bh:h - bh + 3, x0:x0 + bw] = min(level * 1.5, 1.2)  # lit top edge
            for _ in range(int(rng.integers(0, 4))):  # drawers / panels
                dy = int(rng.integers(h - bh, h - 5))
                tex[dy:dy + 2, x0 + 2:x0 + bw - 2] = level * 0.4
        for _ in range(int(rng.integers(4, 9))):  # pipes and cables: vertical stripes
            x0 = int(rng.integers(0, w - 5))
            sw = int(rng.integers(1, 5))
            tex[:, x0:x0 + sw] = rng.choice([0.12, 0.95, 0.3])
        for _ in range(int(rng.integers(2, 6))):  # posters / tool boards with bars
            pw, ph = int(rng.integers(25, 70)), int(rng.integers(30, 60))
            x0, y0 = int(rng.integers(0, w - pw)), int(rng.integers(10, h // 2))
            tex[y0:y0 + ph, x0:x0 + pw] = 0.9
            for k in range(int(rng.integers(3, 9))):
                yy = y0 + 3 + int(rng.integers(0, ph - 6))
                tex[yy:yy + 2, x0 + 3:x0 + int(rng.integers(6, pw - 2))] = 0.15
        for _ in range(int(rng.integers(1, 3))):  # windows: bright, saturating
            ww, wh = int(rng.integers(50, 120)), int(rng.integers(40, 70))
            x0, y0 = int(rng.integers(0, w - ww)), int(rng.integers(5, h // 3))
            tex[y0:y0 + wh, x0:x0 + ww] = 1.6
            tex[y0:y0 + wh, x0 + ww // 2:x0 + ww // 2 + 2] = 0.2
        out.append(tex.astype(np.float32))
    wc, hc = int(2 * ROOM_HALF_X_M / WALL_TEXEL_M), int(2 * ROOM_HALF_Y_M / WALL_TEXEL_M)
    ceiling = 0.35 + 0.04 * smooth_noise(rng, (hc, wc), (16, 8))
    for k in range(6):  # fluorescent strips
        y0 = int((k + 0.5) / 6 * hc)
        ceiling[y0:y0 + 4, wc // 4:3 * wc // 4] = 1.7
    out.append(ceiling.astype(np.float32))
    return tuple(out)


@lru_cache(maxsize=1)
def floor_textures() -> tuple[np.ndarray, np.ndarray]:
    """Concrete (tiled, 4 mm texels) and runway plate pattern (tiled), float32 reflectance."""
    rng = np.random.default_rng(WORKSHOP_SEED + 1)
    n = 512
    concrete = (0.42 + 0.05 * smooth_noise(rng, (n, n), (12, 12)) + 0.03 * smooth_noise(rng, (n, n), (96, 96))
                + 0.015 * rng.standard_normal((n, n)))
    plate = 0.30 + 0.02 * smooth_noise(rng, (n, n), (16, 16))
    # diamond anti-slip pattern: low-contrast raised lozenges
    yy, xx = np.mgrid[0:n, 0:n]
    diamonds = (np.abs(((xx + yy) % 16) - 8) + np.abs(((xx - yy) % 16) - 8)) < 5
    plate = np.where(diamonds, plate + 0.04, plate)
    return concrete.astype(np.float32), plate.astype(np.float32)


def trace_room(o: np.ndarray, d_all: np.ndarray, idx: np.ndarray, hits: Hits, lighting: Lighting) -> None:
    """Walls and ceiling of the room for rays d_all[idx]: every ray ends there (camera inside)."""
    if idx.size == 0:
        return
    d = d_all[idx]
    textures = wall_textures()
    bounds = np.array([ROOM_HALF_X_M, ROOM_HALF_Y_M, ROOM_HEIGHT_M])
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = (np.where(d[:, 0] > 0, bounds[0], -bounds[0]) - o[0]) / d[:, 0]
        ty = (np.where(d[:, 1] > 0, bounds[1], -bounds[1]) - o[1]) / d[:, 1]
        tz = np.where(d[:, 2] > 0, (bounds[2] - o[2]) / d[:, 2], np.inf)
    tx = np.where(np.isfinite(tx) & (tx > 0), tx, np.inf)
    ty = np.where(np.isfinite(ty) & (ty > 0), ty, np.inf)
    t = np.minimum(np.minimum(tx, ty), tz)
    p = o + t[:, None] * d
    face = np.where(tz <= np.minimum(tx, ty), 4, np.where(tx <= ty, np.where(d[:, 0] > 0, 0, 1),
                                                         np.where(d[:, 1] > 0, 2, 3)))
    value = np.zeros(len(d), np.float32)
    for f, tex in enumerate(textures):
        sel = np.nonzero(face == f)[0]
        if sel.size == 0:
            continue
        q = p[sel]
        if f < 2:      # x walls: texture along y (seen from inside), rows from the ceiling down
            s = (q[:, 1] + ROOM_HALF_Y_M) / WALL_TEXEL_M
            r = (ROOM_HEIGHT_M - q[:, 2]) / WALL_TEXEL_M
        elif f < 4:
            s = (q[:, 0] + ROOM_HALF_X_M) / WALL_TEXEL_M
            r = (ROOM_HEIGHT_M - q[:, 2]) / WALL_TEXEL_M
        else:
            s = (q[:, 0] + ROOM_HALF_X_M) / WALL_TEXEL_M
            r = (q[:, 1] + ROOM_HALF_Y_M) / WALL_TEXEL_M
        value[sel] = bilinear(tex, s, r) * (lighting.background_level * 1.6)
    hits.store(idx, t, LABEL_WALL + face, value)


def trace_floor(o: np.ndarray, d: np.ndarray, idx: np.ndarray, hits: Hits, lighting: Lighting,
                floor_z: float, shadow=None) -> None:
    """The runway/floor plane z = floor_z for rays d[idx], lit by the key light;
    ``shadow(p) -> (N,) factor`` darkens it (contact shadows)."""
    dz = d[idx, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (floor_z - o[2]) / dz
    keep = (dz < 0) & (t > 0)
    idx, t = idx[keep], t[keep]
    px = o[0] + t * d[idx, 0]
    py = o[1] + t * d[idx, 1]
    inside = (np.abs(px) < ROOM_HALF_X_M) & (np.abs(py) < ROOM_HALF_Y_M)  # the floor ends at the walls
    idx, t = idx[inside], t[inside]
    win = hits.take(idx, t)
    idx, t = idx[win], t[win]
    if idx.size == 0:
        return
    p = o + t[:, None] * d[idx]
    concrete, plate = floor_textures()
    ax = np.abs(p[:, 0])
    on_runway = (np.abs(ax - RUNWAY_CENTER_X_M) < RUNWAY_HALF_WIDTH_M) & (np.abs(p[:, 1]) < RUNWAY_HALF_LENGTH_M)
    edge = on_runway & (ax > RUNWAY_CENTER_X_M + RUNWAY_HALF_WIDTH_M - RUNWAY_EDGE_M)
    s = p[:, 0] / FLOOR_TEXEL_M
    r = p[:, 1] / FLOOR_TEXEL_M
    albedo = np.where(on_runway, bilinear(plate, s, r, wrap=True), bilinear(concrete, s, r, wrap=True))
    albedo = np.where(edge, 0.65, albedo)
    n = np.tile(np.array([0.0, 0.0, 1.0]), (len(idx), 1))
    value = shade(albedo, n, d[idx], lighting)
    if shadow is not None:
        value = value * shadow(p)
    hits.store(idx, t, LABEL_FLOOR + on_runway.astype(np.int32) + edge, value)


def trace_quads(o: np.ndarray, d: np.ndarray, hits: Hits, lighting: Lighting,
                quads: tuple[TexturedQuad, ...], candidates: dict[int, np.ndarray] | None = None) -> None:
    """Textured parallelograms (bilinear texture); nearest hit wins, so closed boxes work.

    candidates: {quad index: ray indices that may see it}; missing: all rays.
    """
    candidates = candidates or {}
    for qi, quad in enumerate(quads):
        c = np.asarray(quad.corners_station, float)
        e1 = c[1] - c[0]                     # texture +x (width)
        e2 = c[3] - c[0]                     # texture +y (height)
        n = np.cross(e1, e2)
        n /= np.linalg.norm(n)
        sub = candidates.get(qi)
        ds = d if sub is None else d[sub]
        denom = ds[:, 0] * n[0] + ds[:, 1] * n[1] + ds[:, 2] * n[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((c[0] - o) @ n) / denom
        cand = np.flatnonzero(np.isfinite(t) & (t > 0))
        t = t[cand]
        if sub is not None:
            cand = sub[cand]
        if cand.size == 0:
            continue
        # texture coordinates by the dual basis: a = p.g1, b = p.g2 with p = a e1 + b e2
        G = np.linalg.pinv(np.stack([e1, e2], axis=1))  # (2,3)
        oc = o - c[0]
        dc = d[cand]
        a = oc @ G[0] + t * (dc[:, 0] * G[0, 0] + dc[:, 1] * G[0, 1] + dc[:, 2] * G[0, 2])
        b = oc @ G[1] + t * (dc[:, 0] * G[1, 0] + dc[:, 1] * G[1, 1] + dc[:, 2] * G[1, 2])
        inside = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        inside &= hits.take(cand, t)
        idx = cand[inside]
        if idx.size == 0:
            continue
        tex = quad.texture
        th, tw = tex.shape
        value = bilinear(tex, a[inside] * tw, b[inside] * th) * (quad.albedo / 255.0)
        hits.store(idx, t[inside], LABEL_QUAD + qi, shade(value, n, dc[inside], lighting))
