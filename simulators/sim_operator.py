"""The simulated operator: moves the calibration box in a SimWorld (station/operator.py protocol).

Intrinsic poses are random but valid: the box stands near the pair's fixture, shifted, raised,
yawed and tilted (roll/pitch up to ~20 deg), so focal length, principal point and distortion
are all exercised; a pose is accepted only when every camera of the pair sees two faces and
most of their corners fall inside its image (an operator checks the live picture too).
The fixture pose is exactly the configured one. Every pose is kept in :attr:`poses` (truth).
"""

from __future__ import annotations

import numpy as np

from calibration.box_detect import BoxDetection, face_homographies, vertices_from_homographies
from calibration.box_target import POINT_ID_STRIDE, BoxTarget, box_pose_on_floor
from calibration.camera_model import rodrigues_to_matrix
from simulators.scene import Scene, TexturedQuad


class SimOperator:
    def __init__(self, world, box: BoxTarget, config, seed: int = 0):
        self.world = world
        self.box = box
        self.config = config
        self.rng = np.random.default_rng([int(seed), 0xB0C5])
        self.poses: dict = {}   # ("intrinsics", wheel, i) or ("fixture", wheel) -> (R_station_box, t)
        self.lighting = world.random_lighting(np.random.default_rng([int(seed), 1]))

    def _show(self, R, t) -> None:
        quads = tuple(TexturedQuad(c, tex) for c, tex in self.box.face_quads(R, t))
        self.world.set_scene(Scene(quads=quads, lighting=self.lighting))

    def _visible_fraction(self, cam_id: str, R, t) -> tuple[int, float]:
        cam = self.world.cameras[cam_id]
        faces, inside = 0, []
        for f in self.box.faces:
            n = R @ f.normal
            centre = R @ f.corners_box.mean(axis=0) + t
            if n @ (cam.center_station - centre) / np.linalg.norm(cam.center_station - centre) > 0.25:
                faces += 1
                uv = cam.project(f.charuco_box @ R.T + t)
                inside.append(cam.in_image(uv, margin=10))
        frac = float(np.mean(np.concatenate(inside))) if inside else 0.0
        return faces, frac

    def intrinsic_pose(self, cam_ids: list[str], pose_index: int):
        wheel = self.config.cameras[cam_ids[0]].wheel
        fix = self.config.calibration.fixture[wheel]
        base = np.asarray(fix.position_m, float)
        for _ in range(500):
            yaw = fix.yaw_deg + self.rng.uniform(-20, 20)
            R0, _ = box_pose_on_floor(base, yaw)
            tilt = rodrigues_to_matrix(np.radians(np.r_[self.rng.uniform(-20, 20, 2), 0.0]))
            R = tilt @ R0
            t = base + np.array([self.rng.uniform(-0.15, 0.25) * np.sign(base[0] or 1),
                                 self.rng.uniform(-0.2, 0.2), self.rng.uniform(0.02, 0.15)])
            ok = True
            for cam in cam_ids:
                faces, frac = self._visible_fraction(cam, R, t)
                ok &= faces >= 2 and frac > 0.8
            if ok:
                return R, t
        raise RuntimeError(f"no valid box pose found for {cam_ids}")

    # --- the Operator protocol -------------------------------------------------------------------
    def place_box_for_intrinsics(self, cam_ids: list[str], pose_index: int) -> None:
        R, t = self.intrinsic_pose(cam_ids, pose_index)
        wheel = self.config.cameras[cam_ids[0]].wheel
        self.poses[("intrinsics", wheel, pose_index)] = (R, t)
        self._show(R, t)

    def place_box_at_fixture(self, wheel: str) -> None:
        fix = self.config.calibration.fixture[wheel]
        R, t = box_pose_on_floor(fix.position_m, fix.yaw_deg)
        self.poses[("fixture", wheel)] = (R, t)
        self._show(R, t)

    def done(self) -> None:
        self.world.set_scene(Scene())


def projected_detection(box: BoxTarget, camera, R_station_box, t_station_box, sigma_px: float = 0.0,
                        rng: np.random.Generator | None = None, margin_px: float = 10.0) -> BoxDetection:
    """What a perfect detector would report (no rendering): the corners of the faces turned
    toward ``camera`` that project inside its image, plus Gaussian noise of ``sigma_px``.
    For tests and benchmarks of the calibration maths at a chosen corner accuracy."""
    ids, pts, px = [], [], []
    for f in box.faces:
        centre = R_station_box @ f.corners_box.mean(axis=0) + t_station_box
        view = camera.center_station - centre
        if (R_station_box @ f.normal) @ view / np.linalg.norm(view) <= 0.25:
            continue
        P = f.charuco_box
        uv = camera.project(P @ np.asarray(R_station_box).T + t_station_box)
        ok = camera.in_image(uv, margin=margin_px)
        ids.append(f.index * POINT_ID_STRIDE + np.flatnonzero(ok))
        pts.append(P[ok])
        px.append(uv[ok])
    if not ids:
        return BoxDetection(np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0, int),
                            np.full((8, 2), np.nan))
    ids_all, px_all = np.concatenate(ids), np.vstack(px)
    if sigma_px:
        px_all = px_all + (rng or np.random.default_rng(0)).normal(0, sigma_px, px_all.shape)
    vertices = vertices_from_homographies(box, face_homographies(box, ids_all, px_all))  # as the detector does
    return BoxDetection(ids_all, np.vstack(pts), px_all, ids_all // POINT_ID_STRIDE, vertices, {},
                        box.vertices.copy())
