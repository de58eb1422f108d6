"""Bundle adjustment of box observations: every parameter, distortion included, by
``scipy.optimize.least_squares`` on all detected points.

One problem type covers both uses:

* **intrinsics of one camera** from several box poses: one camera whose pose is held at the
  identity (its frame is the "station" frame), every box pose free;
* **a stereo pair in the station frame**: two cameras (intrinsics and pose free), the box
  poses shown for the intrinsics free, and the box at the fixture held at its known pose
  (this fixes the gauge: the station frame is the fixture's).

Model for box point ``B`` (box frame) in view ``v`` seen by camera ``c``::

    X_station = R(view_rvec[v]) B + view_t[v]
    X_cam     = R(cam_rvec[c]) (X_station - cam_C[c])        # R_cam_station, centre C
    pixel     = K_c distort((X/Z, Y/Z), k1 k2 p1 p2 k3)       # docs/conventions.md

Intrinsics vector per camera: ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)``. The standard
deviation of every parameter comes from the Gauss-Newton covariance
``s^2 (J^T J)^-1`` with ``s^2 = |r|^2 / (m - n)`` at the solution.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix

from calibration.camera_model import distort_normalized
from calibration.errors import CalibrationError

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def rotations(rvecs: np.ndarray) -> np.ndarray:
    """(V,3) rotation vectors -> (V,3,3) matrices (Rodrigues, vectorised)."""
    rvecs = np.asarray(rvecs, float).reshape(-1, 3)
    theta = np.linalg.norm(rvecs, axis=1)
    small = theta < 1e-12
    k = rvecs / np.where(small, 1.0, theta)[:, None]
    Kx = np.zeros((len(rvecs), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2] = -k[:, 2], k[:, 1]
    Kx[:, 1, 0], Kx[:, 1, 2] = k[:, 2], -k[:, 0]
    Kx[:, 2, 0], Kx[:, 2, 1] = -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], (1 - np.cos(theta))[:, None, None]
    R = np.eye(3) + s * Kx + c * (Kx @ Kx)
    R[small] = np.eye(3) + _skew(rvecs[small])
    return R


def _skew(w: np.ndarray) -> np.ndarray:
    S = np.zeros((len(w), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    return S - S.transpose(0, 2, 1)


def intrinsics_vector(K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(9,) fx fy cx cy k1 k2 p1 p2 k3: the adjustment estimates OpenCV's five terms only."""
    dist = np.asarray(dist, float).ravel()
    if dist.size != 5:
        raise CalibrationError(f"the bundle adjustment estimates k1 k2 p1 p2 k3, not {dist.size} distortion "
                               "coefficients (OpenCV's rational and thin-prism terms come only with an import)")
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *dist])


def K_from_vector(x: np.ndarray) -> np.ndarray:
    return np.array([[x[0], 0, x[2]], [0, x[1], x[3]], [0, 0, 1.0]])


@dataclass
class Observation:
    """Points of the box seen by camera ``cam`` in view ``view``.

    points_box: (N,3) box frame. pixels: (N,2). ids: (N,) point ids (for reports), optional.
    """

    cam: int
    view: int
    points_box: np.ndarray
    pixels: np.ndarray
    ids: np.ndarray | None = None


@dataclass
class BundleResult:
    """Solution. intrinsics (C,9); cam_rvec, cam_C (C,3); view_rvec, view_t (V,3).

    std_*: same shapes, standard deviations (0 for held parameters). rms_px: (C,) per camera.
    residuals: list of (N,2) per observation (after outlier removal, NaN where removed).
    """

    intrinsics: np.ndarray
    cam_rvec: np.ndarray
    cam_C: np.ndarray
    view_rvec: np.ndarray
    view_t: np.ndarray
    std_intrinsics: np.ndarray
    std_cam_rvec: np.ndarray
    std_cam_C: np.ndarray
    rms_px: np.ndarray
    n_points: np.ndarray
    residuals: list = field(default_factory=list)
    cov_cameras: np.ndarray | None = None  # (15C,15C) per camera [9 intrinsics, rvec, C] (0: held)
    outliers: int = 0
    sigma_px: float = 0.0
    iterations: int = 0

    def K(self, c: int) -> np.ndarray:
        return K_from_vector(self.intrinsics[c])

    def dist(self, c: int) -> np.ndarray:
        return self.intrinsics[c, 4:].copy()

    def R_cam_station(self, c: int) -> np.ndarray:
        return rotations(self.cam_rvec[c])[0]

    def t_cam_station(self, c: int) -> np.ndarray:
        return -self.R_cam_station(c) @ self.cam_C[c]


