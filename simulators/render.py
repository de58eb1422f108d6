"""Render what a simulated station camera sees: exact geometry by ray casting, vectorised numpy.

Pipeline for one camera (shapes: H, W image; N rays):

1. One ray per pixel centre (the exact inverse of the lens distortion, cached per intrinsics),
   traced against the room, the floor, the textured quads and the vehicle's wheels: the nearest
   hit gives a label (which surface part) and a radiance.
2. Pixels whose label differs from a neighbour's, or whose radiance jumps, are edge pixels:
   they are re-rendered with ``supersample`` samples on a rank-1 lattice inside the pixel
   (distinct u and v offsets, so an edge of any direction is resolved to ~1/(2*samples) px),
   each through its own exact ray, and the pixel becomes their mean (box-filter coverage).
3. The optics and the sensor: vignetting, exposure gain, veiling glare and auto exposure if the
   scene's Appearance asks for them, a Gaussian PSF (``blur_sigma`` px), Gaussian read noise
   (``noise_sigma`` grey levels), clipping and quantisation to uint8.

Wheels are traced only inside the bounding box of their projection.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.station_frame import WHEELS
from simulators.rays import grid_start, normalized_to_rays_station, pixel_grid_normalized, sample_rays_station
from simulators.render_body import floor_shadow, trace_body
from simulators.render_wheel import BARREL, FLANGE, trace_wheel, wheel_outline_points
from simulators.scene import Lighting, Scene
from simulators.shading import LABEL_QUAD, LABEL_WHEEL, Hits
from simulators.workshop import trace_floor, trace_quads, trace_room

EDGE_RADIANCE_STEP = 0.04   # radiance jump between neighbours that also counts as an edge (~10 grey)
CLUTTER_SAMPLES = 13        # samples per edge pixel away from measured features (1/26 px)
PRECISE_PARTS = (FLANGE, BARREL)  # wheel parts next to the measured edge: full supersampling


class _RayKey:
    """A camera as the ray cache sees it: equal to any camera of the same intrinsics, size and
    orientation (what its pixel rays depend on), and carrying the camera to compute them."""

    __slots__ = ("camera", "_key")

    def __init__(self, camera: CameraModel):
        self.camera = camera
        self._key = camera.K.tobytes() + camera.dist.tobytes() + camera.R_cam_station.tobytes() + bytes(
            str((camera.width, camera.height)), "ascii")

    def __hash__(self) -> int:
        return hash(self._key)

    def __eq__(self, other) -> bool:
        return isinstance(other, _RayKey) and self._key == other._key


# lru_cache is thread-safe (the capture threads render cameras in parallel); like any pure
# cache, two threads missing the same camera may both compute its rays, and either is kept.
@functools.lru_cache(maxsize=8)
def _rays_of(key: _RayKey) -> np.ndarray:
    rays = normalized_to_rays_station(key.camera, pixel_grid_normalized(key.camera).reshape(-1, 2))
    rays.flags.writeable = False
    return rays


def _pixel_rays(camera: CameraModel) -> np.ndarray:
    """(H*W, 3) station-frame rays of the pixel centres, cached per camera (pose + intrinsics)."""
    return _rays_of(_RayKey(camera))


def lattice_offsets(n: int) -> np.ndarray:
    """(n,2) sample offsets in [-0.5, 0.5)^2: a Fibonacci-style rank-1 lattice, centred.

    Every sample has its own u and its own v level (n distinct values each), so a straight edge
    in any direction is resolved to 1/n of a pixel; the pattern's mean is the pixel centre.
    """
    g = {8: 3, 13: 5, 21: 8, 34: 13, 55: 21, 89: 34}.get(n)
    if g is None:
        g = max(1, int(round(n / 1.618034)))
    i = np.arange(n)
    uv = np.stack([(i + 0.5) / n, np.mod(i * g + 0.5, n) / n], axis=1)
    return uv - 0.5


def wheel_masks(camera: CameraModel, scene: Scene, margin_px: int = 5) -> dict[int, np.ndarray]:
    """{wheel index: (H,W) bool} pixels that may see the wheel: the convex hull of its bounding
    cylinder's projected rims (and middle circle), grown by ``margin_px``."""
    out = {}
    for i, _, _, _, box in wheel_boxes(camera, scene, 0.0):
        c0, c1, r0, r1 = box
        mask = np.zeros((camera.height, camera.width), np.uint8)
        vehicle = scene.vehicle
        center, R = vehicle.wheel_frame_station(WHEELS[i])
        uv = camera.project(wheel_outline_points(center, R, vehicle.wheel))
        if np.isfinite(uv).all() and np.abs(uv).max() < 1e5:
            hull = cv2.convexHull(np.round(uv * 16).astype(np.int32))
            cv2.fillConvexPoly(mask, hull, 1, lineType=cv2.LINE_8, shift=4)
            k = 2 * margin_px + 1
            mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
        else:
            mask[:] = 1
        out[i] = mask.astype(bool)
    return out


