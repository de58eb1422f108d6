"""Canny edges with gradient directions (paper section 2.1), thresholds relative to the image.

Fixed Canny thresholds tuned on one picture fail on the next (dim workshop, glare on a polished
rim); here the hysteresis thresholds come from the image's own gradient distribution.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from station.rim.npfast import percentiles, rows


@dataclass
class EdgeSet:
    """Edge pixels of one image.

    points: (N,2) float64 (u, v); grad: (N,2) unit gradient (direction of increasing
    brightness); mag: (N,) gradient magnitude; shape: (H, W) of the image they came from.
    """

    points: np.ndarray
    grad: np.ndarray
    mag: np.ndarray
    shape: tuple[int, int]

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, idx) -> "EdgeSet":
        return EdgeSet(rows(self.points, idx), rows(self.grad, idx), self.mag[idx], self.shape)

    def columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """u, v, grad u, grad v (N,) each, contiguous (the compiled tests' input), made once per
        points and grad arrays: replace them (as ``subset`` does), never change them in place."""
        key = (id(self.points), id(self.grad))
        if self.__dict__.get("_columns_of") != key:  # (made again if the arrays were replaced)
            self.__dict__["_columns"] = tuple(np.ascontiguousarray(c) for c in (*self.points.T, *self.grad.T))
            self.__dict__["_columns_of"] = key
        return self.__dict__["_columns"]


def _magnitude(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Gradient magnitude of int16 Sobel responses (any shape), float64: exact squares, then a
    correctly rounded root. cv2.magnitude's result moved by an ulp with the arrays' place in
    memory, and with it the edges' gradients, so the same image gave another rim after other
    images had been processed."""
    return np.sqrt(dx.astype(np.int32) ** 2 + dy.astype(np.int32) ** 2)


def canny_thresholds(mag: np.ndarray, high_percentile: float = 90.0) -> tuple[float, float]:
    """(low, high) hysteresis thresholds from the gradient magnitude of every second pixel of
    every second row (``mag``).

    high: the ``high_percentile`` of the magnitude, but at least 4 x the median (a robust
    noise level: most of an image is flat), so a flat noisy image yields few edges;
    low = 0.4 high.
    """
    noise, p_hi = (float(v) for v in percentiles(mag, [50.0, high_percentile]))
    high = max(p_hi, 4.0 * noise, 8.0)
    return 0.4 * high, high


def detect_edges(grey_u8: np.ndarray, blur_sigma: float = 1.0, max_points: int = 16000,
                 high_percentile: float = 90.0) -> EdgeSet:
    """Canny on a (H,W) uint8 image. Returns an :class:`EdgeSet` (at most ``max_points``
    strongest edge pixels, so the voting time stays bounded on a cluttered image)."""
    img = cv2.GaussianBlur(grey_u8, (0, 0), blur_sigma) if blur_sigma > 0 else grey_u8
    dx = cv2.Sobel(img, cv2.CV_16S, 1, 0, ksize=3)
    dy = cv2.Sobel(img, cv2.CV_16S, 0, 1, ksize=3)
    low, high = canny_thresholds(_magnitude(dx[::2, ::2], dy[::2, ::2]), high_percentile)
    edges = cv2.Canny(dx, dy, low, high, L2gradient=True)
    # np.nonzero(edges) and the gathers at (v, u), by flat indices: 2-D nonzero and 2-D
    # fancy indexing take numpy's slow paths (0.4 ms against 0.15 here)
    flat = np.flatnonzero(edges != 0)  # (nonzero of a bool image: 2x faster than of uint8)
    v, u = np.divmod(flat, edges.shape[1])
    gx = dx.ravel()[flat]
    gy = dy.ravel()[flat]
    m = _magnitude(gx, gy)  # (the magnitude of the edge pixels only)
    gx, gy = gx.astype(np.float64), gy.astype(np.float64)
    if len(m) > max_points:
        keep = np.argpartition(-m, max_points)[:max_points]
        u, v, gx, gy, m = u[keep], v[keep], gx[keep], gy[keep], m[keep]
    nz = np.maximum(m, 1e-9)
    return EdgeSet(np.stack([u, v], axis=1).astype(np.float64),
                   np.stack([gx / nz, gy / nz], axis=1), m, grey_u8.shape)
