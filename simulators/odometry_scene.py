"""A textured indoor scene seen by a stereo rig on a car-like robot (the paper's section 3.3).

The room (floor, ceiling, four walls, windows, posters, furniture-like boxes) is a set of
textured rectangles; images are ray cast, vectorised over pixels, with mip-mapped textures so
that far surfaces do not alias. Everything is deterministic by seed. The sequence writer at the
end needs no ``station`` code; the format is described in docs/odometry.md. Render one with

    .venv/bin/python -m simulators.odometry_scene DIR --kind short|long [--seed N]

then measure it with ``station odometry DIR``. What it writes:

    DIR/sequence.json   what was simulated (seed, path, rig)
    DIR/stereo.json     the two cameras (calibration.camera_model dicts, rig frame = left camera)
    DIR/left/000000.png, DIR/right/000000.png, ...   8-bit grey images
    DIR/poses.txt       truth: per step the 3x4 [R|t] of the left camera in step 0's left
                        camera frame (KITTI's layout), row-major, 12 numbers per line

World frame: z up, the floor at z = 0, metres. Camera frames are OpenCV's (x right, y down,
z forward).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.camera_model import CameraModel, look_at

WIDTH, HEIGHT = 720, 480


# --- textures --------------------------------------------------------------------------------
def _texture(rng: np.random.Generator, size: int, shapes: int, text: bool) -> np.ndarray:
    """A (size,size) float32 texture in 0..1: multi-octave noise with shapes and text on it."""
    img = np.zeros((size, size), np.float32)
    for cells, amp in ((4, 0.35), (16, 0.25), (64, 0.15), (size // 4, 0.08)):
        g = rng.random((cells, cells)).astype(np.float32)
        img += amp * cv2.resize(g, (size, size), interpolation=cv2.INTER_CUBIC)
    img = (img - img.min()) / (np.ptp(img) + 1e-9) * 0.6 + 0.2
    canvas = (img * 255).astype(np.uint8)
    for _ in range(shapes):
        kind = rng.integers(0, 4)
        c = tuple(int(v) for v in rng.integers(0, size, 2))
        grey = int(rng.integers(0, 256))
        r = int(rng.integers(size // 200 + 3, size // 25 + 5))
        if kind == 0:
            cv2.circle(canvas, c, r, grey, -1, cv2.LINE_AA)
        elif kind == 1:
            d = tuple(int(v) for v in rng.integers(-2 * r, 2 * r, 2))
            cv2.rectangle(canvas, c, (c[0] + d[0], c[1] + d[1]), grey, -1, cv2.LINE_AA)
        elif kind == 2:
            axes = (r, int(rng.integers(2, r + 3)))
            cv2.ellipse(canvas, c, axes, float(rng.uniform(0, 180)), 0, 360, grey, -1, cv2.LINE_AA)
        else:
            d = tuple(int(v) for v in rng.integers(-3 * r, 3 * r, 2))
            cv2.line(canvas, c, (c[0] + d[0], c[1] + d[1]), grey, int(rng.integers(1, 5)), cv2.LINE_AA)
    if text:
        letters = np.array(list("ABCDEFGHJKLMNPQRSTUVWXYZ0123456789"))
        for _ in range(shapes // 6):
            s = "".join(rng.choice(letters, int(rng.integers(3, 9))))
            org = tuple(int(v) for v in rng.integers(0, size, 2))
            cv2.putText(canvas, s, org, cv2.FONT_HERSHEY_SIMPLEX, float(rng.uniform(0.6, 2.2)),
                        int(rng.integers(0, 256)), int(rng.integers(1, 4)), cv2.LINE_AA)
    return cv2.GaussianBlur(canvas, (0, 0), 0.7).astype(np.float32) / 255.0


def _mip(tex: np.ndarray, levels: int = 7) -> list[np.ndarray]:
    out = [tex]
    for _ in range(levels - 1):
        out.append(cv2.pyrDown(out[-1]))
    return out


# --- scene -----------------------------------------------------------------------------------
@dataclass
class Quad:
    """A rectangle: ``origin + s*e1 + u*e2`` for s, u in [0,1]; visible from the side of
    ``e1 x e2``. Texture ``tex`` is sampled at ``texel_m`` metres per texel, shifted by
    ``offset`` texels; ``albedo`` scales it, ``emissive`` makes it a light (a window)."""

    origin: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    tex: int
    texel_m: float
    offset: tuple[float, float]
    albedo: float = 1.0
    emissive: float = 0.0


def _rect(origin, e1, e2, tex, texel_m, rng, albedo=1.0, emissive=0.0) -> Quad:
    off = (float(rng.uniform(0, 4096)), float(rng.uniform(0, 4096)))
    return Quad(np.asarray(origin, float), np.asarray(e1, float), np.asarray(e2, float),
                tex, texel_m, off, albedo, emissive)


def _box(lo, hi, tex, rng, texel_m=0.004) -> list[Quad]:
    """The five visible faces (no bottom) of an axis-aligned box, normals outward."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    X, Y, Z = np.eye(3)
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    alb = float(rng.uniform(0.7, 1.0))
    return [
        _rect((x0, y0, z1), dx * X, dy * Y, tex, texel_m, rng, alb),          # top (+z)
        _rect((x0, y0, z0), dx * X, dz * Z, tex, texel_m, rng, alb),          # -y face
        _rect((x1, y1, z0), -dx * X, dz * Z, tex, texel_m, rng, alb),         # +y face
        _rect((x0, y1, z0), -dy * Y, dz * Z, tex, texel_m, rng, alb),         # -x face
        _rect((x1, y0, z0), dy * Y, dz * Z, tex, texel_m, rng, alb),          # +x face
    ]