def wheel_boxes(camera: CameraModel, scene: Scene, margin_px: float = 4.0) -> list[tuple]:
    """[(wheel index, name, centre (3,), R (3,3), (c0, c1, r0, r1) pixel box)] for visible wheels."""
    out = []
    vehicle = scene.vehicle
    if vehicle is None:
        return out
    for i, name in enumerate(WHEELS):
        center, R = vehicle.wheel_frame_station(name)
        pts = wheel_outline_points(center, R, vehicle.wheel)
        uv = camera.project(pts)
        ok = np.isfinite(uv).all(axis=1)
        if not ok.any():
            continue
        if not ok.all():
            box = (0, camera.width, 0, camera.height)
        else:
            c0 = int(np.floor(uv[:, 0].min() - margin_px))
            c1 = int(np.ceil(uv[:, 0].max() + margin_px)) + 1
            r0 = int(np.floor(uv[:, 1].min() - margin_px))
            r1 = int(np.ceil(uv[:, 1].max() + margin_px)) + 1
            box = (max(c0, 0), min(c1, camera.width), max(r0, 0), min(r1, camera.height))
            if box[0] >= box[1] or box[2] >= box[3]:
                continue
        out.append((i, name, center, R, box))
    return out


def _caliper_angle(vehicle, name: str, R: np.ndarray) -> float:
    """Angle in the wheel's u-v plane of the caliper: behind the axle, a little above it, on the
    knuckle (it steers with the wheel but does not roll with it)."""
    rear = vehicle.knuckle_turn_station(name) @ vehicle.R_station_vehicle @ np.array(
        [0.0, -1.0, 0.35 if name.startswith("F") else 0.2])
    e = R.T @ rear
    return float(np.arctan2(e[1], e[0]))


def trace(o: np.ndarray, d: np.ndarray, scene: Scene, lighting: Lighting,
          wheel_candidates: dict[int, np.ndarray], body: bool = True,
          quad_candidates: dict[int, np.ndarray] | None = None) -> Hits:
    """Nearest hits of rays d (N,3) from o (3,).

    wheel_candidates / quad_candidates: {index: ray indices} that may see that wheel / quad
    (a wheel missing from the dict is not traced; quads default to all rays).
    """
    hits = Hits(len(d))
    if scene.quads:
        trace_quads(o, d, hits, lighting, scene.quads, quad_candidates)
    vehicle = scene.vehicle
    if vehicle is not None and body:
        trace_body(o, d, np.arange(len(d)), hits, lighting, vehicle, scene.appearance)
    if vehicle is not None:
        frames = {name: vehicle.wheel_frame_station(name) for name in WHEELS}
        # nearest wheel first: its hits cull the rays of the wheels behind it
        order = sorted(range(len(WHEELS)), key=lambda i: np.linalg.norm(frames[WHEELS[i]][0] - o))
        for i in order:
            idx = wheel_candidates.get(i)
            if idx is None or idx.size == 0:
                continue
            center, R = frames[WHEELS[i]]
            trace_wheel(o, d, idx, hits, lighting, center, R, vehicle.wheel, i,
                        _caliper_angle(vehicle, WHEELS[i], R), scene.appearance)
    # objects stand on the floor inside the room: the floor and the walls are seen only by
    # the rays that hit nothing else
    rest = np.nonzero(np.isinf(hits.t))[0]
    shadow = floor_shadow(vehicle) if vehicle is not None and body else None
    trace_floor(o, d, rest, hits, lighting, scene.floor_z_m, shadow)
    rest = rest[np.isinf(hits.t[rest])]
    trace_room(o, d, rest, hits, lighting)
    return hits


