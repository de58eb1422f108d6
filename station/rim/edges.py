"""Canny edges with gradient directions (paper section 2.1), thresholds relative to the image.

Fixed Canny thresholds tuned on one picture fail on the next (dim workshop, glare on a polished
rim); here the hysteresis thresholds come from the image's own gradient distribution.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from station.rim.npfast import finite_rows, percentiles, rows


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

    def near_curve(self, curve_px: np.ndarray, radius_px: float, cell_px: float = 8.0) -> np.ndarray:
        """Indices (sorted) of the edge pixels in the grid cells of ``cell_px`` that lie within
        ``radius_px`` (+ a cell) of the dense curve points ``curve_px`` (M,2): a superset of the
        pixels within ``radius_px`` of the curve, without a distance to every pixel."""
        if getattr(self, "_grid", (None, None))[:2] != (cell_px, id(self.points)):
            gw = int(self.shape[1] // cell_px) + 2
            gh = int(self.shape[0] // cell_px) + 2
            cu = np.clip(np.floor(self.points[:, 0] / cell_px).astype(np.int64), 0, gw - 1)
            cv = np.clip(np.floor(self.points[:, 1] / cell_px).astype(np.int64), 0, gh - 1)
            self._grid = (cell_px, id(self.points), gh, gw, cv * gw + cu)
        _, _, gh, gw, cell_of_point = self._grid
        mask = np.zeros((gh, gw), np.uint8)
        ok = finite_rows(curve_px)
        # (M,2) cell (column, row) of each curve point; off the grid: its border cell
        cell = np.clip(np.floor(rows(curve_px, ok) / cell_px), 0, (gw - 1, gh - 1)).astype(np.int64)
        mask[cell[:, 1], cell[:, 0]] = 1
        r = int(np.ceil(radius_px / cell_px))
        mask = cv2.dilate(mask, _square(2 * r + 1))
        return np.flatnonzero(mask.view(bool).ravel()[cell_of_point])  # (0/1: nonzero of a bool is 2x faster)


@lru_cache(maxsize=8)
def _square(k: int) -> np.ndarray:
    """(k,k) uint8 ones: a square structuring element (made once per size, read-only)."""
    kernel = np.ones((k, k), np.uint8)
    kernel.flags.writeable = False
    return kernel


def canny_thresholds(mag: np.ndarray, high_percentile: float = 90.0) -> tuple[float, float]:
    """(low, high) hysteresis thresholds from the gradient magnitude image.

    high: the ``high_percentile`` of the magnitude, but at least 4 x the median (a robust
    noise level: most of an image is flat), so a flat noisy image yields few edges;
    low = 0.4 high.
    """
    noise, p_hi = (float(v) for v in percentiles(mag[::2, ::2], [50.0, high_percentile]))
    high = max(p_hi, 4.0 * noise, 8.0)
    return 0.4 * high, high


def detect_edges(grey_u8: np.ndarray, blur_sigma: float = 1.0, max_points: int = 16000,
                 high_percentile: float = 90.0) -> EdgeSet:
    """Canny on a (H,W) uint8 image. Returns an :class:`EdgeSet` (at most ``max_points``
    strongest edge pixels, so the voting time stays bounded on a cluttered image)."""
    img = cv2.GaussianBlur(grey_u8, (0, 0), blur_sigma) if blur_sigma > 0 else grey_u8
    dx = cv2.Sobel(img, cv2.CV_16S, 1, 0, ksize=3)
    dy = cv2.Sobel(img, cv2.CV_16S, 0, 1, ksize=3)
    # exact squares, then a correctly rounded root: cv2.magnitude's result moved by an ulp with
    # the arrays' place in memory, and with it the edges' gradients, so the same image gave
    # another rim after other images had been processed
    mag = np.sqrt(dx.astype(np.int32) ** 2 + dy.astype(np.int32) ** 2)
    low, high = canny_thresholds(mag, high_percentile)
    edges = cv2.Canny(dx, dy, low, high, L2gradient=True)
    # np.nonzero(edges) and the gathers at (v, u), by flat indices: 2-D nonzero and 2-D
    # fancy indexing take numpy's slow paths (0.4 ms against 0.15 here)
    flat = np.flatnonzero(edges != 0)  # (nonzero of a bool image: 2x faster than of uint8)
    v, u = np.divmod(flat, edges.shape[1])
    gx = dx.ravel()[flat].astype(np.float64)
    gy = dy.ravel()[flat].astype(np.float64)
    m = mag.ravel()[flat].astype(np.float64)
    if len(m) > max_points:
        keep = np.argpartition(-m, max_points)[:max_points]
        u, v, gx, gy, m = u[keep], v[keep], gx[keep], gy[keep], m[keep]
    nz = np.maximum(m, 1e-9)
    return EdgeSet(np.stack([u, v], axis=1).astype(np.float64),
                   np.stack([gx / nz, gy / nz], axis=1), m, grey_u8.shape)