class Room:
    """The indoor scene: ``half_x`` x ``half_y`` metres, ``height`` tall, deterministic by seed."""

    def __init__(self, seed: int = 0, half_x: float = 8.0, half_y: float = 6.0, height: float = 3.0,
                 tex_size: int = 1024):
        rng = np.random.default_rng(seed)
        self.textures = [_mip(_texture(rng, tex_size, 1400, text=(k % 2 == 0))) for k in range(6)]
        X, Y, Z = np.eye(3)
        hx, hy, h = half_x, half_y, height
        q: list[Quad] = [
            _rect((-hx, -hy, 0), 2 * hx * X, 2 * hy * Y, 0, 0.006, rng, 0.9),     # floor (+z)
            _rect((-hx, hy, h), 2 * hx * X, -2 * hy * Y, 1, 0.012, rng, 0.8),     # ceiling (-z)
            _rect((-hx, hy, 0), 2 * hx * X, h * Z, 2, 0.010, rng, 0.85),          # north wall (-y)
            _rect((hx, -hy, 0), -2 * hx * X, h * Z, 3, 0.010, rng, 0.85),         # south wall (+y)
            _rect((-hx, -hy, 0), 2 * hy * Y, h * Z, 4, 0.010, rng, 0.85),         # west wall (+x)
            _rect((hx, hy, 0), -2 * hy * Y, h * Z, 5, 0.010, rng, 0.85),          # east wall (-x)
        ]
        eps = 0.01
        # windows (bright, emissive) and posters, slightly in front of the walls
        for x in (-5.0, -1.0, 3.0):
            q.append(_rect((x, hy - eps, 1.0), 1.6 * X, 1.3 * Z, 1, 0.01, rng, 1.0, emissive=0.9))
        for y in (-3.0, 2.0):
            q.append(_rect((hx - eps, y + 1.5, 1.0), -1.5 * Y, 1.3 * Z, 3, 0.01, rng, 1.0, emissive=0.9))
        for k, x in enumerate((-6.0, -2.5, 1.5, 5.0)):
            q.append(_rect((x + 1.0, -hy + eps, 0.9), -1.0 * X, 1.2 * Z, k % 6, 0.003, rng, 1.0))
        for y in (-4.0, 0.5, 3.5):
            q.append(_rect((-hx + eps, y, 0.8), 1.0 * Y, 1.4 * Z, (y > 0) + 2, 0.003, rng, 1.0))
        # furniture-like boxes along the walls and two islands
        boxes = [((-7.6, -5.6, 0), (-5.6, -4.8, 0.8)), ((-1.0, -5.7, 0), (1.2, -4.9, 1.1)),
                 ((4.0, -5.7, 0), (7.6, -5.0, 0.75)), ((7.0, -2.0, 0), (7.7, 0.5, 1.9)),
                 ((6.8, 3.0, 0), (7.6, 5.6, 0.9)), ((-3.5, 5.0, 0), (-1.8, 5.7, 1.6)),
                 ((0.8, 5.1, 0), (2.6, 5.7, 0.7)), ((-7.7, -1.5, 0), (-7.0, 1.8, 1.2)),
                 ((-0.6, -0.5, 0), (0.6, 0.4, 0.75)), ((-2.5, 1.6, 0), (-1.9, 2.2, 2.2))]
        for k, (lo, hi) in enumerate(boxes):
            q += _box(lo, hi, k % 6, rng)
        self.quads = q
        self.half_x, self.half_y, self.height = hx, hy, h
        self.obstacles = [(np.array(lo[:2]), np.array(hi[:2])) for lo, hi in boxes]


