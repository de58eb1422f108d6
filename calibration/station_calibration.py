"""A whole station calibration from box detections (paper section 2.3, then refinement).

Per wheel (one stereo pair; left = precision camera, right = reference camera):

1. **Intrinsics** of each camera from N box poses in front of the pair: the paper's closed form
   (calibration/box_linear.py) on every view that shows two faces gives K per view; their
   median starts a bundle adjustment of K, the distortion k1 k2 p1 p2 k3 and every view's pose
   on all detected corners (calibration/refine.py).
2. **Pose in the station frame** from the box at the wheel's fixture (``calibration.fixture``:
   bottom centre + yaw): the box corners are then known in the station frame, so the paper's
   eq. 4 holds with world = station; its closed form on the undistorted corners gives
   ``R_cam_station, t``.
3. **Joint pair refinement**: both cameras' intrinsics and station poses, and the box poses of
   step 1, refined together on every corner of every view, with the fixture view held at its
   known pose (the station frame). The pair's relative pose is then constrained by all N + 1
   views, not by the fixture alone. Standard deviations come from this adjustment.
4. **Limits** (``calibration.limits``): reprojection RMS, focal-length std, position std; a camera
   beyond any of them is named in a :class:`CalibrationRejected`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np

from calibration.box_detect import BoxDetection
from calibration.box_linear import paper_box_calibration
from calibration.box_target import BoxTarget, box_pose_on_floor
from calibration.calib_file import CameraCalibration, StationCalibration
from calibration.camera_model import CameraModel, matrix_to_rodrigues
from calibration.errors import CalibrationError, CalibrationRejected
from calibration.refine import (INTRINSIC_NAMES, BundleProblem, BundleResult, Observation, intrinsics_vector,
                               rotations)

MIN_VIEW_POINTS = 12      # a view with fewer corners is not used
MIN_INTRINSIC_VIEWS = 3


@dataclass
class IntrinsicsEstimate:
    cam_id: str
    K: np.ndarray
    dist: np.ndarray
    view_R: dict      # view index -> R_cam_box (3,3)
    view_t: dict      # view index -> t_cam_box (3,)
    linear_K: list    # per-view K of the paper's closed form (all corners)
    bundle: BundleResult
    vertex_K: list = field(default_factory=list)  # per-view K from the detected vertices only


@dataclass
class PairResult:
    wheel: str
    left: str
    right: str
    bundle: BundleResult
    cameras: dict = field(default_factory=dict)   # cam id -> CameraCalibration
    linear_fixture: dict = field(default_factory=dict)  # cam id -> (R, t) of the paper's closed form
    linear_K: dict = field(default_factory=dict)        # cam id -> median K of the paper's closed form
    vertex_K: dict = field(default_factory=dict)        # cam id -> median K from the vertices only


def _usable(det: BoxDetection | None) -> bool:
    return det is not None and det.n_points >= MIN_VIEW_POINTS


def _linear_points(det: BoxDetection):
    """Points for the paper's closed form: every detected corner. The paper uses the eight
    vertices; its equations hold for any box points of known position, and the corners are
    measured, whereas our vertex pixels are extrapolated (BoxDetection.vertex_pixels)."""
    return det.points_box, det.pixels


def paper_vertices(det: BoxDetection):
    """(V,3) box vertices B_k and (V,2) their pixels, for the vertices the detection placed."""
    vis = det.vertex_mask & np.all(np.isfinite(det.vertices_box), axis=1)
    return det.vertices_box[vis], det.vertex_pixels[vis]


def calibrate_intrinsics(cam_id: str, width: int, height: int,
                         detections: list[BoxDetection | None]) -> IntrinsicsEstimate:
    """Step 1 for one camera. detections: one per box pose (None or few points: skipped)."""
    views = [i for i, d in enumerate(detections) if _usable(d)]
    if len(views) < MIN_INTRINSIC_VIEWS:
        raise CalibrationError(f"camera {cam_id}: the box was found in only {len(views)} of {len(detections)} "
                               f"poses; at least {MIN_INTRINSIC_VIEWS} are needed for its intrinsics",
                               hint=f"check that {cam_id} sees the box (focus, light, lens cap) and repeat")
    linear_K = []
    for i in views:
        try:
            res = paper_box_calibration(*_linear_points(detections[i]))
        except CalibrationError:
            continue  # one face only (coplanar) or degenerate: no closed form from this view
        if res.K[0, 0] > 0 and np.all(res.depths > 0):
            linear_K.append(res.K)
    vertex_K = []
    for i in views:  # the paper's points proper: the vertices found from the face boards
        d = detections[i]
        B, uv = paper_vertices(d)
        if len(B) >= 6:
            try:
                res = paper_box_calibration(B, uv)
                vertex_K.append(res.K)
            except CalibrationError:
                pass
    if not linear_K:
        raise CalibrationError(f"camera {cam_id}: no box pose shows two faces of the box, so the paper's "
                               "closed form has no solution (all points coplanar)",
                               hint="turn the box so that the camera sees two of its faces")
    K0 = np.median(np.array(linear_K), axis=0)
    K0[0, 1] = K0[1, 0] = K0[2, 0] = K0[2, 1] = 0
    K0[2, 2] = 1
    rvecs, tvecs, obs = [], [], []
    for j, i in enumerate(views):
        d = detections[i]
        ok, r, t = cv2.solvePnP(d.points_box.astype(np.float64), d.pixels.astype(np.float64), K0, None,
                                flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            raise CalibrationError(f"camera {cam_id}: cannot find the box pose in view {i}")
        rvecs.append(r.ravel())
        tvecs.append(t.ravel())
        obs.append(Observation(0, j, d.points_box, d.pixels, d.ids))
    prob = BundleProblem([intrinsics_vector(K0, np.zeros(5))], [[0, 0, 0]], [[0, 0, 0]], rvecs, tvecs, obs,
                         free_cam_pose=[False])
    res = prob.solve()
    Rv = rotations(res.view_rvec)
    return IntrinsicsEstimate(cam_id, res.K(0), res.dist(0), {i: Rv[j] for j, i in enumerate(views)},
                              {i: res.view_t[j] for j, i in enumerate(views)}, linear_K, res, vertex_K)


def _undistorted_pixels(K, dist, pixels):
    m = CameraModel("tmp", 1, 1, K, dist)
    return m.pixels_to_normalized(pixels) @ K[:2, :2].T + K[:2, 2]


def fixture_pose(cam_id: str, intr: IntrinsicsEstimate, det: BoxDetection | None, R_sb, t_sb, wheel: str):
    """Step 2: the paper's closed form with world = station on the fixture view (undistorted)."""
    if not _usable(det):
        n = 0 if det is None else det.n_points
        raise CalibrationError(f"camera {cam_id}: the box at the fixture of wheel {wheel} was not found "
                               f"({n} corners)", hint=f"place the box on the {wheel} fixture, check {cam_id}'s view and light")
    pts_station = det.points_box @ R_sb.T + t_sb
    uv = _undistorted_pixels(intr.K, intr.dist, det.pixels)
    ok = np.all(np.isfinite(uv), axis=1)
    try:
        lin = paper_box_calibration(pts_station[ok], uv[ok])
    except CalibrationError as e:
        raise CalibrationError(f"camera {cam_id} at the fixture of wheel {wheel}: {e}", hint=e.hint) from None
    return lin.R, lin.t


