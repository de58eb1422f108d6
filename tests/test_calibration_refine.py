"""Refinement: bundle adjustment against truth and against cv2.calibrateCamera; the pair flow
with the fixture; refusals naming the camera."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.box_detect import BoxDetector
from calibration.camera_model import CameraModel, rodrigues_to_matrix
from calibration.errors import CalibrationError
from calibration.refine import BundleProblem, Observation, intrinsics_vector
from calibration.station_calibration import calibrate_intrinsics, calibrate_pair, check_limits, fixture_poses, assemble
from station.config import load_box, load_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_calibration_detect import render_box  # noqa: E402  (the small exact renderer)

BOX_YAML = Path(__file__).resolve().parent.parent / "config" / "box.yaml"


@pytest.fixture(scope="module")
def box():
    return load_box(BOX_YAML)


@pytest.fixture(scope="module")
def station():
    from simulators.sim_operator import SimOperator
    from simulators.world import SimWorld
    config = load_config()
    world = SimWorld.from_config(config)
    return config, world, SimOperator(world, load_box(config.box_path), config, seed=3)


def _views(rng, n):
    out = []
    base = np.array([[0, 1.0, 0], [0, 0, -1], [-1, 0, 0]])  # box z up -> camera -y
    for _ in range(n):
        a = np.radians(rng.uniform(20, 70))
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
        R = rodrigues_to_matrix(np.r_[rng.uniform(-0.3, 0.3, 2), 0]) @ base @ Rz
        t = np.array([rng.uniform(-0.1, 0.1), rng.uniform(0.2, 0.35), rng.uniform(1.25, 1.5)])
        out.append((R, t))
    return out


@pytest.mark.slow
def test_refined_intrinsics_at_least_as_good_as_opencv_on_the_same_detections(box):
    """Rendered images (noise sigma 2 grey levels), detected corners, then both calibrations."""
    rng = np.random.default_rng(11)
    K = np.array([[1790.0, 0, 652.0], [0, 1791.0, 503.0], [0, 0, 1]])
    det = BoxDetector(box)
    dets = []
    for R, t in _views(rng, 6):
        img = render_box(box, K, R, t, noise=2.0, rng=rng, ss=3)
        dets.append(det.detect(img))
    assert all(d.n_points > 100 for d in dets) and sum(len(d.faces) == 2 for d in dets) >= 2
    ours = calibrate_intrinsics("camX", 1280, 1024, dets)
    K_guess = np.array([[1800.0, 0, 639.5], [0, 1800.0, 511.5], [0, 0, 1]])
    obj = [d.points_box.astype(np.float32) for d in dets]
    img = [d.pixels.astype(np.float32) for d in dets]
    _, K_cv, d_cv, _, _ = cv2.calibrateCamera(obj, img, (1280, 1024), K_guess.copy(), np.zeros(5),
                                              flags=cv2.CALIB_USE_INTRINSIC_GUESS)
    err_ours = np.abs(ours.K - K)[[0, 1, 0, 1], [0, 1, 2, 2]]
    err_cv = np.abs(K_cv - K)[[0, 1, 0, 1], [0, 1, 2, 2]]
    assert np.linalg.norm(err_ours) <= np.linalg.norm(err_cv) * 1.05 + 1e-6, (err_ours, err_cv)
    assert err_ours[0] / K[0, 0] < 2e-3
    assert ours.bundle.rms_px[0] < 0.2


def test_bundle_std_is_consistent_with_the_scatter(box):
    """Exact projections + Gaussian noise: the reported std matches the actual error spread."""
    rng = np.random.default_rng(4)
    K = np.array([[1800.0, 0, 645.0], [0, 1800.0, 509.0], [0, 0, 1]])
    dist = np.array([-0.15, 0.08, 2e-4, -3e-4, 0.0])
    errs, stds = [], []
    views = _views(rng, 8)
    for trial in range(4):
        obs, rv, tv = [], [], []
        for v, (R, t) in enumerate(views):
            cam = CameraModel("c", 1280, 1024, K, dist, R, t)
            uv = cam.project(box.points_box)
            ok = cam.in_image(uv) & (box.points_box @ np.array([0, 0, 1]) < 0.59)
            obs.append(Observation(0, v, box.points_box[ok], uv[ok] + rng.normal(0, 0.1, (ok.sum(), 2))))
            rv.append(cv2.Rodrigues(R)[0].ravel())
            tv.append(t)
        res = BundleProblem([intrinsics_vector(K * [[1.01], [1.01], [1]], np.zeros(5))], [[0, 0, 0]], [[0, 0, 0]],
                            rv, tv, obs, free_cam_pose=[False]).solve()
        errs.append(res.intrinsics[0, 0] - K[0, 0])
        stds.append(res.std_intrinsics[0, 0])
        assert abs(res.rms_px[0] - 0.1 * np.sqrt(2)) < 0.02
    assert np.sqrt(np.mean(np.square(errs))) < 4 * np.mean(stds)
    assert np.mean(stds) < 0.5


def _pair_detections(station, wheel, n_poses, sigma, rng, hide=None):
    from simulators.sim_operator import projected_detection
    config, world, op = station
    p = config.pairs[wheel]
    ids = [p.precision, p.reference]
    dets = {c: [] for c in ids}
    box = op.box
    for i in range(n_poses):
        R, t = op.intrinsic_pose(ids, i)
        for c in ids:
            dets[c].append(projected_detection(box, world.cameras[c], R, t, sigma, rng))
    fix = fixture_poses(config)[wheel]
    fdet = {c: projected_detection(box, world.cameras[c], *fix, sigma, rng) for c in ids}
    if hide:
        fdet[hide] = fdet[hide].select(np.zeros(fdet[hide].n_points, bool))
    return ids, dets, fdet, fix


def test_pair_flow_recovers_the_true_station_cameras(station):
    config, world, _ = station
    rng = np.random.default_rng(5)
    ids, dets, fdet, fix = _pair_detections(station, "FL", 6, 0.05, rng)
    res = calibrate_pair("FL", *ids, {c: (1280, 1024) for c in ids}, dets, fdet, fix)
    for c in ids:
        est, true = res.cameras[c].model, world.cameras[c]
        assert abs(est.K[0, 0] - true.K[0, 0]) < 1.0
        assert np.abs(est.K[:2, 2] - true.K[:2, 2]).max() < 1.5
        assert np.linalg.norm(est.center_station - true.center_station) < 0.5e-3
        assert res.cameras[c].reprojection_rms_px < 0.1
        assert 0 < res.cameras[c].std["fx"] < 1.0
    # the joint covariance of both cameras (for the measurement's stated uncertainty)
    cov = res.bundle.cov_cameras
    assert cov.shape == (30, 30) and np.allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > -1e-12 * np.abs(cov).max())
    for k, c in enumerate(ids):
        np.testing.assert_allclose(np.sqrt(np.diag(cov))[15 * k:15 * k + 9], res.bundle.std_intrinsics[k], rtol=1e-9)
        np.testing.assert_allclose(np.sqrt(np.diag(cov))[15 * k + 12:15 * k + 15], res.bundle.std_cam_C[k], rtol=1e-9)
        # check points in the wheel volume reproject like the truth
        X = np.random.default_rng(1).uniform([-1.0, 1.0, 0.05], [-0.6, 1.7, 0.6], (200, 3))
        d = est.project(X) - true.project(X)
        assert np.sqrt(np.mean(np.sum(d ** 2, axis=1))) < 0.1


def test_box_not_found_at_the_fixture_names_the_camera(station):
    rng = np.random.default_rng(6)
    ids, dets, fdet, fix = _pair_detections(station, "RR", 4, 0.05, rng, hide="cam8")
    with pytest.raises(CalibrationError, match="cam8.*fixture of wheel RR"):
        calibrate_pair("RR", *ids, {c: (1280, 1024) for c in ids}, dets, fdet, fix)


def test_too_few_box_poses_name_the_camera(station):
    rng = np.random.default_rng(7)
    ids, dets, fdet, fix = _pair_detections(station, "RL", 3, 0.05, rng)
    dets[ids[0]][1] = None
    with pytest.raises(CalibrationError, match=f"camera {ids[0]}.*only 2 of 3"):
        calibrate_pair("RL", *ids, {c: (1280, 1024) for c in ids}, dets, fdet, fix)


def test_one_face_only_is_refused_as_coplanar(box):
    rng = np.random.default_rng(8)
    K = np.array([[1800.0, 0, 640.0], [0, 1800.0, 512.0], [0, 0, 1]])
    dets = []
    from calibration.box_detect import BoxDetection
    for R, t in _views(rng, 4):
        cam = CameraModel("c", 1280, 1024, K, np.zeros(5), R, t)
        f = box.face("px")
        P = f.charuco_box
        dets.append(BoxDetection(np.arange(len(P)), P, cam.project(P), np.zeros(len(P), int), np.full((8, 2), np.nan)))
    with pytest.raises(CalibrationError, match="coplanar"):
        calibrate_intrinsics("cam5", 1280, 1024, dets)


@pytest.mark.slow
def test_levenberg_marquardt_reaches_the_same_minimum_as_scipy(box):
    rng = np.random.default_rng(9)
    K = np.array([[1800.0, 0, 645.0], [0, 1800.0, 509.0], [0, 0, 1]])
    dist = np.array([-0.12, 0.05, 1e-4, -2e-4, 0.0])
    obs, rv, tv = [], [], []
    for v, (R, t) in enumerate(_views(rng, 4)):
        cam = CameraModel("c", 1280, 1024, K, dist, R, t)
        uv = cam.project(box.points_box)
        ok = cam.in_image(uv) & (box.points_box[:, 2] < 0.59)
        obs.append(Observation(0, v, box.points_box[ok], uv[ok] + rng.normal(0, 0.1, (ok.sum(), 2))))
        rv.append(cv2.Rodrigues(R)[0].ravel() + 0.01)
        tv.append(t + 0.01)
    args = ([intrinsics_vector(K * [[1.01], [1.01], [1]], np.zeros(5))], [[0, 0, 0]], [[0, 0, 0]], rv, tv, obs)
    a = BundleProblem(*args, free_cam_pose=[False], solver="lm").solve()
    b = BundleProblem(*args, free_cam_pose=[False], solver="scipy").solve()
    # the same minimum: differences far below the parameters' own uncertainty
    assert np.all(np.abs(a.intrinsics - b.intrinsics) < 1e-3 * a.std_intrinsics)
    assert np.allclose(a.std_intrinsics, b.std_intrinsics, rtol=1e-3)