# --- rendering -------------------------------------------------------------------------------
def _sample(levels: list[np.ndarray], s: np.ndarray, u: np.ndarray, lod: np.ndarray) -> np.ndarray:
    """Bilinear, wrapping lookup in the mip level ``lod`` (int, (M,)) at texel coords s, u."""
    out = np.empty(len(s), np.float32)
    for L in np.unique(lod):
        m = lod == L
        img = levels[L]
        n = img.shape[0]
        x = s[m] / 2.0 ** L - 0.5
        y = u[m] / 2.0 ** L - 0.5
        x0 = np.floor(x)
        y0 = np.floor(y)
        fx = (x - x0).astype(np.float32)
        fy = (y - y0).astype(np.float32)
        xi = x0.astype(np.int64) % n
        yi = y0.astype(np.int64) % n
        xj = (xi + 1) % n
        yj = (yi + 1) % n
        out[m] = ((img[yi, xi] * (1 - fx) + img[yi, xj] * fx) * (1 - fy)
                  + (img[yj, xi] * (1 - fx) + img[yj, xj] * fx) * fy)
    return out


def _clip_near(poly: np.ndarray, near: float = 1e-3) -> np.ndarray:
    """Clip a convex polygon (n,3) in camera coordinates to z >= near (Sutherland-Hodgman)."""
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        if a[2] >= near:
            out.append(a)
        if (a[2] >= near) != (b[2] >= near):
            out.append(a + (near - a[2]) / (b[2] - a[2]) * (b - a))
    return np.array(out).reshape(-1, 3)