def _edge_mask(label: np.ndarray, value: np.ndarray) -> np.ndarray:
    """(H,W) bool: pixels whose centre label differs from any of their 8 neighbours' (an edge
    crosses the pixel or clips its corner), or, on printed quads, whose radiance jumps."""
    diff = np.zeros(label.shape, bool)
    dl_h = label[:, 1:] != label[:, :-1]
    dl_v = label[1:, :] != label[:-1, :]
    dl_d = label[1:, 1:] != label[:-1, :-1]
    dl_a = label[1:, :-1] != label[:-1, 1:]
    diff[1:, 1:] |= dl_d
    diff[:-1, :-1] |= dl_d
    diff[1:, :-1] |= dl_a
    diff[:-1, 1:] |= dl_a
    # radiance jumps count only on printed quads (sharp-edged textures); elsewhere the
    # procedural textures are smooth and labels mark every geometric edge
    textured = label >= LABEL_QUAD
    tex_h = textured[:, 1:] | textured[:, :-1]
    tex_v = textured[1:, :] | textured[:-1, :]
    dv_h = tex_h & (np.abs(value[:, 1:] - value[:, :-1]) > EDGE_RADIANCE_STEP)
    dv_v = tex_v & (np.abs(value[1:, :] - value[:-1, :]) > EDGE_RADIANCE_STEP)
    h = dl_h | dv_h
    v = dl_v | dv_v
    diff[:, 1:] |= h
    diff[:, :-1] |= h
    diff[1:, :] |= v
    diff[:-1, :] |= v
    return diff


def _near(label: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """(H,W) bool: pixels with a label in [lo, hi) in their 3x3 neighbourhood."""
    m = ((label >= lo) & (label < hi)).astype(np.uint8)
    return cv2.dilate(m, np.ones((3, 3), np.uint8)).astype(bool)


def quad_masks(camera: CameraModel, scene: Scene, margin_px: int = 3) -> dict[int, np.ndarray | None]:
    """{quad index: (H,W) bool pixels that may see it, or None (all)}: the convex hull of its
    densely projected outline (distortion bends the edges), grown by ``margin_px``."""
    out = {}
    s = np.linspace(0, 1, 16, endpoint=False)[:, None]
    for i, q in enumerate(scene.quads):
        c = np.asarray(q.corners_station, float)
        outline = np.vstack([c[k] + s * (c[(k + 1) % 4] - c[k]) for k in range(4)])
        uv = camera.project(outline)
        if not (np.isfinite(uv).all() and np.abs(uv).max() < 1e5):
            out[i] = None
            continue
        mask = np.zeros((camera.height, camera.width), np.uint8)
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round(uv * 16).astype(np.int32)), 1, cv2.LINE_8, 4)
        k = 2 * margin_px + 1
        out[i] = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool)
    return out


