"""The rim's face as a surface seen by both cameras, and how far it turned between two captures.

A steered wheel is seen from a new direction at every steer position. Its face is no plane:
spokes, hub and, through the windows, the brake disc stand tens of millimetres apart along the
axis, so a profile sampled in one plane (station/wheel/rim_pattern.py) shifts with the view and
reads the face's turn up to a few tenths of a degree off on some rims; SAI, which rests on that
turn, is then off by several times as much. Here the face is a surface:

- on a polar grid about the wheel's 3-D circle at the reference capture (``RING_RADII`` x the lip
  radius, ``ARC_SAMPLES`` angles), each cell's depth along the axis is the one at which both
  cameras of the pair see the same thing (normalised cross-correlation over a short arc, over
  ``DEPTH_RANGE_M``; median-filtered);
- cells the views do not agree on, and cells next to a jump in depth (a spoke's edge in front of
  the disc: another view hides or uncovers what lies behind it) are left out (``weight`` 0);
- the turn at another capture is the angle about that capture's axis which, applied to the
  surface, makes each camera's image there match its image at the reference: per ring
  normalised grey levels, squared differences capped at ``RESIDUAL_CAP`` so that the few cells
  still hidden or uncovered cannot pull it; a grid over +/-``SEARCH_DEG`` about a prior, refined.

On the simulated station's steering sweeps it reads the turn to 0.0065 deg RMS (bench/steering.py,
docs/procedures.md).

Shapes: a surface's depth and weight are (R, S) = (len(RING_RADII), ARC_SAMPLES); points (R,S,3)
in the station frame (m); images (H,W) grey, linear.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import minimize_scalar

from calibration.camera_model import CameraModel
from station.wheel.rim_pattern import FacePose, ring_basis

RING_RADII = np.linspace(0.30, 0.90, 25)    # the rings, as fractions of the lip radius
ARC_SAMPLES = 1024                          # cells round a ring (0.35 deg apart)
DEPTH_RANGE_M = (-0.12, 0.03)               # where the face may be, along the outward axis from the lip plane
DEPTH_STEP_M = 0.0025
ARC_HALF = 5                                # the views are compared over 2 * ARC_HALF + 1 cells of a ring
MIN_AGREEMENT = 0.8                         # a cell's two views correlate at least this well at its depth
DEPTH_JUMP_M = 0.006                        # a step in depth between neighbouring cells: an occluding edge
EDGE_MARGIN = 3                             # cells left out on either side of such an edge (along the ring)
RESIDUAL_CAP = 1.0                          # a cell's squared grey difference (ring-normalised) counts at most this
SEARCH_DEG = 1.0                            # the turn is searched this far either side of its prior
SEARCH_STEP_DEG = 0.05
MIN_CELLS = 200                             # a surface with fewer usable cells cannot be followed


@dataclass(frozen=True)
class FaceSurface:
    """The face at the reference capture: its pose, each cell's depth (R,S) m along the axis
    from the lip plane and weight (R,S) (1 usable, 0 left out), the rings' radii (R,) as
    fractions of the lip radius."""

    pose: FacePose
    depth_m: np.ndarray
    weight: np.ndarray
    radii: np.ndarray = field(default_factory=lambda: RING_RADII)

    @property
    def usable_cells(self) -> int:
        return int(np.count_nonzero(self.weight))


def surface_points(pose: FacePose, depth_m: np.ndarray | float, psi_rad: float = 0.0,
                   radii: np.ndarray = RING_RADII, samples: int = ARC_SAMPLES) -> np.ndarray:
    """(R,S,3) the grid's cells (``radii`` (R,) x the lip radius, ``samples`` S round each) at
    ``depth_m`` (scalar or (R,S)) for a face posed at ``pose`` and turned by ``psi_rad`` about
    its axis (from e1 toward e2 of rim_pattern.ring_basis)."""
    n = np.asarray(pose.axis_station, float)
    n = n / np.linalg.norm(n)
    e1, e2 = ring_basis(n)
    phi = np.arange(samples) * (2 * np.pi / samples) + psi_rad
    r = np.asarray(radii, float)[:, None] * pose.radius_m                             # (R,1)
    d = np.broadcast_to(np.asarray(depth_m, float), (len(r), samples))
    return (np.asarray(pose.center_station, float) + (r * np.cos(phi))[..., None] * e1
            + (r * np.sin(phi))[..., None] * e2 + d[..., None] * n)


def face_surface(images: dict[str, np.ndarray], cameras: dict[str, CameraModel], pose: FacePose,
                 radii: np.ndarray = RING_RADII, samples: int = ARC_SAMPLES,
                 depth_range_m: tuple[float, float] = DEPTH_RANGE_M, depth_step_m: float = DEPTH_STEP_M) -> FaceSurface:
    """The face's surface at the capture of ``images`` (the pair's two cameras) and ``pose``, on
    rings ``radii`` x the lip radius of ``samples`` cells each, at depths over ``depth_range_m``
    ``depth_step_m`` apart."""
    cam_a, cam_b = list(images)
    images = {c: np.asarray(images[c], np.float32) for c in (cam_a, cam_b)}   # once, not per depth
    depths = np.arange(depth_range_m[0], depth_range_m[1] + 1e-9, depth_step_m)
    in_plane = surface_points(pose, 0.0, radii=radii, samples=samples)                  # (R,S,3)
    n = np.asarray(pose.axis_station, float) / np.linalg.norm(pose.axis_station)
    points = in_plane[None] + depths[:, None, None, None] * n                          # (D,R,S,3)
    a, b = _sample(images[cam_a], cameras[cam_a], points), _sample(images[cam_b], cameras[cam_b], points)
    ma, mb = _arc_mean(a), _arc_mean(b)
    cov = _arc_mean(a * b) - ma * mb
    var = (_arc_mean(a * a) - ma ** 2) * (_arc_mean(b * b) - mb ** 2)
    agreement = cov / np.sqrt(np.maximum(var, 1e-12))                                  # (D,R,S)
    agreement = np.nan_to_num(agreement, nan=-1.0)
    k = np.argmax(agreement, axis=0)                                                   # (R,S)
    best = np.take_along_axis(agreement, k[None], 0)[0]
    inner = np.clip(k, 1, len(depths) - 2)
    y0, y1, y2 = (np.take_along_axis(agreement, (inner + j)[None], 0)[0] for j in (-1, 0, 1))
    den = y0 - 2 * y1 + y2
    step = np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, -1.0), 0.0)
    depth = np.where((k == 0) | (k == len(depths) - 1), depths[k], depths[inner] + np.clip(step, -1, 1) * depth_step_m)
    depth = _circular_median(depth)
    return FaceSurface(pose, depth, _weight(depth, best), np.asarray(radii, float))


def turn_on_surface(surface: FaceSurface, reference_image: np.ndarray, image: np.ndarray, camera: CameraModel,
                    pose: FacePose, prior_rad: float) -> float:
    """The face's turn (rad) about its axis at the capture of ``image`` (posed at ``pose``)
    since the reference capture (``reference_image``, the surface's), in one camera."""
    grid = {"radii": surface.radii, "samples": surface.depth_m.shape[1]}
    image = np.asarray(image, np.float32)                                               # once, not per turn tried
    before = _sample(reference_image, camera, surface_points(surface.pose, surface.depth_m, **grid))
    usable = np.isfinite(before) & (surface.weight > 0)

    def misfit(psi: float) -> float:
        after = _sample(image, camera, surface_points(pose, surface.depth_m, psi, **grid))
        w = (usable & np.isfinite(after)) * surface.weight                              # (R,S)
        n = np.maximum(w.sum(axis=1, keepdims=True), 1e-9)
        x, y = np.nan_to_num(before), np.nan_to_num(after)
        x = x - (w * x).sum(axis=1, keepdims=True) / n
        y = y - (w * y).sum(axis=1, keepdims=True) / n
        x = x / (np.sqrt((w * x * x).sum(axis=1, keepdims=True) / n) + 1e-9)
        y = y / (np.sqrt((w * y * y).sum(axis=1, keepdims=True) / n) + 1e-9)
        return float(np.sum(w * np.minimum((x - y) ** 2, RESIDUAL_CAP)))

    candidates = prior_rad + np.radians(np.arange(-SEARCH_DEG, SEARCH_DEG + 1e-9, SEARCH_STEP_DEG))
    start = candidates[int(np.argmin([misfit(p) for p in candidates]))]
    h = np.radians(SEARCH_STEP_DEG)
    return float(minimize_scalar(misfit, bounds=(start - h, start + h), method="bounded",
                                 options={"xatol": 1e-8}).x)


def _sample(image: np.ndarray, camera: CameraModel, points: np.ndarray) -> np.ndarray:
    """(..., S) the image's grey at the points (..., S, 3), bilinear; NaN outside the image."""
    shape = points.shape[:-1]
    uv = camera.project(points.reshape(-1, 3)).astype(np.float32)
    rows = (-1, shape[-1])
    values = cv2.remap(np.asarray(image, np.float32), uv[:, 0].reshape(rows), uv[:, 1].reshape(rows),
                       cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return values.astype(float).reshape(shape)


def _arc_mean(a: np.ndarray, half: int = ARC_HALF) -> np.ndarray:
    """(..., S) the mean of a (..., S) over 2 * half + 1 cells along each ring (circular)."""
    k = 2 * half + 1
    c = np.cumsum(np.concatenate([a[..., -half - 1:], a, a[..., :half]], axis=-1), axis=-1)
    return (c[..., k:] - c[..., :-k]) / k


def _circular_median(depth: np.ndarray, size: int = 5) -> np.ndarray:
    """(R,S) depth median-filtered over size x size cells, wrapping round the rings."""
    pad = size // 2
    wrapped = np.hstack([depth[:, -pad:], depth, depth[:, :pad]]).astype(np.float32)
    return cv2.medianBlur(wrapped, size)[:, pad:-pad].astype(float)


def _weight(depth: np.ndarray, agreement: np.ndarray) -> np.ndarray:
    """(R,S) 1 where the views agree and no depth jump is near, else 0."""
    jump = np.abs(np.roll(depth, -1, axis=1) - depth) > DEPTH_JUMP_M
    jump[:-1] |= np.abs(depth[1:] - depth[:-1]) > DEPTH_JUMP_M
    m = EDGE_MARGIN
    edge = np.hstack([jump[:, -m:], jump, jump[:, :m]]).astype(np.uint8)
    edge = cv2.dilate(edge, np.ones((3, 2 * m + 1), np.uint8))[:, m:-m]
    return ((agreement > MIN_AGREEMENT) & (edge == 0)).astype(float)


RECESS_RADII = np.linspace(0.5, 0.9, 9)     # the face's outer part, clear of a hub that may stand proud
RECESS_SAMPLES = 256
RECESS_RANGE_M = (-0.08, 0.03)              # a face deeper than 80 mm reads 80: enough to tell
RECESS_STEP_M = 0.005


def face_near_plane(images: dict[str, np.ndarray], cameras: dict[str, CameraModel], pose: FacePose,
                    within_m: float) -> tuple[float, int]:
    """(share, cells): the share of the cells both cameras place on the outer part of the face
    (``RECESS_RADII``) that lie less than ``within_m`` behind the plane of the circle ``pose``, or
    in front of it, and how many cells they place (NaN, 0: none). A coarse surface: some 7 ms a
    wheel. A share, not a depth: a few cells matched at a wrong depth (harsh light, a tenth of
    them at most on the simulated station) must not decide."""
    s = face_surface(images, cameras, pose, RECESS_RADII, RECESS_SAMPLES, RECESS_RANGE_M, RECESS_STEP_M)
    d = s.depth_m[s.weight > 0]
    return (float(np.mean(d > -within_m)) if len(d) else float("nan")), int(len(d))