def render(room: Room, cam: CameraModel, rng: np.random.Generator | None = None,
           noise_grey: float = 1.0) -> np.ndarray:
    """Ray cast ``room`` through ``cam`` (pinhole + its lens distortion): (H, W) uint8."""
    W, H = cam.width, cam.height
    K = cam.K
    uu, vv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    Rt = cam.R_cam_station.T                            # world <- camera
    distorted = bool(np.any(cam.dist))
    if distorted:                                       # each pixel's undistorted ray
        xy = cam.pixels_to_normalized(np.stack([uu.ravel(), vv.ravel()], axis=1))
        xc, yc = xy[:, 0].reshape(H, W), xy[:, 1].reshape(H, W)
    else:
        xc, yc = (uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1]
    dx, dy, dz = (Rt[k, 0] * xc + Rt[k, 1] * yc + Rt[k, 2] for k in range(3))  # (H,W) each
    C = cam.center_station
    depth = np.full((H, W), np.inf)
    hit_q = np.full((H, W), -1, np.int32)
    hit_s = np.zeros((H, W))
    hit_u = np.zeros((H, W))
    f = 0.5 * (K[0, 0] + K[1, 1])
    for qi, q in enumerate(room.quads):
        n = np.cross(q.e1, q.e2)
        if n @ (C - q.origin) <= 0:           # seen from behind
            continue
        corners = q.origin + np.array([[0, 0], [1, 0], [1, 1], [0, 1]]) @ np.stack([q.e1, q.e2])
        poly = _clip_near(cam.station_to_cam(corners))
        if len(poly) < 3:
            continue
        if distorted:   # the pixels whose rays fall in the polygon's pinhole bounding box
            lo, hi = (poly[:, :2] / poly[:, 2:]).min(0), (poly[:, :2] / poly[:, 2:]).max(0)
            m = (xc >= lo[0]) & (xc <= hi[0]) & (yc >= lo[1]) & (yc <= hi[1])
            rows, cols = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
            if not len(rows):
                continue
            c0, r0, c1, r1 = cols[0] - 1, rows[0] - 1, cols[-1] + 1, rows[-1] + 1
        else:
            uv = poly[:, :2] / poly[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
            c0, r0 = np.floor(uv.min(0)).astype(int) - 1
            c1, r1 = np.ceil(uv.max(0)).astype(int) + 1
        c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, W - 1), min(r1, H - 1)
        if c0 > c1 or r0 > r1:
            continue
        sl = (slice(r0, r1 + 1), slice(c0, c1 + 1))     # views: no copies of the ray arrays
        X, Y, Z = dx[sl], dy[sl], dz[sl]
        rel = C - q.origin
        e1n, e2n = q.e1 / (q.e1 @ q.e1), q.e2 / (q.e2 @ q.e2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (n @ (q.origin - C)) / (X * n[0] + Y * n[1] + Z * n[2])
        s = rel @ e1n + t * (X * e1n[0] + Y * e1n[1] + Z * e1n[2])
        u = rel @ e2n + t * (X * e2n[0] + Y * e2n[1] + Z * e2n[2])
        ok = (t > 1e-6) & (t < depth[sl]) & (s >= 0) & (s <= 1) & (u >= 0) & (u <= 1)
        depth[sl][ok] = t[ok]
        hit_q[sl][ok] = qi
        hit_s[sl][ok] = s[ok]
        hit_u[sl][ok] = u[ok]
    d = np.stack([dx.ravel(), dy.ravel(), dz.ravel()], axis=1)
    dnorm = np.linalg.norm(d, axis=1)
    depth, hit_q, hit_s, hit_u = depth.ravel(), hit_q.ravel(), hit_s.ravel(), hit_u.ravel()
    img = np.zeros(W * H, np.float32)
    valid = hit_q >= 0
    light = np.array([0.3, -0.5, 0.81])
    light /= np.linalg.norm(light)
    order = np.argsort(hit_q, kind="stable")          # pixels grouped by the quad they hit
    bounds = np.searchsorted(hit_q[order], np.arange(len(room.quads) + 1))
    for qi in np.unique(hit_q[valid]):
        q = room.quads[qi]
        m = order[bounds[qi]:bounds[qi + 1]]
        n = np.cross(q.e1, q.e2)
        n /= np.linalg.norm(n)
        dist = depth[m] * dnorm[m]
        cos_t = np.abs(d[m] @ n) / dnorm[m]
        footprint = dist / (f * np.sqrt(np.maximum(cos_t, 0.05)))       # metres per pixel
        levels = room.textures[q.tex]
        lod = np.clip(np.round(np.log2(np.maximum(footprint / q.texel_m, 1.0))), 0, len(levels) - 1)
        s = hit_s[m] * np.linalg.norm(q.e1) / q.texel_m + q.offset[0]
        u = hit_u[m] * np.linalg.norm(q.e2) / q.texel_m + q.offset[1]
        tex = _sample(levels, s, u, lod.astype(int))
        if q.emissive:
            img[m] = q.emissive + 0.1 * tex
        else:
            shade = 0.45 + 0.4 * max(float(n @ light), 0.0) + 0.15 * abs(n[2])
            img[m] = 1.3 * q.albedo * tex * shade * (0.75 + 0.5 / (1.0 + 0.3 * dist))
    out = img.reshape(H, W) * 255.0
    if rng is not None and noise_grey > 0:
        out = out + rng.normal(0.0, noise_grey, out.shape)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


# --- the robot, its rig and its path ---------------------------------------------------------
@dataclass(frozen=True)
class Rig:
    """A parallel stereo pair on the robot: the right camera ``baseline_m`` to the right of the
    left one, both ``height_m`` above the floor, pitched down by ``pitch_deg``."""

    baseline_m: float = 0.30
    height_m: float = 1.0
    pitch_deg: float = 8.0
    f_px: float = 480.0
    width: int = WIDTH
    height: int = HEIGHT
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)  # both cameras

    def K(self) -> np.ndarray:
        return np.array([[self.f_px, 0, (self.width - 1) / 2], [0, self.f_px, (self.height - 1) / 2],
                         [0, 0, 1.0]])

    def cameras_rig(self) -> tuple[CameraModel, CameraModel]:
        """The pair in the rig frame (= left camera frame): x_right = I x_left + (-b, 0, 0)."""
        dist = np.array(self.dist, float)
        left = CameraModel("left", self.width, self.height, self.K(), dist)
        right = CameraModel("right", self.width, self.height, self.K(), dist, np.eye(3),
                            np.array([-self.baseline_m, 0.0, 0.0]))
        return left, right

    def cameras_world(self, x: float, y: float, yaw: float) -> tuple[CameraModel, CameraModel]:
        """Both cameras posed in the world for the robot at (x, y) heading ``yaw`` (rad)."""
        fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
        p = np.radians(self.pitch_deg)
        view = np.cos(p) * fwd - np.sin(p) * np.array([0, 0, 1.0])
        c_left = np.array([x, y, self.height_m])
        R, t = look_at(c_left, c_left + view)
        left, right_cam = self.cameras_rig()
        c_right = c_left + self.baseline_m * right
        return left.with_pose(R, t), right_cam.with_pose(R, -R @ c_right)