def calibrate_pair(wheel: str, left: str, right: str, sizes: dict, intrinsic_dets: dict,
                   fixture_dets: dict, fixture: tuple[np.ndarray, np.ndarray],
                   progress: Callable[[str], None] = lambda s: None) -> PairResult:
    """Steps 1-3 for one pair. intrinsic_dets: cam id -> [BoxDetection | None] per pose.
    fixture_dets: cam id -> BoxDetection. fixture: (R_station_box, t_station_box)."""
    R_sb, t_sb = fixture
    intr, pose0 = {}, {}
    for cam in (left, right):
        progress(f"{cam}: intrinsics from {sum(_usable(d) for d in intrinsic_dets[cam])} box poses")
        intr[cam] = calibrate_intrinsics(cam, *sizes[cam], intrinsic_dets[cam])
        pose0[cam] = fixture_pose(cam, intr[cam], fixture_dets[cam], R_sb, t_sb, wheel)
    progress(f"pair {wheel} ({left}, {right}): joint refinement")
    n_views = len(intrinsic_dets[left])
    fixture_view = n_views
    view_rvec = np.zeros((n_views + 1, 3))
    view_t = np.zeros((n_views + 1, 3))
    used = np.zeros(n_views + 1, bool)
    view_rvec[fixture_view] = matrix_to_rodrigues(R_sb)
    view_t[fixture_view] = t_sb
    used[fixture_view] = True
    for v in range(n_views):
        for cam in (left, right):  # box pose in the station frame via the camera that saw it
            if v in intr[cam].view_R:
                R_cs, t_cs = pose0[cam]
                R_cb, t_cb = intr[cam].view_R[v], intr[cam].view_t[v]
                view_rvec[v] = matrix_to_rodrigues(R_cs.T @ R_cb)
                view_t[v] = R_cs.T @ (t_cb - t_cs)
                used[v] = True
                break
    obs = []
    for c, cam in enumerate((left, right)):
        for v, d in enumerate(list(intrinsic_dets[cam]) + [fixture_dets[cam]]):
            if _usable(d) and (v == fixture_view or v in intr[cam].view_R):
                obs.append(Observation(c, v, d.points_box, d.pixels, d.ids))
    cam_rvec = [matrix_to_rodrigues(pose0[c][0]) for c in (left, right)]
    cam_C = [-pose0[c][0].T @ pose0[c][1] for c in (left, right)]
    prob = BundleProblem([intrinsics_vector(intr[c].K, intr[c].dist) for c in (left, right)], cam_rvec, cam_C,
                         view_rvec, view_t, obs, free_view=used & (np.arange(n_views + 1) != fixture_view))
    res = prob.solve()
    result = PairResult(wheel, left, right, res, linear_fixture=pose0,
                        linear_K={c: np.median(np.array(intr[c].linear_K), axis=0) for c in (left, right)},
                        vertex_K={c: np.median(np.array(intr[c].vertex_K), axis=0) for c in (left, right)
                                  if intr[c].vertex_K})
    for c, cam in enumerate((left, right)):
        w, h = sizes[cam]
        model = CameraModel(cam, w, h, res.K(c), res.dist(c), res.R_cam_station(c), res.t_cam_station(c))
        std = {name: float(s) for name, s in zip(INTRINSIC_NAMES, res.std_intrinsics[c])}
        std["position_m"] = res.std_cam_C[c].tolist()
        std["rotation_deg"] = np.degrees(res.std_cam_rvec[c]).tolist()
        result.cameras[cam] = CameraCalibration(model, float(res.rms_px[c]), int(res.n_points[c]), std)
    return result


