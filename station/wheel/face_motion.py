"""A wheel's spin axis from its face turning as one rigid body (runout compensation).

The lip's plane gives the spin axis through the change of its normal between the roll's
captures, and that change carries the lip edge's view-dependent bias (docs/procedures.md,
"What limits it"). The face and the tyre's lettering give it independently: the wheel's motion
from one capture to another is a rotation about its spin axis (and a translation), whatever
the lip's edge does.

1. At every capture, corners of the face matched in the pair and triangulated
   (station/wheel/face_points.py); the rigid motion from the reference capture (the last) to
   each other one, by consensus, where the face pattern's turn puts the points.
2. Each point's patch, laid on the face's plane, is followed into both cameras of every
   capture by a Lucas-Kanade shift (``followed``): one physical patch in all 2K views,
   triangulated with its covariance, from each shift's own (a patch on an edge is known across
   the edge, not along it). Every capture's points are anchors, not only the
   reference's (``followed_all``): a corner one view finds another misses.
3. One fit of all captures (``joint_fit``): the axis (2 dof), a turn and a translation per
   capture and the body's points, the residuals whitened by each point's covariance and
   weighted down by a Cauchy loss (corners that are not one physical point, a caliper seen
   through the spokes). Its axis covariance, scaled by ``COVARIANCE_SCALE``, joins the lip's
   spin axis by generalised least squares (``combined``).

Shapes: K captures, N points; X (K,N,3) station metres, C (K,N,3,3) m^2, ok (K,N) bool; turns
(K,) rad about the outward axis, relative to the reference capture (the last).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from calibration.camera_model import CameraModel
from station.wheel.face_points import PIXEL_NOISE_PX, FacePoints, matched, rigid_ransac, stereo_points, triangulated
from station.wheel.rim_pattern import FacePose
from station.wheel.runout import SpinAxis, rotation_matrix, spin_axis
from station.wheel.steering_axis import rotation_vector
from station.wheel.uncertainty import axis_basis, normal_from

PATCH_HALF = 5                  # patches of 11 x 11 samples, about a pixel apart in the first camera
CONSENSUS_M = 0.8e-3            # a point follows the coarse motion within this
REMATCH_M = 1.0e-3              # points found again within this of the coarse motion's prediction
REMATCH_DESCRIPTOR = 400.0      # with a first camera's descriptor this close
DUPLICATE_M = 1.5e-3            # another capture's corner this near a point already anchored is that point
TRACK_REPROJECTION_PX = 0.5     # a followed patch's two views meet within this
FLOOR_M = 0.05e-3               # added to every point's position noise (the patch's own texture)
CAUCHY_SCALE = 2.5              # the Cauchy loss's width, in robust sigmas of the whitened residuals
MIN_POINTS = 30                 # points followed through every capture, else no face axis
COVARIANCE_SCALE = 1.885        # the face's stated axis sd is scaled by this: what it understated from the
#                                 reference capture's points alone (bench/runout.py's seeds 3200-3209); from
#                                 every capture's points it understates by 2.375 there, but joined with that
#                                 scale toe measured worse (docs/procedures.md, step 4)
AGREEMENT_CHI2 = 13.8           # the lip's and the face's axes further apart (chi-square, 2 dof, 0.1 %): the
#                                 joined axis's stated variance grows with their distance (``with_face``)


@dataclass(frozen=True)
class FaceSpin:
    """The spin axis (3,) unit, outward, from the face's motion, its (3,3) covariance (rad^2,
    scaled by COVARIANCE_SCALE^2), and the number of points that carried it."""

    axis_station: np.ndarray
    cov_axis: np.ndarray
    points: int


def _sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples (...) of ``image`` (H,W) float32 at ``uv`` (...,2); NaN outside."""
    shape = uv.shape[:-1]
    flat = uv.reshape(-1, 2).astype(np.float32)
    width = 4096                          # cv2.remap's maps: under 32767 a side
    rows = -(-len(flat) // width)
    padded = np.full((rows * width, 2), -10.0, np.float32)
    padded[:len(flat)] = flat
    out = cv2.remap(image, padded[:, 0].reshape(rows, width), padded[:, 1].reshape(rows, width), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return out.reshape(-1)[:len(flat)].reshape(shape)


def _normalised(patches: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Patches (N,m,m) less their mean, over their norm; and the norms (N,) (NaN samples: off
    the image, left out)."""
    seen = np.isfinite(patches)
    mean = np.where(seen, patches, 0).sum((1, 2), keepdims=True) / np.maximum(seen.sum((1, 2), keepdims=True), 1)
    p = patches - mean
    norm = np.sqrt(np.nansum(p ** 2, axis=(1, 2), keepdims=True)) + 1e-9
    return p / norm, norm[:, 0, 0]


def lucas_kanade(template: np.ndarray, image: np.ndarray, uv0: np.ndarray, iterations: int = 12):
    """The shift (N,2) px that best lays each normalised ``template`` patch (N,m,m) on ``image``
    (H,W) float32 sampled at ``uv0`` (N,m,m,2) + shift (normalised patches, Gauss-Newton);
    whether it converged (N,) bool; the shift's covariance (N,2,2) px^2: the residual's variance
    through the inverse of the patch's gradient matrix (large along an edge, where the patch only
    knows its position across it), plus ``PIXEL_NOISE_PX`` on each coordinate."""
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3) / 8
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3) / 8
    d = np.zeros((len(template), 2))
    step = np.zeros_like(d)
    H = np.tile(np.eye(2), (len(template), 1, 1))
    for _ in range(iterations):
        uv = uv0 + d[:, None, None, :]
        patch, norm = _normalised(_sample(image, uv))
        jx, jy = _sample(gx, uv) / norm[:, None, None], _sample(gy, uv) / norm[:, None, None]
        r = patch - template
        ok = np.isfinite(r) & np.isfinite(jx) & np.isfinite(jy)
        r, jx, jy = np.where(ok, r, 0), np.where(ok, jx, 0), np.where(ok, jy, 0)
        H = np.stack([np.stack([(jx * jx).sum((1, 2)), (jx * jy).sum((1, 2))], -1),
                      np.stack([(jx * jy).sum((1, 2)), (jy * jy).sum((1, 2))], -1)], -2)
        H += (1e-6 * np.trace(H, axis1=1, axis2=2) + 1e-9)[:, None, None] * np.eye(2)  # a one-way texture
        g = np.stack([(jx * r).sum((1, 2)), (jy * r).sum((1, 2))], -1)
        step = np.clip(np.nan_to_num(-np.linalg.solve(H, g[..., None])[..., 0]), -1.5, 1.5)
        d += step
        if np.max(np.abs(step)) < 1e-3:
            break
    last = _sample(image, uv0 + d[:, None, None, :])
    fitted, norm = _normalised(last)
    seen = np.isfinite(last)
    residual = np.where(seen, fitted - template, 0.0)
    variance = (residual ** 2).sum((1, 2)) / np.maximum(seen.sum((1, 2)) - 2, 1)
    cov = variance[:, None, None] * np.linalg.inv(H) + PIXEL_NOISE_PX ** 2 * np.eye(2)
    converged = ((np.abs(step).max(1) < 0.02) & (np.linalg.norm(d, axis=1) < 3.0)
                 & (seen.mean((1, 2)) >= 0.9) & (norm > 1e-3))                # the patch on the image
    return d, converged & np.isfinite(cov).all((1, 2)), cov


def _plane_grid(X: np.ndarray, axis: np.ndarray, step_m: np.ndarray) -> np.ndarray:
    """(N,m,m,3) grids on the planes through points X (N,3) across ``axis`` (3,), ``step_m`` (N,) apart."""
    _, u, v = axis_basis(axis)
    g = np.arange(-PATCH_HALF, PATCH_HALF + 1, dtype=float)
    return X[:, None, None, :] + step_m[:, None, None, None] * (g[None, :, None, None] * u + g[None, None, :, None] * v)


def followed(images: list[tuple[np.ndarray, np.ndarray]], cameras: tuple[CameraModel, CameraModel],
             anchors: FacePoints, axis: np.ndarray, motions: list, source: int = -1
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points ``anchors`` of capture ``source`` (the reference, the last, unless told)
    followed into every capture: ``images`` (K) of the pair; ``motions`` (K) (R (3,3), t (3,))
    from the source capture to each capture, or (None, None). Returns X (K,N,3), C (K,N,3,3),
    ok (K,N)."""
    cam_a, cam_b = cameras
    K, N = len(images), len(anchors)
    depth = (anchors.X_station - cam_a.center_station) @ cam_a.optical_axis_station
    grid = _plane_grid(anchors.X_station, axis, depth / cam_a.K[0, 0])                # (N,m,m,3)
    m = grid.shape[1]
    reference_a = np.asarray(images[source][0], np.float32)
    template, _ = _normalised(_sample(reference_a, cam_a.project(grid.reshape(-1, 3)).reshape(N, m, m, 2)))
    X, C = np.full((K, N, 3), np.nan), np.full((K, N, 3, 3), np.nan)
    ok = np.zeros((K, N), bool)
    for k, (R, t) in enumerate(motions):
        if R is None:
            continue
        moved = grid.reshape(-1, 3) @ R.T + t
        centres = anchors.X_station @ R.T + t
        uv, cov_uv, conv = [], [], np.ones(N, bool)
        for q, cam in enumerate(cameras):
            if k == source % K and q == 0:     # the template's own view: the refined corner
                uv.append(anchors.uv_a)
                cov_uv.append(np.broadcast_to(PIXEL_NOISE_PX ** 2 * np.eye(2), (N, 2, 2)))
                continue
            shift, c, cov_shift = lucas_kanade(template, np.asarray(images[k][q], np.float32),
                                               cam.project(moved).reshape(N, m, m, 2))
            uv.append(cam.project(centres) + shift)
            cov_uv.append(np.where(c[:, None, None], cov_shift, np.eye(2)))
            conv &= c
        X[k], C[k], err = triangulated(cam_a, cam_b, uv[0], uv[1], *cov_uv)
        ok[k] = conv & (err < TRACK_REPROJECTION_PX)
    return X, C, ok


def followed_all(images: list[tuple[np.ndarray, np.ndarray]], cameras: tuple[CameraModel, CameraModel],
                 points: list[FacePoints], axis: np.ndarray, motions: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every capture's points ``points`` (K) followed into every capture (``followed``): a corner
    one capture's view finds and the reference's does not still carries the face. ``motions`` (K)
    from the reference (the last) to each capture, or (None, None). A point within
    ``DUPLICATE_M`` of one already anchored (the reference's first, then the others in turn, put
    in the reference by the motions) is left out: one physical corner counts once. Returns X
    (K,N,3), C (K,N,3,3), ok (K,N), N the anchors of all captures."""
    K = len(images)
    taken = np.zeros((0, 3))
    out = []
    for j in [K - 1] + list(range(K - 1)):
        Rj, tj = motions[j]
        if Rj is None or not len(points[j]):
            continue
        in_reference = (points[j].X_station - tj) @ Rj                              # R^T (X - t), (N_j,3)
        if len(taken):
            new = np.linalg.norm(in_reference[:, None] - taken[None], axis=2).min(1) > DUPLICATE_M
        else:
            new = np.ones(len(in_reference), bool)
        if not new.any():
            continue
        anchors = FacePoints(*(np.asarray(f)[new] for f in (points[j].X_station, points[j].cov, points[j].uv_a,
                                                             points[j].uv_b, points[j].desc_a, points[j].desc_b)))
        from_j = [(None, None) if R is None else (R @ Rj.T, t - R @ Rj.T @ tj) for R, t in motions]
        axis_j = Rj @ axis
        out.append(followed(images, cameras, anchors, axis_j, from_j, source=j))
        taken = np.vstack([taken, in_reference[new]])
    return tuple(np.concatenate(parts, axis=1) for parts in zip(*out))


def coarse_motion(before: FacePoints, after: FacePoints, centre_before: np.ndarray, centre_after: np.ndarray,
                  axis: np.ndarray, turn_rad: float):
    """(R, t) taking ``before``'s points to ``after``'s (the wheel turned by ``turn_rad`` about
    ``axis`` and its centre moved), or (None, None): consensus on descriptor matches near the
    predicted places, then again on the points found near that motion's prediction."""
    R0 = rotation_matrix(axis, turn_rad)
    i, j = matched(before, after, centre_after + (before.X_station - centre_before) @ R0.T)
    R, t, inliers = rigid_ransac(before.X_station[i], after.X_station[j], CONSENSUS_M)
    if R is None:
        return None, None
    predicted = before.X_station @ R.T + t
    D = np.linalg.norm(predicted[:, None] - after.X_station[None], axis=2)
    a = np.arange(len(predicted))
    b = D.argmin(1)
    again = ((D[a, b] < REMATCH_M) & (D.argmin(0)[b] == a)
             & (np.linalg.norm(before.desc_a[a] - after.desc_a[b], axis=1) < REMATCH_DESCRIPTOR))
    if again.sum() >= 4:
        R2, t2, _ = rigid_ransac(before.X_station[a[again]], after.X_station[b[again]], CONSENSUS_M)
        if R2 is not None:
            return R2, t2
    return R, t


def joint_fit(X: np.ndarray, C: np.ndarray, ok: np.ndarray, axis0: np.ndarray, turns0: np.ndarray, outer: int = 6):
    """The common axis of the captures' rigid motions: X_k = Rot(a, theta_k) Y + t_k (the last
    capture the reference: theta = 0, t = 0), the body's points Y (N,3) eliminated (for given
    motions, each point's weighted mean over the captures), residuals whitened by C (+ FLOOR_M^2) and Cauchy-weighted. ``axis0`` (3,),
    ``turns0`` (K,) start it. Returns (axis (3,), cov (3,3) rad^2 unscaled x chi^2/dof, points
    that carried it)."""
    K, N, _ = X.shape
    basis = axis_basis(axis0)
    cov = np.where(ok[..., None, None], C + FLOOR_M ** 2 * np.eye(3), np.eye(3))
    info = np.linalg.inv(cov)                                                          # (K,N,3,3)
    L = np.linalg.cholesky(info)
    Xz = np.where(ok[..., None], X, 0.0)
    seen = ok.sum(0) >= 2
    weight = (ok & seen[None]).astype(float)
    p = np.concatenate([np.zeros(2), turns0[:-1], np.zeros(3 * (K - 1))])
    for k in range(K - 1):
        both = ok[k] & ok[-1]
        R = rotation_matrix(axis0, turns0[k])
        p[2 + (K - 1) + 3 * k:5 + (K - 1) + 3 * k] = (X[k][both] - X[-1][both] @ R.T).mean(0) if both.any() else 0.0

    def motions(p):
        a = normal_from(p[:2], *basis)
        turns = np.append(p[2:K + 1], 0.0)
        t = np.vstack([p[K + 1:].reshape(K - 1, 3), np.zeros(3)])
        return a, [rotation_matrix(a, th) for th in turns], t

    def body(p, w):
        _, Rs, t = motions(p)
        A, b = np.zeros((N, 3, 3)), np.zeros((N, 3))
        for k in range(K):
            RtW = Rs[k].T @ (w[k][:, None, None] * info[k])
            A += RtW @ Rs[k]
            b += (RtW @ (Xz[k] - t[k])[..., None])[..., 0]
        return np.linalg.solve(A + 1e-12 * np.eye(3), b[..., None])[..., 0]

    def residuals(p, w, unweighted=None):
        _, Rs, t = motions(p)
        Y = body(p, w)                                 # variable projection: the body's best points for p
        e = Xz - np.einsum("kij,nj->kni", np.stack(Rs), Y) - t[:, None, :]            # (K,N,3)
        r = np.einsum("knji,knj->kni", L, e)                                          # L^T e
        return (np.sqrt(w if unweighted is None else unweighted)[..., None] * r).ravel()

    usable = ok & seen[None]
    for _ in range(outer):
        fit = least_squares(residuals, p, args=(weight,), method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12)
        p = fit.x
        m2 = (residuals(p, weight, usable.astype(float)).reshape(K, N, 3) ** 2).sum(-1) / 3
        # a robust sigma of the whitened residuals (Gaussian 3-D residuals: median of m2 0.4549), at
        # least a tenth of the stated noise (exact data would weigh out round-off)
        scale = max(np.sqrt(np.median(m2[usable]) / 0.4549), 0.1)
        weight = usable / (1 + m2 / (CAUCHY_SCALE * scale) ** 2)
    dof = max(fit.fun.size - p.size - 3 * int(seen.sum()), 1)
    chi2 = float(fit.fun @ fit.fun / dof)
    a, _, _ = motions(p)
    cov_p = np.linalg.pinv(fit.jac.T @ fit.jac)[:2, :2]
    h = 1e-7
    J = np.stack([(normal_from(p[:2] + h * e, *basis) - normal_from(p[:2] - h * e, *basis)) / (2 * h) for e in np.eye(2)], 1)
    return a, J @ cov_p @ J.T * chi2, int((weight > 0.5).all(0).sum())


def face_spin_axis(images: list[tuple[np.ndarray, np.ndarray]], cameras: tuple[CameraModel, CameraModel],
                   poses: list[FacePose], turns_rad: np.ndarray) -> FaceSpin | None:
    """The spin axis from the face's motion over the captures: ``images`` (K) of the pair (its
    first camera, then its second), ``poses`` (K) the lip circles (centre, axis, radius),
    ``turns_rad`` (K,) the face pattern's turns relative to the last capture. None when fewer
    than MIN_POINTS points follow the face through every capture."""
    toward = np.sign(np.asarray(poses[-1].axis_station) @ (cameras[0].center_station - poses[-1].center_station))
    if toward < 0:  # the turns are about the axis as given: about the flipped one they change sign
        poses = [FacePose(p.center_station, -np.asarray(p.axis_station), p.radius_m) for p in poses]
    axis = np.asarray(poses[-1].axis_station, float)
    turns = np.asarray(turns_rad, float) * (1.0 if toward >= 0 else -1.0)
    points = [stereo_points(im, cameras, pose, th) for im, pose, th in zip(images, poses, turns)]
    reference = points[-1]
    if len(reference) < MIN_POINTS:
        return None
    motions = [coarse_motion(reference, p, poses[-1].center_station, pose.center_station, axis, th)
               for p, pose, th in zip(points[:-1], poses[:-1], turns[:-1])] + [(np.eye(3), np.zeros(3))]
    X, C, ok = followed_all(images, cameras, points, axis, motions)
    if (ok.all(0)).sum() < MIN_POINTS:
        return None
    turned = [k for k in range(len(turns) - 1) if motions[k][0] is not None]
    if not turned:
        return None
    R = motions[max(turned, key=lambda k: abs(turns[k]))][0]
    axis0 = rotation_vector(R)
    axis0 /= np.linalg.norm(axis0)
    axis0 = axis0 if axis0 @ axis > 0 else -axis0
    a, cov, n = joint_fit(X, C, ok, axis0, np.where(np.isfinite(turns), turns, 0.0))
    if n < MIN_POINTS:
        return None
    return FaceSpin(a, cov * COVARIANCE_SCALE ** 2, n)


def with_face(spin: SpinAxis, face: FaceSpin, lip_radius_m: float) -> SpinAxis | None:
    """The lip's spin axis ``spin`` joined with the face's (``combined``); the runout is then the
    tilt of the lip's normal against the joined axis. Where the two disagree beyond their
    covariances (squared Mahalanobis distance d^2 over ``AGREEMENT_CHI2``) one of them is off by
    more than it says, and which cannot be told: the joined axis is stated d^2 / 2 times less
    certain (its variance). None (the lip's axis stays) when the lip's has no covariance."""
    if not np.all(np.isfinite(spin.cov_axis)):
        return None
    a, cov = combined(spin.axis_station, spin.cov_axis, face.axis_station, face.cov_axis)
    d2 = disagreement(spin.axis_station, spin.cov_axis, face.axis_station, face.cov_axis)
    return spin_axis(a, cov * (d2 / 2 if d2 > AGREEMENT_CHI2 else 1.0), spin.normal_at_zero, spin.misfit_deg,
                     lip_radius_m)


def disagreement(axis_a: np.ndarray, cov_a: np.ndarray, axis_b: np.ndarray, cov_b: np.ndarray) -> float:
    """The squared Mahalanobis distance between two estimates (3,) of one unit axis across it,
    under the sum of their (3,3) covariances (chi-square with 2 degrees of freedom)."""
    _, u, v = axis_basis(axis_a)
    B = np.stack([u, v], 1)
    z = B.T @ (np.asarray(axis_b) - axis_a)
    return float(z @ np.linalg.solve(B.T @ (cov_a + cov_b) @ B, z))


def combined(axis_a: np.ndarray, cov_a: np.ndarray, axis_b: np.ndarray, cov_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two estimates (3,) of one unit axis with their (3,3) covariances joined by generalised
    least squares across the axis: (axis (3,), cov (3,3))."""
    _, u, v = axis_basis(axis_a)
    B = np.stack([u, v], 1)                                                            # (3,2)
    z_b = B.T @ (np.asarray(axis_b) - axis_a)
    S_a, S_b = B.T @ cov_a @ B, B.T @ cov_b @ B
    cov = np.linalg.inv(np.linalg.inv(S_a) + np.linalg.inv(S_b))
    z = cov @ np.linalg.solve(S_b, z_b)
    a = axis_a + B @ z
    return a / np.linalg.norm(a), B @ cov @ B.T