def turtle_path(start: tuple[float, float, float], program: list[tuple], step_m: float) -> np.ndarray:
    """Poses (N+1, 3) of x, y, yaw (rad) of a car-like robot, one row per step.

    program: ("straight", n_steps) or ("turn", total_deg, n_steps) - an arc driven over n steps
    (a car turns while moving; no turning on the spot).
    """
    x, y, yaw = start
    out = [(x, y, yaw)]
    for cmd in program:
        n = cmd[-1]
        dyaw = np.radians(cmd[1]) / n if cmd[0] == "turn" else 0.0
        for _ in range(n):
            # exact arc: the chord leaves at half the heading change
            chord = step_m if dyaw == 0 else 2 * step_m / dyaw * np.sin(dyaw / 2)
            x += chord * np.cos(yaw + dyaw / 2)
            y += chord * np.sin(yaw + dyaw / 2)
            yaw += dyaw
            out.append((x, y, yaw))
    return np.array(out)


SHORT_PROGRAM = [("straight", 3), ("turn", 45, 2), ("straight", 2), ("turn", -75, 2),
                 ("straight", 1), ("turn", 30, 1)]          # 11 steps: straight, diagonal, turns


LONG_PROGRAM = [("straight", 56), ("turn", 45, 6), ("straight", 6), ("turn", 45, 6),
                ("straight", 30), ("turn", 90, 12), ("straight", 44), ("turn", 60, 8),
                ("straight", 14), ("turn", 30, 5), ("straight", 10), ("turn", 90, 12),
                ("straight", 12), ("turn", -30, 5), ("straight", 6), ("turn", 30, 5),
                ("straight", 6)]            # 243 steps, one lap of the room with 30-90 deg turns


