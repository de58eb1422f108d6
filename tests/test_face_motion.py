"""The spin axis from the face's rigid motion (station/wheel/face_motion.py, face_points.py): the
joint fit returns the axis of exact motions, keeps it when points that do not turn (a caliper)
are among them, the consensus finds a rigid motion among outliers, and two axes join by their
covariances, and a patch followed by Lucas-Kanade states its shift's uncertainty."""

import cv2
import numpy as np
import pytest

from station.wheel.face_motion import (AGREEMENT_CHI2, FaceSpin, _normalised, _sample, combined, joint_fit, lucas_kanade,
                                      with_face)
from calibration.rigid_motion import kabsch
from station.wheel.face_points import rigid_ransac
from station.wheel.runout import fit_spin_axis, rotation_matrix


def _angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _face(seed, n=80, turns=(-0.43, 0.43, 0.02, 0.0), noise_m=0.0, static_share=0.0):
    """Points of a wheel's face (radius 0.05-0.3 m, depth 0-60 mm) turned about a tilted axis at
    K captures (the last the reference) and moved along the runway: X (K,N,3), axis (3,)."""
    rng = np.random.default_rng(seed)
    axis = np.array([1.0, 0.004, 0.003])
    axis /= np.linalg.norm(axis)
    u = np.cross(axis, [0, 0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    r, phi = rng.uniform(0.05, 0.3, n), rng.uniform(0, 2 * np.pi, n)
    centre = np.array([0.8, 1.35, 0.33])
    Y = centre + (r * np.cos(phi))[:, None] * u + (r * np.sin(phi))[:, None] * v + rng.uniform(-0.06, 0, n)[:, None] * axis
    X = []
    for k, th in enumerate(turns):
        t = np.array([0.0, -0.32 * th, 0.0])                    # rolled: the centre travels th x rolling radius
        Xk = (Y - centre) @ rotation_matrix(axis, th).T + centre + t
        still = np.arange(n) < static_share * n                 # a caliper: it does not turn
        Xk[still] = Y[still] + t
        X.append(Xk + rng.normal(0, noise_m, Xk.shape))
    return np.array(X), axis, np.array(turns)


def test_joint_fit_returns_the_axis_of_exact_motions():
    X, axis, turns = _face(1)
    C = np.broadcast_to(np.eye(3) * 1e-12, X.shape + (3,)).copy()
    start = axis + np.array([0.0, 0.01, -0.008])
    a, cov, n = joint_fit(X, C, np.ones(X.shape[:2], bool), start / np.linalg.norm(start), turns + 0.01)
    assert _angle_deg(a, axis) < 1e-6
    assert n == X.shape[1]
    assert cov.shape == (3, 3) and np.all(np.isfinite(cov))


def test_joint_fit_keeps_the_axis_when_some_points_do_not_turn():
    X, axis, turns = _face(2, n=120, noise_m=0.05e-3, static_share=0.15)
    C = np.broadcast_to(np.eye(3) * (0.05e-3) ** 2, X.shape + (3,)).copy()
    a, cov, n = joint_fit(X, C, np.ones(X.shape[:2], bool), axis, turns)
    assert _angle_deg(a, axis) < 0.01
    sd = np.degrees(np.sqrt(np.trace(cov) / 2))
    assert _angle_deg(a, axis) < 4 * sd
    assert n <= 0.9 * X.shape[1]                                # the still points weighed out
    # a plain rigid fit of all points through the end captures is pulled away by the caliper
    R, _ = kabsch(X[1], X[0])
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    assert _angle_deg(w * np.sign(w @ axis), axis) > 5 * _angle_deg(a, axis)


def test_rigid_ransac_finds_the_motion_among_outliers():
    rng = np.random.default_rng(3)
    A = rng.uniform(-0.3, 0.3, (60, 3))
    R = rotation_matrix(np.array([0.2, 0.9, 0.1]) / np.linalg.norm([0.2, 0.9, 0.1]), 0.4)
    t = np.array([0.01, -0.1, 0.02])
    B = A @ R.T + t
    B[:20] += rng.uniform(0.01, 0.05, (20, 3))                  # a third matched wrongly
    R_found, t_found, inliers = rigid_ransac(A, B, 1e-3)
    assert inliers[20:].all() and not inliers[:20].any()
    np.testing.assert_allclose(R_found, R, atol=1e-9)
    np.testing.assert_allclose(t_found, t, atol=1e-9)
    assert rigid_ransac(A[:2], B[:2], 1e-3)[0] is None


def test_two_axes_join_by_their_covariances():
    a = np.array([1.0, 0.0, 0.0])
    b = np.array([1.0, 0.002, -0.001])
    b /= np.linalg.norm(b)
    cov_a = np.diag([0.0, 1e-8, 4e-8])                          # sure across y, less so across z
    cov_b = np.diag([0.0, 4e-8, 1e-8])
    c, cov = combined(a, cov_a, b, cov_b)
    # per component the inverse-variance mean: y 0.2 of b's offset, z 0.8 of it
    assert c[1] == pytest.approx(0.2 * b[1] / b[0], rel=1e-3)
    assert c[2] == pytest.approx(0.8 * b[2] / b[0], rel=1e-3)
    assert cov[1, 1] == pytest.approx(0.8e-8, rel=1e-3) and cov[2, 2] == pytest.approx(0.8e-8, rel=1e-3)
    assert np.linalg.norm(c) == pytest.approx(1.0)


def test_a_face_axis_that_disagrees_with_the_lips_makes_the_joined_axis_less_certain():
    axis = np.array([1.0, 0.0, 0.0])
    turns = np.radians([0.0, -25.0, 25.0, 0.0])
    m = np.array([1.0, 0.003, 0.002])
    m /= np.linalg.norm(m)
    normals = np.array([rotation_matrix(axis, th) @ m for th in turns])
    lip = fit_spin_axis(normals, turns, np.broadcast_to(np.eye(3) * 1e-8, (4, 3, 3)), 0.22)
    sd = np.sqrt(np.trace(lip.cov_axis) / 2)
    near = FaceSpin(np.array([1.0, 1.0 * sd, 0.0]) / np.linalg.norm([1.0, 1.0 * sd, 0.0]), lip.cov_axis.copy(), 80)
    joined = with_face(lip, near, 0.22)
    assert joined is not None                                   # within their noise: halfway between
    assert joined.axis_station[1] == pytest.approx(0.5 * sd, rel=0.05)
    far_off = 2 * sd * np.sqrt(AGREEMENT_CHI2)                  # well beyond both covariances
    far = FaceSpin(np.array([1.0, far_off, 0.0]) / np.linalg.norm([1.0, far_off, 0.0]), lip.cov_axis.copy(), 80)
    apart = with_face(lip, far, 0.22)
    assert apart.axis_station[1] == pytest.approx(0.5 * far_off, rel=0.05)
    d2 = far_off ** 2 / (2 * sd ** 2)                           # each component's variance sd^2, summed
    np.testing.assert_allclose(apart.cov_axis, joined.cov_axis * d2 / 2, rtol=0.05)


def test_a_patch_on_an_edge_is_known_across_it_not_along_it():
    """Lucas-Kanade finds a textured patch's shift and states it about equally well known both
    ways; a patch on a strong straight edge over a faint texture is found across the edge, and
    its stated uncertainty along the edge is the larger."""
    rng = np.random.default_rng(5)
    xx = np.mgrid[0:120, 0:120][1].astype(float)
    textured = (cv2.GaussianBlur(rng.uniform(0, 1, (120, 120)), (0, 0), 2.0) * 4000).astype(np.float32)
    edge = (1000 + 3000 / (1 + np.exp(-(xx - 60.3) / 1.2)) + 0.3 * textured).astype(np.float32)  # a vertical edge
    g = np.arange(-5, 6, dtype=float)
    grid = np.stack(np.meshgrid(g, g, indexing="xy"), -1)[None] + np.array([60.0, 60.0])      # (1,11,11,2)
    true_shift = np.array([0.4, -0.3])
    sd = {}
    for name, image in (("textured", textured), ("edge", edge)):
        template, _ = _normalised(_sample(image, grid))
        shift, ok, cov = lucas_kanade(template, (image + rng.normal(0, 20, image.shape)).astype(np.float32),
                                      grid - true_shift)
        assert ok[0]
        assert abs(shift[0, 0] - true_shift[0]) < 0.1                # across the edge
        sd[name] = np.sqrt(np.diag(cov[0]))
    assert abs(sd["textured"][1] / sd["textured"][0] - 1) < 0.2
    assert sd["edge"][1] ** 2 > 1.8 * sd["edge"][0] ** 2          # variances
