"""How far a wheel has turned about its own axis between two captures, from its rim's pattern.

The rim's face (spokes, windows, the hub) is a pattern that turns with the wheel. Sampled round
rings about the wheel's 3-D circle (its centre and axis from the circle fit), each view gives
an angular profile of the face; the angle by which one capture's profile is the other's turned
is the wheel's rotation about its axis between them (``rotation_between``).

The face is recessed behind the lip plane by a depth that differs from rim to rim (20-70 mm):
sampled in the lip plane, its pattern shifts with the viewing direction, by about a degree when
the car has rolled 15 cm. Sampled at its own depth, both cameras of the pair see the same
profile; ``face_depth`` finds that depth as the one at which they agree best, and rings at it
measure the rotation to about 0.01 deg on the simulated station.

A rim with N spokes looks the same turned by 360/N deg: ``rotation_between`` takes the
correlation peak nearest a prior (the roll the wheel centre's travel implies, or none for a
steered wheel, which turns about its kingpin, not about its axis).

Reference direction: angles are measured from the projection of the station's up (+z) onto the
rim plane, toward ``axis x up``; a profile is (N,) samples over [0, 2 pi), normalised to zero
mean and unit spread per ring, summed over the rings.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calibration.camera_model import CameraModel

RING_RADII = np.linspace(0.35, 0.88, 12)   # the rings, as fractions of the lip radius: the face inside the lip
PROFILE_SAMPLES = 2048                      # samples round a ring (about 0.18 deg apart)
DEPTH_RANGE_M = (-0.12, 0.03)               # where the face may be, along the outward axis from the lip plane
DEPTH_STEP_M = 0.005
MIN_PEAK_SHARE = 0.8                        # a correlation peak this close to the highest competes with it


@dataclass(frozen=True)
class FacePose:
    """A wheel's 3-D circle at one capture: centre (3,), outward unit axis (3,), lip radius (m)."""

    center_station: np.ndarray
    axis_station: np.ndarray
    radius_m: float


def ring_basis(axis_station: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e1, e2) (3,) each: the in-plane reference direction (the station's up projected onto the
    plane of normal ``axis_station``) and axis x e1."""
    n = np.asarray(axis_station, float) / np.linalg.norm(axis_station)
    up = np.array([0.0, 0.0, 1.0])
    e1 = up - n * (n @ up)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def angular_profile(image: np.ndarray, camera: CameraModel, pose: FacePose, depth_m: float,
                    radii: np.ndarray = RING_RADII, samples: int = PROFILE_SAMPLES) -> np.ndarray:
    """(samples,) the face's grey profile round the wheel, in one view: rings of ``radii`` x the
    lip radius in the plane ``depth_m`` along the axis from the lip, projected into ``image``
    (grey, (H,W)), sampled bilinearly; each ring normalised, then summed."""
    n = np.asarray(pose.axis_station, float)
    e1, e2 = ring_basis(n)
    phi = np.arange(samples) * (2 * np.pi / samples)
    unit = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2                     # (S,3)
    centre = np.asarray(pose.center_station, float) + depth_m * n
    points = centre + (np.asarray(radii, float)[:, None, None] * pose.radius_m) * unit[None]  # (R,S,3)
    uv = camera.project(points.reshape(-1, 3)).astype(np.float32)
    grey = np.asarray(image, np.float32)
    values = cv2.remap(grey, uv[:, 0].reshape(len(radii), samples), uv[:, 1].reshape(len(radii), samples),
                       cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(float)        # (R,S)
    values -= values.mean(axis=1, keepdims=True)
    spread = values.std(axis=1, keepdims=True)
    return (values / np.where(spread > 0, spread, 1.0)).sum(axis=0)


def face_depth(images: dict[str, np.ndarray], cameras: dict[str, CameraModel], pose: FacePose) -> tuple[float, float]:
    """(depth m, agreement 0..1): the plane along the axis at which both views' profiles of the
    face agree best (their correlation, a grid over DEPTH_RANGE_M, refined by a parabola)."""
    cam_a, cam_b = list(images)
    depths = np.arange(DEPTH_RANGE_M[0], DEPTH_RANGE_M[1] + 1e-9, DEPTH_STEP_M)
    agree = np.array([_correlation(angular_profile(images[cam_a], cameras[cam_a], pose, h),
                                   angular_profile(images[cam_b], cameras[cam_b], pose, h)) for h in depths])
    k = int(np.argmax(agree))
    if 0 < k < len(depths) - 1:
        y0, y1, y2 = agree[k - 1:k + 2]
        den = y0 - 2 * y1 + y2
        step = 0.5 * (y0 - y2) / den if den < 0 else 0.0
        return float(depths[k] + np.clip(step, -1, 1) * DEPTH_STEP_M), float(y1)
    return float(depths[k]), float(agree[k])


def rotation_between(before: np.ndarray, after: np.ndarray, prior_rad: float = 0.0) -> tuple[float, float]:
    """(angle rad, peak): how far the pattern of profile ``before`` (S,) has turned in ``after``
    (S,) about the axis (positive: from e1 toward e2), by circular correlation refined by a
    parabola; of the peaks within MIN_PEAK_SHARE of the highest (a rim's N-fold symmetry), the
    one nearest ``prior_rad``. ``peak``: that peak's correlation coefficient (1: identical)."""
    s = len(before)
    a = (before - before.mean()) / (before.std() * s)
    b = (after - after.mean()) / after.std()
    corr = np.fft.irfft(np.conj(np.fft.rfft(a)) * np.fft.rfft(b), s)               # (S,) lag k: after(phi + k) ~ before(phi)
    peaks = np.nonzero((corr >= np.roll(corr, 1)) & (corr >= np.roll(corr, -1))
                       & (corr >= MIN_PEAK_SHARE * corr.max()))[0]
    step = 2 * np.pi / s
    k = int(min(peaks, key=lambda j: abs(_wrap(j * step - prior_rad))))
    y0, y1, y2 = corr[(k - 1) % s], corr[k], corr[(k + 1) % s]
    den = y0 - 2 * y1 + y2
    offset = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    return float(_wrap((k + offset) * step)), float(y1)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = np.sqrt((a @ a) * (b @ b))
    return float(a @ b / den) if den > 0 else 0.0


def _wrap(angle_rad: float) -> float:
    return float((angle_rad + np.pi) % (2 * np.pi) - np.pi)
