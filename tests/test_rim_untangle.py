"""A rim fit that is a compromise between two contours is untangled (detector._untangled).

A bright rim whose flange is shaded to the tyre's grey over a third of the rim, where a lip
highlight 14 px inside is the only edge: an ellipse through the flange on two thirds and the
highlight on the rest is a compromise; the same wheel's runner-up shares only the flange's arcs.
"""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from station.rim import detector
from station.rim.ellipse import Ellipse
from station.rim.ellipse_fit import fit_direct
from station.rim.preprocess import PixelMap
from station.rim.subpixel import EdgeSamples

CENTRE, R, INNER = np.array([640.3, 512.6]), 300.0, 286.0
SHADOW = (np.radians(200), np.radians(320))  # the arc where the flange is as dark as the tyre


def _image(seed: int = 3) -> np.ndarray:
    import cv2

    vv, uu = np.mgrid[0:1024, 0:1280].astype(float)
    r = np.hypot(uu - CENTRE[0], vv - CENTRE[1])
    phi = np.mod(np.arctan2(vv - CENTRE[1], uu - CENTRE[0]), 2 * np.pi)
    shade = (phi > SHADOW[0]) & (phi < SHADOW[1])
    img = np.full(r.shape, 40.0)                                    # tyre
    img[r < R] = 170.0                                              # metal
    img[(r < R) & (r >= INNER) & shade] = 46.0                      # the flange in shadow
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    return np.clip(img + np.random.default_rng(seed).normal(0, 2.0, img.shape), 0, 255).astype(np.float32)


def _compromise_points() -> np.ndarray:
    """(N,2) edge points 1.5 px apart that follow the flange, and the highlight on the shaded arc."""
    t = np.arange(0, 2 * np.pi, 1.5 / R)
    radius = np.where((t > SHADOW[0]) & (t < SHADOW[1]), INNER, R)
    return CENTRE + radius[:, None] * np.stack([np.cos(t), np.sin(t)], axis=1)


def _compromise() -> Ellipse:
    return fit_direct(_compromise_points())


def _cand(e: Ellipse, score: float) -> dict:
    return {"ellipse": e.to_dict(), "score": score}


def _off_flange(points: np.ndarray) -> np.ndarray:
    return np.abs(np.linalg.norm(points - CENTRE, axis=1) - R)


@pytest.fixture(scope="module")
def grey():
    return _image()


def test_a_compromise_between_the_flange_and_an_inner_contour_keeps_the_flange_arcs(grey):
    pts = _compromise_points()
    n = len(pts)
    samples = EdgeSamples(pts, np.zeros(n), np.full(n, 120.0), np.ones(n), np.ones(n), np.ones(n, bool))
    best = SimpleNamespace(ellipse=_compromise())   # one ellipse through both contours
    assert np.percentile(np.abs(best.ellipse.distance(pts)[0]), 90) > 2
    flange = Ellipse(CENTRE, (R, R), 0.0)            # the runner-up: the same wheel, nearly as good
    out = detector._untangled(grey, PixelMap(None), [_cand(best.ellipse, 0.8), _cand(flange, 0.72)], best,
                              samples, samples.ok.copy(), 1.0)
    assert out is not None
    new_fit, new_samples, new_mask, _, info = out
    assert info["other_contour_arcs"] >= 6 and info["runner_up"] == 1
    assert _off_flange(new_samples.points_px[new_mask]).max() < 1e-6                    # the flange only
    assert new_mask.sum() > 0.6 * n
    assert np.linalg.norm(new_fit.ellipse.center_px - CENTRE) < 0.01
    assert new_fit.ellipse.axes_px == pytest.approx((R, R), abs=0.01)


def test_a_fit_on_one_curve_stays_and_distant_or_weak_runners_up_are_not_refined(grey, monkeypatch):
    pmap = PixelMap(None)
    fit, samples, mask, blur = detector._refine(grey, Ellipse(CENTRE, (R, R), 0.0), pmap)
    assert _off_flange(samples.points_px[mask]).max() < 0.6
    compromise = _compromise()
    assert detector._untangled(grey, pmap, [_cand(fit.ellipse, 0.8), _cand(compromise, 0.75)],
                               fit, samples, mask, blur) is None
    refined = []
    monkeypatch.setattr(detector, "_refine", lambda *a, **k: refined.append(a) or (None, None, None, None))
    far = Ellipse(CENTRE + 80, (R, R), 0.0)          # another wheel's place, or another size
    small = Ellipse(CENTRE, (0.6 * R, 0.6 * R), 0.0)
    cands = [_cand(fit.ellipse, 0.8), _cand(far, 0.79), _cand(small, 0.79), _cand(compromise, 0.5)]
    assert detector._untangled(grey, pmap, cands, fit, samples, mask, blur) is None
    assert refined == []                             # none of them is the same wheel's near tie


def test_harsh_light_the_simulated_station_does_not_follow_the_lip_highlight():
    """A harsh-light scene seen by cam1 of the paper's layout (the camera on the wheel's axis):
    one lamp leaves the flange of the lower left in shadow, and the chosen candidate follows
    the lip's highlight 14 px inside there; the detected rim must stay on the flange all
    round."""
    from bench import outside_envelope as oe
    from simulators.world import SimWorld
    from station.config import load_config
    from station.rim import detect_rim

    cfg = load_config(Path(__file__).parents[1] / "config" / "station-paper-layout.yaml")
    world = SimWorld.from_config(cfg, noise_sigma=2.0)
    scene = oe.scene_for(world, "harsh-light", 1004, cfg.nominal_vehicle)
    world.set_scene(scene)
    cam = world.cameras["cam1"]
    image = world.render("cam1", np.random.default_rng(5))
    det = detect_rim(image, camera=cam, camera_id="cam1")
    centre, R_ws = scene.vehicle.wheel_frame_station(cfg.cameras["cam1"].wheel)
    t = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    rim = centre + scene.vehicle.wheel.rim_radius_m * (np.cos(t)[:, None] * R_ws[:, 0] + np.sin(t)[:, None] * R_ws[:, 1])
    pmap = PixelMap(cam)
    truth = fit_direct(pmap.undistort(cam.project(rim)))
    off = np.abs(truth.distance(pmap.undistort(det.points_px))[0])
    assert "untangled" in det.details
    assert np.percentile(off, 99) < 1.5 and len(off) > 400   # the highlight lies 15 px off on a third of the rim
