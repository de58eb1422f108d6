"""Rim candidates in a photograph and the wheel's structure around them (``photo_search``).

A wheel seen from any side is a bright-ish metal rim inside a dark rubber annulus, the tyre.
Cut the image at a grey level between the two and the rim is a bright region whose outer
boundary is the lip's ellipse, all round, inside a dark ring: the outer boundary of a
connected bright region (``cv2.findContours``) that an ellipse follows over most of its
turn. Which level separates them is not known (the lip may be shaded, the tyre lit), so the
search image is cut at ``LEVELS`` levels evenly spaced in log-light between its 1st and 95th
percentiles, and the same ellipse found at several levels is one candidate (``support``: how
many levels found it, the region's stability).

Every candidate is then measured on its concentric similar ellipses (``profile``): the
tyre's physics, not the image's statistics, decides (``photo_search.structure``).

Arrays: the search image ``L`` is (h,w) float32 natural log of light (light on 0..1,
floored at ``LOG_FLOOR``); ellipses are in search-image pixels until ``photo_search`` scales
them to the photograph's.
"""

from __future__ import annotations

import cv2
import numpy as np

from station.rim.ellipse import Ellipse

SEARCH_SIDE_PX = 900     # the search image's larger side at most (a 2592 px photo: 1/3)
LOG_FLOOR = 0.004        # of the white: log(light + floor) keeps the deep shadows' detail
LEVELS = 16              # grey levels the search image is cut at
MIN_COVER = 0.6          # of the turn (36 sectors): an ellipse must follow a region's boundary this far
FIT_TOL_PX = 1.5         # a boundary pixel this near the ellipse (search px) follows it
SECTORS = 36


def search_image(grey: np.ndarray) -> tuple[np.ndarray, int]:
    """(H,W) float32 grey proportional to light (0..255) -> ((h,w) float32 log-light, scale s):
    area-averaged by the integer s that brings the larger side to <= ``SEARCH_SIDE_PX``,
    smoothed by a Gaussian of 1 px (JPEG blocks, sensor noise)."""
    s = max(1, int(np.ceil(max(grey.shape) / SEARCH_SIDE_PX)))
    h, w = grey.shape
    g = grey[: h - h % s, : w - w % s]
    if s > 1:
        g = cv2.resize(g, (g.shape[1] // s, g.shape[0] // s), interpolation=cv2.INTER_AREA)
    L = np.log(np.maximum(g, 0) * np.float32(1 / 255.0) + np.float32(LOG_FLOOR)).astype(np.float32)
    return cv2.GaussianBlur(L, (0, 0), 1.0), s


def profile(L: np.ndarray, e: Ellipse, rhos: np.ndarray, n_angles: int = 72) -> np.ndarray:
    """(R, n_angles) log-light on the concentric similar ellipses rho * e (rhos (R,)) at equal
    parameter steps (bilinear); NaN outside the image."""
    t = (np.arange(n_angles) + 0.5) * (2 * np.pi / n_angles)
    p = e.scaled_points(rhos, t).astype(np.float32)  # (R*n,2)
    h, w = L.shape
    out = cv2.remap(L, p[:, 0].reshape(1, -1), p[:, 1].reshape(1, -1), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan).reshape(len(rhos), n_angles)
    inside = (p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)
    out[~inside.reshape(out.shape)] = np.nan
    return out


def _fit(pts: np.ndarray, a_min: float, a_max: float, min_ratio: float) -> tuple[Ellipse, float] | None:
    """An ellipse following the boundary pts (N,2) over most of its turn, and that share
    (sectors of the ellipse holding a boundary pixel within ``FIT_TOL_PX``), or None. The fit
    is trimmed twice: the boundary may leave the lip where a highlight crosses the tyre."""
    keep = pts
    e = None
    for _ in range(3):
        if len(keep) < 12:
            return None
        try:
            (cx, cy), (d1, d2), ang = cv2.fitEllipseDirect(keep.astype(np.float32))
        except cv2.error:
            return None
        if not (np.isfinite(d1) and np.isfinite(d2) and min(d1, d2) > 2):
            return None
        e = Ellipse((cx, cy), (d1 / 2, d2 / 2), np.radians(ang))
        if not (a_min <= e.axes_px[0] <= a_max and e.axes_px[1] >= min_ratio * e.axes_px[0]):
            return None
        d, t = e.distance(pts)
        near = np.abs(d) <= FIT_TOL_PX * (3 - _)  # 4.5, 3, 1.5 px: the trim tightens
        keep = pts[near]
    sectors = np.unique((np.mod(t[near], 2 * np.pi) * (SECTORS / (2 * np.pi))).astype(int) % SECTORS)
    return e, len(sectors) / SECTORS


def candidates(L: np.ndarray, a_min: float, a_max: float, min_ratio: float) -> list[dict]:
    """Bright regions with an elliptical outer boundary in the search image ``L``: dicts with
    ``ellipse`` (search px), ``cover`` (share of the turn followed, best level) and ``support``
    (levels that found it), the most supported first. a_min, a_max: the semi-major axis
    range (search px); min_ratio: the smallest b/a looked for."""
    lo, hi = np.percentile(L[::4, ::4], [1, 95])
    found: list[dict] = []
    min_len = 2 * a_min * (1 + min_ratio)  # about the smallest ellipse's perimeter
    for level in np.linspace(lo, hi, LEVELS + 2)[1:-1]:
        mask = (L > level).astype(np.uint8)
        contours, hier = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        if hier is None:
            continue
        for c, hrow in zip(contours, hier[0]):
            if hrow[3] != -1 or len(c) < min_len:  # outer boundaries of bright regions only
                continue
            pts = c.reshape(-1, 2).astype(float)
            ext = pts.max(axis=0) - pts.min(axis=0)
            if max(ext) < 2 * a_min * 0.9 or max(ext) > 2.2 * a_max:
                continue
            got = _fit(pts, a_min, a_max, min_ratio)
            if got is None or got[1] < MIN_COVER:
                continue
            e, cover = got
            for f in found:  # the same ellipse at another level: one candidate
                if same_ellipse(f["ellipse"], e, 0.08):
                    f["support"] += 1
                    if cover > f["cover"]:
                        f["ellipse"], f["cover"] = e, cover
                    break
            else:
                found.append({"ellipse": e, "cover": cover, "support": 1, "level": float(level)})
    found.sort(key=lambda f: (-f["support"], -f["cover"]))
    return found


def same_ellipse(e: Ellipse, o: Ellipse, share: float) -> bool:
    """Centres within ``share`` of the semi-major axis and sizes within that share."""
    a = max(e.axes_px[0], o.axes_px[0])
    return bool(np.linalg.norm(e.center_px - o.center_px) <= share * a
                and abs(e.axes_px[0] - o.axes_px[0]) <= share * a
                and abs(e.axes_px[1] - o.axes_px[1]) <= share * a)