def path(kind: str = "short") -> np.ndarray:
    """The paper-like 11-step path ("short", 0.4 m steps) or a 243-step loop ("long", 0.15 m)."""
    if kind == "short":
        return turtle_path((-4.0, -2.5, 0.0), SHORT_PROGRAM, 0.4)
    if kind == "long":
        return turtle_path((-5.5, -3.3, 0.0), LONG_PROGRAM, 0.15)
    raise ValueError(f"unknown path {kind!r}: use 'short' or 'long'")


def pose_matrix(cam: CameraModel) -> np.ndarray:
    """4x4 camera-to-world transform of ``cam``."""
    T = np.eye(4)
    T[:3, :3] = cam.R_cam_station.T
    T[:3, 3] = cam.center_station
    return T


# --- writer ----------------------------------------------------------------------------------
def write_sequence(directory: str | os.PathLike, kind: str = "short", seed: int = 0,
                   rig: Rig = Rig(), poses_xy_yaw: np.ndarray | None = None,
                   noise_grey: float = 1.0, progress=None) -> Path:
    """Render a stereo sequence into ``directory`` (our format, see the module docstring).

    poses_xy_yaw: (N+1, 3) robot poses; default :func:`path` (kind). Returns the directory.
    """
    directory = Path(directory)
    (directory / "left").mkdir(parents=True, exist_ok=True)
    (directory / "right").mkdir(parents=True, exist_ok=True)
    room = Room(seed)
    poses = path(kind) if poses_xy_yaw is None else np.asarray(poses_xy_yaw, float)
    left0, right0 = rig.cameras_rig()
    (directory / "stereo.json").write_text(json.dumps({"left": left0.to_dict(),
                                                        "right": right0.to_dict()}, indent=1))
    T0_inv = None
    lines = []
    for i, (x, y, yaw) in enumerate(poses):
        left, right = rig.cameras_world(x, y, yaw)
        for name, cam, k in (("left", left, 0), ("right", right, 1)):
            img = render(room, cam, np.random.default_rng([seed, i, k]), noise_grey)
            cv2.imwrite(str(directory / name / f"{i:06d}.png"), img)
        T = pose_matrix(left)
        if T0_inv is None:
            T0_inv = np.linalg.inv(T)
        lines.append(" ".join(f"{v:.12e}" for v in (T0_inv @ T)[:3].ravel()))
        if progress:
            progress(i, len(poses))
    (directory / "poses.txt").write_text("\n".join(lines) + "\n")
    meta = {"format": "station-odometry", "version": 1, "kind": kind, "seed": seed,
            "n_images": len(poses), "n_steps": len(poses) - 1, "image_size": [rig.width, rig.height],
            "baseline_m": rig.baseline_m, "camera_height_m": rig.height_m,
            "pitch_deg": rig.pitch_deg, "robot_xy_yaw_world": poses.tolist()}
    (directory / "sequence.json").write_text(json.dumps(meta, indent=1))
    return directory


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m simulators.odometry_scene",
                                 description="render a simulated stereo sequence for `station odometry DIR`")
    ap.add_argument("directory", metavar="DIR", help="a new or empty folder")
    ap.add_argument("--kind", choices=("short", "long"), default="short",
                    help="'short' (11 steps, like the paper's) or 'long' (243 steps round a room)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the scene and the sensor noise (default 0)")
    args = ap.parse_args(argv)
    directory = Path(args.directory)
    if directory.exists() and (not directory.is_dir() or any(directory.iterdir())):
        print(f"{directory}: not a new or empty folder; a sequence is never written over another",
              file=sys.stderr)
        return 2
    print(f"rendering the {args.kind} simulated sequence into {directory} ...", file=sys.stderr)
    write_sequence(directory, args.kind, seed=args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