class BundleProblem:
    """Parameters (initial values) + which are free + observations. :meth:`solve` refines."""

    def __init__(self, intrinsics, cam_rvec, cam_C, view_rvec, view_t, observations,
                 free_cam_pose=None, free_view=None, free_intrinsics=None, solver: str = "lm"):
        self.solver = solver
        self.intrinsics = np.array(intrinsics, float).reshape(-1, 9)
        self.cam_rvec = np.array(cam_rvec, float).reshape(-1, 3)
        self.cam_C = np.array(cam_C, float).reshape(-1, 3)
        self.view_rvec = np.array(view_rvec, float).reshape(-1, 3)
        self.view_t = np.array(view_t, float).reshape(-1, 3)
        n_cam, n_view = len(self.intrinsics), len(self.view_rvec)
        self.observations = [o for o in observations if len(o.pixels)]
        self.free_cam_pose = np.ones(n_cam, bool) if free_cam_pose is None else np.asarray(free_cam_pose, bool)
        self.free_view = np.ones(n_view, bool) if free_view is None else np.asarray(free_view, bool)
        fi = np.ones((n_cam, 9), bool) if free_intrinsics is None else np.asarray(free_intrinsics, bool)
        self.free_intrinsics = np.broadcast_to(fi, (n_cam, 9)).copy()
        # flatten observations
        self.obs_cam = np.concatenate([np.full(len(o.pixels), o.cam) for o in self.observations])
        self.obs_view = np.concatenate([np.full(len(o.pixels), o.view) for o in self.observations])
        self.obs_B = np.vstack([o.points_box for o in self.observations]).astype(float)
        self.obs_uv = np.vstack([o.pixels for o in self.observations]).astype(float)
        self.active = np.ones(len(self.obs_uv), bool)

    # --- parameter vector ----------------------------------------------------------------------
    def _full(self) -> np.ndarray:
        return np.concatenate([self.intrinsics.ravel(), self.cam_rvec.ravel(), self.cam_C.ravel(),
                               self.view_rvec.ravel(), self.view_t.ravel()])

    def _free_mask(self) -> np.ndarray:
        return np.concatenate([self.free_intrinsics.ravel(), np.repeat(self.free_cam_pose, 3),
                               np.repeat(self.free_cam_pose, 3), np.repeat(self.free_view, 3),
                               np.repeat(self.free_view, 3)])

    def _unpack(self, full: np.ndarray):
        nc, nv = len(self.intrinsics), len(self.view_rvec)
        i = 0
        out = []
        for size, shape in ((nc * 9, (nc, 9)), (nc * 3, (nc, 3)), (nc * 3, (nc, 3)),
                            (nv * 3, (nv, 3)), (nv * 3, (nv, 3))):
            out.append(full[i:i + size].reshape(shape))
            i += size
        return out

    def project(self, full: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
        """(M,2) predicted pixels of the observations ``idx`` (default: active ones)."""
        intr, crv, cC, vrv, vt = self._unpack(full)
        idx = np.flatnonzero(self.active) if idx is None else idx
        c, v = self.obs_cam[idx], self.obs_view[idx]
        Rv = rotations(vrv)[v]
        Xs = np.einsum("nij,nj->ni", Rv, self.obs_B[idx]) + vt[v]
        Rc = rotations(crv)[c]
        Xc = np.einsum("nij,nj->ni", Rc, Xs - cC[c])
        xy = Xc[:, :2] / Xc[:, 2:3]
        ic = intr[c]
        r2 = xy[:, 0] ** 2 + xy[:, 1] ** 2
        k1, k2, p1, p2, k3 = ic[:, 4], ic[:, 5], ic[:, 6], ic[:, 7], ic[:, 8]
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        x, y = xy[:, 0], xy[:, 1]
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([ic[:, 0] * xd + ic[:, 2], ic[:, 1] * yd + ic[:, 3]], axis=1)

    def _sparsity(self, free: np.ndarray) -> coo_matrix:
        """Which free parameters each residual depends on: (2M, n_free), vectorised."""
        nc, nv = len(self.intrinsics), len(self.view_rvec)
        idx = np.flatnonzero(self.active)
        c, v = self.obs_cam[idx], self.obs_view[idx]
        a3 = np.arange(3)
        cols = np.concatenate([c[:, None] * 9 + np.arange(9), nc * 9 + 3 * c[:, None] + a3,
                               nc * 12 + 3 * c[:, None] + a3, nc * 15 + 3 * v[:, None] + a3,
                               nc * 15 + nv * 3 + 3 * v[:, None] + a3], axis=1)      # (M,21)
        col_of = -np.ones(len(free), int)
        col_of[free] = np.arange(free.sum())
        cols = col_of[cols]
        rows = np.arange(len(idx))[:, None].repeat(cols.shape[1], axis=1)
        ok = cols >= 0
        r, k = rows[ok], cols[ok]
        data = np.ones(2 * len(r), np.int8)
        return coo_matrix((data, (np.r_[2 * r, 2 * r + 1], np.r_[k, k])),
                          shape=(2 * len(idx), int(free.sum())))

    def solve(self, outlier_sigmas: float = 5.0, max_rounds: int = 3) -> BundleResult:
        full0 = self._full()
        free = self._free_mask()
        result = None
        for _round in range(max_rounds):
            x0 = full0[free]

            def fun(x):
                full = full0.copy()
                full[free] = x
                return (self.project(full) - self.obs_uv[self.active]).ravel()

            jac = _grouped_jacobian(fun, self._sparsity(free).tocsc())
            if self.solver == "scipy":
                result = least_squares(fun, x0, jac=jac, method="trf", tr_solver="exact", x_scale="jac",
                                       xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=100)
            else:
                result = levenberg_marquardt(fun, jac, x0)
            full0 = full0.copy()
            full0[free] = result.x
            # robust: drop points far beyond the residual spread, then solve again
            idx = np.flatnonzero(self.active)
            r = np.linalg.norm(result.fun.reshape(-1, 2), axis=1)
            sigma = 1.4826 * np.median(r) / 1.1774  # per-axis sigma from the median 2-D norm
            bad = r > max(outlier_sigmas * sigma, 1e-6)
            if not bad.any():
                break
            self.active[idx[bad]] = False
        return self._result(full0, free, result)

    def _result(self, full: np.ndarray, free: np.ndarray, result) -> BundleResult:
        intr, crv, cC, vrv, vt = (a.copy() for a in self._unpack(full))
        r = result.fun
        m, n = len(r), int(free.sum())
        if m <= n:
            raise CalibrationError(f"calibration: {m // 2} points for {n} parameters; show the camera more of the box")
        s2 = float(r @ r) / (m - n)
        J = result.jac.toarray() if hasattr(result.jac, "toarray") else np.asarray(result.jac)
        JTJ = J.T @ J
        try:
            cov = np.linalg.inv(JTJ) * s2
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(JTJ) * s2
        cov_all = np.zeros((len(full), len(full)))
        cov_all[np.ix_(free, free)] = cov
        std_free = np.sqrt(np.clip(np.diag(cov), 0, None))
        std_full = np.zeros(len(full))
        std_full[free] = std_free
        s_intr, s_crv, s_cC, _, _ = self._unpack(std_full)
        nc = len(intr)
        pred = self.project(full, np.arange(len(self.obs_uv)))
        res_all = pred - self.obs_uv
        res_all[~self.active] = np.nan
        rms = np.zeros(nc)
        npts = np.zeros(nc, int)
        for c in range(nc):
            sel = (self.obs_cam == c) & self.active
            npts[c] = int(sel.sum())
            rms[c] = float(np.sqrt(np.mean(np.sum(res_all[sel] ** 2, axis=1)))) if npts[c] else np.nan
        split = np.cumsum([len(o.pixels) for o in self.observations])[:-1]
        cam_idx = np.concatenate([np.r_[c * 9:c * 9 + 9, nc * 9 + c * 3:nc * 9 + c * 3 + 3,
                                        nc * 12 + c * 3:nc * 12 + c * 3 + 3] for c in range(nc)])
        return BundleResult(intr, crv, cC, vrv, vt, s_intr.copy(), s_crv.copy(), s_cC.copy(), rms, npts,
                            cov_cameras=cov_all[np.ix_(cam_idx, cam_idx)],
                            residuals=np.split(res_all, split), outliers=int((~self.active).sum()),
                            sigma_px=float(np.sqrt(s2 / 1.0)), iterations=int(result.nfev))


@dataclass
class _LMResult:
    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    nfev: int


def levenberg_marquardt(fun, jac, x0: np.ndarray, max_iter: int = 100, tol: float = 1e-12) -> _LMResult:
    """Levenberg-Marquardt on the normal equations (J^T J is only n x n): the same minimum as
    ``scipy.optimize.least_squares`` (a test checks it; ``solver="scipy"`` uses scipy), but
    without an SVD of the tall m x n Jacobian at every step, which is slow on busy machines."""
    x = np.asarray(x0, float).copy()
    r = fun(x)
    cost = r @ r
    lam = 1e-3
    nfev = 1
    J = jac(x)
    for _ in range(max_iter):
        g = J.T @ r
        A = J.T @ J
        d = np.sqrt(np.diag(A)) + 1e-300
        As = A / d[:, None] / d[None, :]
        gs = g / d
        improved = False
        for _ in range(20):
            step = -np.linalg.solve(As + lam * np.eye(len(x)), gs) / d
            r_new = fun(x + step)
            nfev += 1
            c_new = r_new @ r_new
            if c_new < cost:
                x, r, lam = x + step, r_new, max(lam / 5, 1e-12)
                improved = True
                break
            lam *= 10
        if not improved:
            break
        done = cost - c_new <= tol * cost or np.max(np.abs(step) / (np.abs(x) + 1e-8)) < 1e-12
        cost = c_new
        J = jac(x)
        if done:
            break
    return _LMResult(x, r, J, nfev)


def _grouped_jacobian(fun, sparsity):
    """A dense central-difference Jacobian that perturbs many columns at once: columns whose
    residual rows do not overlap (e.g. the poses of different views) share one evaluation
    (greedy colouring of the sparsity pattern, as Curtis-Powell-Reid)."""
    S = sparsity.astype(bool)
    n = S.shape[1]
    col_rows = [S.indices[S.indptr[j]:S.indptr[j + 1]] for j in range(n)]
    groups: list[list[int]] = []
    used: list[np.ndarray] = []
    for j in range(n):
        for g, rows in enumerate(used):
            if not rows[col_rows[j]].any():
                groups[g].append(j)
                rows[col_rows[j]] = True
                break
        else:
            rows = np.zeros(S.shape[0], bool)
            rows[col_rows[j]] = True
            groups.append([j])
            used.append(rows)

    def jac(x):
        J = np.zeros((S.shape[0], n))
        h = 1e-6 * np.maximum(1.0, np.abs(x))
        for g in groups:
            dx = np.zeros(n)
            dx[g] = h[g]
            diff = (fun(x + dx) - fun(x - dx))
            for j in g:
                r = col_rows[j]
                J[r, j] = diff[r] / (2 * h[j])
        return J
    return jac


def reprojection_rms(K: np.ndarray, dist: np.ndarray, R: np.ndarray, t: np.ndarray,
                     points: np.ndarray, pixels: np.ndarray) -> float:
    """RMS (px) of ``|project(points) - pixels|`` for one camera, x_cam = R X + t."""
    Xc = np.asarray(points, float) @ R.T + t
    xy = distort_normalized(Xc[:, :2] / Xc[:, 2:3], dist)
    uv = xy * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    return float(np.sqrt(np.mean(np.sum((uv - pixels) ** 2, axis=1))))
