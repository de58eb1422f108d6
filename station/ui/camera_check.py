"""The Cameras page's check: one capture of every camera (a burst of NOISE_MIN_FRAMES, averaged),
the rim each found drawn over its image, and each camera's exposure, focus and rim-size warnings
(as ``station measure`` gives them) and whether its grey is proportional to light (its burst's
noise, station/capture/linearity.py).

Nothing is kept: no frames on disk, no history row; it is for setting up and service.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from station.capture.frame_average import NOISE_MIN_FRAMES
from station.capture.linearity import response_warnings
from station.capture.sync import capture_averaged
from station.measure import measure_frames

DISPLAY_WIDTH_PX = 640        # images are sent at most this wide
CAMERA_WARNINGS = ("focus", "exposure", "small_rim")


def ellipse_pixels(model, center_px, axes_px, angle_deg, n: int = 240) -> np.ndarray:
    """(n,2) points of a rim ellipse given in the camera's ideal (undistorted) pixels, moved to
    its image's pixels (the lens distortion applied) so that they lie on the rim as imaged."""
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    a, b = axes_px
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    local = np.stack([a * np.cos(t), b * np.sin(t)], axis=1)
    ideal = local @ np.array([[c, s], [-s, c]]) + np.asarray(center_px, float)
    return model.normalized_to_pixels(model.unapply_K(ideal))


def overlay_png(image: np.ndarray, points_px: np.ndarray | None) -> bytes:
    """The image (8 or 16 bit grey) as an 8-bit colour PNG, at most DISPLAY_WIDTH_PX wide, with the
    rim drawn in green (None: nothing found)."""
    import cv2

    grey = image if image.dtype == np.uint8 else np.clip(image / 256.0, 0, 255).astype(np.uint8)
    scale = min(1.0, DISPLAY_WIDTH_PX / grey.shape[1])
    if scale < 1.0:
        grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    bgr = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    if points_px is not None:
        pts = np.round((points_px + 0.5) * scale - 0.5).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(bgr, [pts], isClosed=True, color=(60, 220, 60), thickness=2)
    ok, png = cv2.imencode(".png", bgr)
    return png.tobytes()


def check_cameras(station, show: Callable[[str], None]) -> tuple[dict, dict]:
    """({camera id: PNG bytes}, summary {cameras: {id: {wheel, ok, reason, warnings}}, warnings})."""
    cfg = station.config
    show(f"capturing {len(station.cameras)} cameras once ({NOISE_MIN_FRAMES} frames each)")
    frames = capture_averaged(station.cameras, station.timeout_s, station.trigger_board, frames=NOISE_MIN_FRAMES)
    not_linear = dict(response_warnings(frames, cfg))
    images = {c: f.image for c, f in frames.items()}
    show("finding the rim in every image")
    result = measure_frames(images, station.models, cfg, workers=station.workers,
                            calibration_cov=station.calibration.pair_covariance)
    pngs, cams = {}, {}
    for cid in cfg.cameras:
        det = (result.detections or {}).get(cid)
        pts = None
        if det is not None and det.ok:
            pts = ellipse_pixels(station.models[cid], det.center_px, det.axes_px, det.angle_deg)
        if cid in images:
            pngs[cid] = overlay_png(images[cid], pts)
        warnings = [f.text for f in result.warning_flags if f.camera == cid and f.kind in CAMERA_WARNINGS]
        warnings += [not_linear[cid]] if cid in not_linear else []
        cams[cid] = {"wheel": cfg.cameras[cid].wheel, "ok": bool(det and det.ok),
                     "reason": None if det is None else det.reason,
                     "rim_axes_px": None if not (det and det.ok) else [round(x, 1) for x in det.axes_px],
                     "warnings": warnings, "image": cid in pngs}
    if not result.detections and result.failure is not None:  # no detection at all: say why
        for c in cams.values():
            c["reason"] = c["reason"] or result.failure.message
    show("camera check done: " + ", ".join(f"{c} {'rim found' if v['ok'] else 'NO RIM'}" for c, v in cams.items()))
    return pngs, {"cameras": cams, "valid": result.valid}