def check_limits(calib: StationCalibration, limits) -> list[str]:
    """Reasons (one per camera and limit) the calibration is beyond ``calibration.limits``."""
    reasons = []
    for cam_id, c in calib.cameras.items():
        if not np.isfinite(c.reprojection_rms_px) or c.reprojection_rms_px > limits.reprojection_rms_px:
            reasons.append(f"camera {cam_id}: reprojection RMS {c.reprojection_rms_px:.3f} px exceeds the limit "
                           f"{limits.reprojection_rms_px} px")
        f_std = max(c.std.get("fx", np.inf), c.std.get("fy", np.inf))
        if not f_std <= limits.focal_std_px:
            reasons.append(f"camera {cam_id}: focal length std {f_std:.3f} px exceeds the limit {limits.focal_std_px} px")
        p_std = float(np.max(c.std.get("position_m", [np.inf])))
        if not p_std <= limits.position_std_m:
            reasons.append(f"camera {cam_id}: position std {p_std * 1000:.3f} mm exceeds the limit "
                           f"{limits.position_std_m * 1000:.3f} mm")
    return reasons


def fixture_poses(config) -> dict:
    """wheel -> (R_station_box, t_station_box) from ``calibration.fixture``."""
    return {w: box_pose_on_floor(f.position_m, f.yaw_deg) for w, f in config.calibration.fixture.items()}


def assemble(config, pair_results: dict[str, PairResult], box: BoxTarget) -> StationCalibration:
    cams = {}
    for cam_id in config.cameras:
        for pr in pair_results.values():
            if cam_id in pr.cameras:
                cams[cam_id] = pr.cameras[cam_id]
    pairs = {w: (pr.left, pr.right) for w, pr in pair_results.items()}
    notes = {"box": {"source": box.source, "size_m": list(box.size_m), "square_m": box.square_m},
             "fixture": {w: {"position_m": list(f.position_m), "yaw_deg": f.yaw_deg}
                         for w, f in config.calibration.fixture.items()},
             "intrinsic_poses": int(config.calibration.intrinsic_poses),
             "outliers": {pr.wheel: pr.bundle.outliers for pr in pair_results.values()}}
    covs = {w: pr.bundle.cov_cameras for w, pr in pair_results.items() if pr.bundle.cov_cameras is not None}
    return StationCalibration(cams, pairs, station_name=config.name, notes=notes, pair_covariance=covs)
