"""Image preparation for rim detection (paper section 3.1).

* :func:`to_grey` - grey by eq. 36, ``Y = 0.299 R + 0.587 G + 0.114 B`` (float32, 0..255);
* :func:`equalize` - the paper's global histogram equalisation, or CLAHE (the default: local
  equalisation copes with the uneven workshop lighting a global one cannot);
* :func:`detection_scale` / :func:`downscale` - the coarse image the Hough search runs on;
* :func:`noise_grey` - the image's read noise, estimated from the image itself;
* :class:`PixelMap` - lens-distortion correction. The paper resamples the whole image; we
  correct the *points* instead (exact, and no resampling blur of the edges we measure): edge
  points are moved to ideal pinhole pixels, where the rim is an exact ellipse, and profiles are
  still sampled in the original image.
"""

from __future__ import annotations

import cv2
import numpy as np

from station.errors import ImageError
from station.rim.npfast import row_norms

# eq. 36 weights in OpenCV's B, G, R channel order
EQ36_BGR = np.array([[0.114, 0.587, 0.299]], dtype=np.float32)
MIN_SIDE_PX = 48
DETECT_MAX_SIDE_PX = 440  # the Hough search runs at most on this size (1280x1024 -> 426x341)


def to_grey(image: np.ndarray, camera_id: str = "") -> np.ndarray:
    """(H,W) uint8/uint16/float grey or (H,W,3|4) BGR(A) -> (H,W) float32 grey on 0..255 (eq. 36)."""
    tag = f"{camera_id}: " if camera_id else ""
    if not isinstance(image, np.ndarray):
        raise ImageError(f"{tag}expected an image array, got {type(image).__name__}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (3, 4)):
        raise ImageError(f"{tag}expected a grey (H,W) or colour (H,W,3) image, got shape {image.shape}",
                         hint="pass a single grey or BGR colour image")
    h, w = image.shape[:2]
    if min(h, w) < MIN_SIDE_PX:
        raise ImageError(f"{tag}image is too small ({w}x{h} px); a wheel needs at least "
                         f"{MIN_SIDE_PX}x{MIN_SIDE_PX} px, in practice a rim of 100 px or more",
                         hint="use the camera's full-resolution image")
    if image.dtype == np.uint8:
        scale = 1.0
    elif image.dtype == np.uint16:
        scale = 255.0 / 65535.0
    elif image.dtype in (np.float32, np.float64):
        if not np.all(np.isfinite(image)):
            raise ImageError(f"{tag}image contains NaN or infinity")
        scale = 1.0
    else:
        raise ImageError(f"{tag}unsupported pixel type {image.dtype}; expected uint8 or uint16")
    img = image.astype(np.float32, copy=False)
    if img.ndim == 3:
        grey = cv2.transform(img[:, :, :3], EQ36_BGR)  # eq. 36
        grey = grey.reshape(h, w)
    else:
        grey = img.copy() if img is image else img
    if scale != 1.0:
        grey = grey * np.float32(scale)
    return np.ascontiguousarray(grey, dtype=np.float32)


# Immerkaer's mask: the difference of two Laplacians, blind to any plane and to most of a
# smooth shading; on white noise of std s its response has std 6 s (the mask's norm)
_NOISE_MASK = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
NOISE_MARGIN_PX = 8  # the box round the given points grown by this
NOISE_STRIDE = 3     # the median over every 3rd row and column (10^4-10^5 values are plenty)


def noise_grey(grey: np.ndarray, points_px: np.ndarray | None = None) -> float:
    """Read noise (grey levels, std) of (H,W) float32 ``grey``, within the box round
    ``points_px`` (N,2) if given: the median absolute response to Immerkaer's mask over 6 and
    0.6745 (the normal's median absolute deviation). Edges and texture are the few pixels
    where the response is large, so the median stays with the flat ones; what they add makes
    the estimate err high."""
    h, w = grey.shape
    if points_px is not None and len(points_px):
        lo = np.floor(points_px.min(axis=0)).astype(int) - NOISE_MARGIN_PX
        hi = np.ceil(points_px.max(axis=0)).astype(int) + NOISE_MARGIN_PX
        x0, y0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
        x1, y1 = min(int(hi[0]), w), min(int(hi[1]), h)
        if x1 - x0 >= 3 and y1 - y0 >= 3:
            grey = grey[y0:y1, x0:x1]
    response = cv2.filter2D(grey, cv2.CV_32F, _NOISE_MASK, borderType=cv2.BORDER_REPLICATE)
    sample = np.abs(response[1:-1:NOISE_STRIDE, 1:-1:NOISE_STRIDE]).ravel()  # every 9th: the median's cost
    if sample.size == 0:
        return float("nan")
    return float(np.partition(sample, sample.size // 2)[sample.size // 2] / (6.0 * 0.6745))


def equalize(grey_u8: np.ndarray, method: str = "clahe") -> np.ndarray:
    """(H,W) uint8 -> (H,W) uint8. method: "clahe" (default), "global" (the paper), "none"."""
    if method == "none":
        return grey_u8
    if method == "global":
        return cv2.equalizeHist(grey_u8)
    if method == "clahe":
        h, w = grey_u8.shape
        tiles = (max(2, round(w / 160)), max(2, round(h / 160)))
        return cv2.createCLAHE(clipLimit=3.0, tileGridSize=tiles).apply(grey_u8)
    raise ValueError(f"unknown equalisation {method!r}")


def detection_scale(shape: tuple[int, int]) -> int:
    """The smallest integer downscale factor that brings the larger side to <= DETECT_MAX_SIDE_PX."""
    return max(1, int(np.ceil(max(shape) / DETECT_MAX_SIDE_PX)))


def downscale(grey: np.ndarray, s: int) -> np.ndarray:
    """(H,W) float32 -> (H//s, W//s) by area averaging (pixel centres map as (u+0.5)/s-0.5)."""
    if s == 1:
        return grey
    h, w = grey.shape
    g = grey[: h - h % s, : w - w % s]
    return cv2.resize(g, (g.shape[1] // s, g.shape[0] // s), interpolation=cv2.INTER_AREA)


class PixelMap:
    """Distorted image pixels <-> ideal pinhole pixels of a camera (same K, no distortion).

    With ``camera=None`` both are the same (identity). Arrays are (N,2) (u, v).
    """

    def __init__(self, camera=None):
        self.camera = camera
        self.identity = camera is None or not np.any(camera.dist)

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        if self.identity:
            return np.asarray(uv, float)
        return self.camera.apply_K(self.camera.pixels_to_normalized(uv))

    def distort(self, uv_ideal: np.ndarray) -> np.ndarray:
        if self.identity:
            return np.asarray(uv_ideal, float)
        return self.camera.normalized_to_pixels(self.camera.unapply_K(np.asarray(uv_ideal, float)))

    def along_normals(self, p_ideal: np.ndarray, n_ideal: np.ndarray):
        """Points (N,2) and unit normals (N,2) given in ideal pixels, in image pixels: (points,
        unit normals, (N,) image px per ideal px along each normal)."""
        if self.identity:
            return np.asarray(p_ideal, float), np.asarray(n_ideal, float), np.ones(len(p_ideal))
        base = self.distort(p_ideal)
        nrm = self.distort(p_ideal + n_ideal) - base
        scale = row_norms(nrm)
        return base, nrm / scale[:, None], scale

    def normalized(self, uv: np.ndarray) -> np.ndarray:
        """(N,2) distorted pixels -> (N,2) undistorted normalised coordinates (needs a camera)."""
        if self.camera is None:
            raise ValueError("normalised coordinates need a camera model")
        return self.camera.pixels_to_normalized(uv)