def _precise_area(label: np.ndarray) -> np.ndarray:
    """(H,W) bool: printed quads and the rim flange's surroundings, dilated by one pixel."""
    part = np.mod(label - LABEL_WHEEL, 40)
    wheel = (label >= LABEL_WHEEL) & (label < LABEL_QUAD)
    area = (label >= LABEL_QUAD) | (wheel & np.isin(part, PRECISE_PARTS))
    return cv2.dilate(area.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def render_radiance(camera: CameraModel, scene: Scene, lighting: Lighting | None = None,
                    supersample: int = 34, body: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free, unblurred radiance (H,W) float32 and the centre-sample labels (H,W) int32."""
    lighting = lighting or Lighting()
    H, W = camera.height, camera.width
    o = camera.center_station
    grid = pixel_grid_normalized(camera)
    d = _pixel_rays(camera)
    masks = wheel_masks(camera, scene)
    cand = {i: np.flatnonzero(m) for i, m in masks.items()}
    qmasks = quad_masks(camera, scene)
    qcand = {i: np.flatnonzero(m) for i, m in qmasks.items() if m is not None}
    hits = trace(o, d, scene, lighting, cand, body, qcand)
    label = hits.label.reshape(H, W)
    value = hits.value.reshape(H, W).copy()
    edges = _edge_mask(label, value) if supersample > 1 else np.zeros((H, W), bool)
    precise = edges & _precise_area(label)
    for mask, n_samples in ((precise, supersample), (edges & ~precise, min(supersample, CLUTTER_SAMPLES))):
        rr, cc = np.nonzero(mask)
        if rr.size:
            offsets = lattice_offsets(n_samples)
            S = len(offsets)
            uv = np.empty((rr.size * S, 2))
            uv[:, 0] = (cc[:, None] + offsets[None, :, 0]).ravel()
            uv[:, 1] = (rr[:, None] + offsets[None, :, 1]).ravel()
            start = grid_start(grid, rr, cc, offsets)
            ds = sample_rays_station(camera, uv, start)
            # a sample can only see a wheel or quad that a pixel centre of its 3x3
            # neighbourhood sees (thinner slivers are below what the edge test resolves)
            offs = np.arange(S)
            scand = {i: (np.flatnonzero(_near(label, LABEL_WHEEL + 40 * i, LABEL_WHEEL + 40 * (i + 1))[rr, cc])[:, None] * S
                         + offs).ravel() for i in masks}
            sq = {i: (np.flatnonzero(_near(label, LABEL_QUAD + i, LABEL_QUAD + i + 1)[rr, cc])[:, None] * S
                      + offs).ravel() for i in range(len(scene.quads))}
            sh = trace(o, ds, scene, lighting, scand, body, sq)
            value[rr, cc] = sh.value.reshape(-1, S).mean(axis=1)
    return value, label


def vignetting(camera: CameraModel, strength: float) -> np.ndarray:
    """(H,W) float32 relative illumination: 1 at the principal point, 1 - strength at the corner."""
    H, W = camera.height, camera.width
    cx, cy = camera.K[0, 2], camera.K[1, 2]
    u = (np.arange(W, dtype=np.float32) - cx)[None, :]
    v = (np.arange(H, dtype=np.float32) - cy)[:, None]
    corner2 = max((cx - dx) ** 2 + (cy - dy) ** 2 for dx in (0, W - 1) for dy in (0, H - 1))
    r2 = (u * u + v * v) / np.float32(corner2)
    return (1.0 - strength * r2).astype(np.float32)


def render_clean(camera: CameraModel, scene: Scene, lighting: Lighting | None = None,
                 blur_sigma: float = 0.75, supersample: int = 34, body: bool = True) -> np.ndarray:
    """The (H,W) float32 grey levels ``camera`` receives of ``scene`` before the sensor's read
    noise and quantisation: radiance x exposure x vignetting, blurred by the lens's PSF.
    A still scene gives the same clean image to every frame (:func:`sensor_frame`).
    The scene's ``appearance.veiling_glare`` adds that share of the image's light spread over
    about a tenth of the frame (light scattered in the lens); ``appearance.auto_exposure``
    replaces the lighting's gain by the one that puts the image's bright percentile there."""
    lighting = lighting or Lighting()
    look = scene.appearance
    radiance, _ = render_radiance(camera, scene, lighting, supersample, body)
    image = radiance * (255.0 * lighting.gain) * vignetting(camera, lighting.vignetting)
    if look.veiling_glare > 0:
        image = image + np.float32(look.veiling_glare) * veiling_glare(image)
    if blur_sigma > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_sigma, borderType=cv2.BORDER_REFLECT)
    if look.auto_exposure > 0:
        bright = float(np.percentile(image, look.auto_exposure_percentile))
        image = image * np.float32(look.auto_exposure / max(bright, 1e-3))
    return image


def veiling_glare(image: np.ndarray) -> np.ndarray:
    """(H,W) float32: the image's light spread by a Gaussian of sigma ~1/10 of its width (on a
    16x smaller copy, then interpolated back)."""
    H, W = image.shape
    small = cv2.resize(image, (max(W // 16, 1), max(H // 16, 1)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), max(W, H) / 160.0, borderType=cv2.BORDER_REFLECT)
    return cv2.resize(small, (W, H), interpolation=cv2.INTER_LINEAR)


def sensor_frame(clean: np.ndarray, rng: np.random.Generator | None = None, noise_sigma: float = 2.0) -> np.ndarray:
    """One (H,W) uint8 exposure of the clean image (H,W) float32: Gaussian read noise of
    ``noise_sigma`` grey levels from ``rng`` (default: a fixed seed), clipped and quantised."""
    image = clean
    if noise_sigma > 0:
        rng = rng if rng is not None else np.random.default_rng(0)
        image = image + rng.standard_normal(image.shape, dtype=np.float32) * np.float32(noise_sigma)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def render(camera: CameraModel, scene: Scene, lighting: Lighting | None = None,
           rng: np.random.Generator | None = None, noise_sigma: float = 2.0,
           blur_sigma: float = 0.75, supersample: int = 34, body: bool = True) -> np.ndarray:
    """The (H,W) uint8 image ``camera`` takes of ``scene`` under ``lighting``.

    rng: the sensor-noise stream (default: a fixed seed, so the call is deterministic).
    noise_sigma: Gaussian read noise in grey levels. blur_sigma: Gaussian PSF in px (0: none).
    supersample: samples per edge pixel near measured features. body: draw the vehicle's body
    (with wheel arches) and its floor shadow, not just its four wheels.
    """
    return sensor_frame(render_clean(camera, scene, lighting, blur_sigma, supersample, body), rng, noise_sigma)
