"""A 3-D circle's image in a camera, and the distance of image points to it.

A circle (centre c, unit normal n, radius r, camera frame) projects to the conic of
:func:`circle_conic` in normalised coordinates; the Sampson distance of a point to that conic,
scaled by the focal length, is its first-order image distance in pixels (:func:`sampson_px`),
which the 3-D circle fits minimise (station/wheel/circle_fit.py, other_contour.py).
"""

from __future__ import annotations

import numpy as np

from calibration.triangulation import homogeneous


def circle_conic(center_cam: np.ndarray, normal_cam: np.ndarray, radius: float) -> np.ndarray:
    """(3,3) conic of a 3-D circle's image in normalised coordinates (camera frame inputs).

    Points X = lambda x on the cone through the circle satisfy
    (n.c)^2 x.x - 2 (n.c)(n.x)(c.x) + (c.c - r^2)(n.x)^2 = 0.
    """
    return circle_conics(center_cam[None], normal_cam[None], np.array([radius], float))[0]


def circle_conics(center_cam: np.ndarray, normal_cam: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(K,3,3) :func:`circle_conic` of K circles at once: centres (K,3), normals (K,3), radii (K,)."""
    c, n = center_cam, normal_cam
    nc = np.einsum("ki,ki->k", n, c)[:, None, None]
    nn = n[:, :, None] * n[:, None, :]
    nc_outer = n[:, :, None] * c[:, None, :]
    cc_rr = (np.einsum("ki,ki->k", c, c) - radius * radius)[:, None, None]
    return nc * nc * np.eye(3) - nc * (nc_outer + np.swapaxes(nc_outer, 1, 2)) + cc_rr * nn


def sampson_jacobian(C: np.ndarray, dC: np.ndarray, X: np.ndarray, focal_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Sampson distances (N,) px of homogeneous points X (N,3) to the conic C (3,3), and their
    derivatives (N,K) along K conic directions dC (K,3,3): s = f F / G with F = x'Cx and
    G = 2 |(Cx)_12|, so ds = f (dF G - F dG) / G^2, dF = x' dC x, dG = 2 g.(dC x)_12 / |g|.
    One (N,3) x (3,3(K+1)) product for all of them."""
    K = len(dC)
    Y = (X @ np.concatenate([C, *dC], axis=1)).reshape(len(X), K + 1, 3)   # C and dC symmetric
    CX, dCX = Y[:, 0], Y[:, 1:]
    F = np.einsum("ni,ni->n", CX, X)
    dF = np.einsum("nki,ni->nk", dCX, X)
    g = np.hypot(CX[:, 0], CX[:, 1])
    dG = 2 * (dCX[:, :, 0] * CX[:, :1] + dCX[:, :, 1] * CX[:, 1:2]) / g[:, None]
    G = 2 * g
    return focal_px * F / G, focal_px * (dF * G[:, None] - F[:, None] * dG) / (G * G)[:, None]


def sampson_px(C: np.ndarray, xy: np.ndarray, focal_px: float) -> np.ndarray:
    """(N,) first-order geometric distance (px) of normalised points (N,2), or the same points
    already homogeneous (N,3) (a fit calls this hundreds of times on the same points), to the conic C."""
    X = xy if xy.shape[1] == 3 else homogeneous(xy)
    CX = X @ C
    f = np.einsum("ni,ni->n", CX, X)
    grad = 2 * np.hypot(CX[:, 0], CX[:, 1])
    return focal_px * f / grad
