"""detect_rim on synthetic wheels with a known rim ellipse: accuracy, the choice of the rim
among tyre outline / disc / hub, distortion, the prior, and every refusal."""

import cv2
import numpy as np
import pytest

from calibration.camera_model import CameraModel
from station.errors import ImageError, RimNotFound
from station.rim import Ellipse, RimDetection, detect_rim
from tests.synthetic_wheel import WheelSpec, random_spec, render_wheel


def _errors(det: RimDetection, truth: Ellipse):
    dc = np.linalg.norm(det.ellipse.center_px - truth.center_px)
    dax = np.abs(det.ellipse.axes_px - truth.axes_px).max()
    d, _ = truth.distance(det.points_px)
    return dc, dax, float(np.sqrt(np.mean(d**2)))


@pytest.mark.parametrize("seed", [11, 12, 13, 14])
def test_random_wheels_subpixel_accuracy(seed):
    img, truth = render_wheel(random_spec(np.random.default_rng(seed)), seed=seed)
    det = detect_rim(img, camera_id="cam1")
    dc, dax, rms = _errors(det, truth)
    assert dc < 0.05 and dax < 0.05, (dc, dax)
    assert rms < 0.1
    assert det.score > 0.8 and det.coverage > 0.9
    assert len(det.points_px) > 500
    assert det.ellipse_cov.shape == (5, 5) and np.all(np.linalg.eigvalsh(det.ellipse_cov) >= -1e-15)
    assert set(det.timing_s) >= {"grey", "edges", "hough", "refine"}


@pytest.mark.parametrize("blur", [1.7, 2.2])
def test_a_soft_focus_is_measured_as_sharply(blur):
    """An edge blurred over 1.7-2.2 px (a lens a little out of focus): the edge blur is
    estimated as such and the windows grow with it. With the fixed +/-3 px cut and windows
    the blur came out as 1.3-1.6 px and the axes 0.2-0.7 px off."""
    from dataclasses import replace
    for seed in (1, 3):
        spec = replace(random_spec(np.random.default_rng(seed)), blur_sigma_px=blur)
        img, truth = render_wheel(spec, seed=seed)
        det = detect_rim(img)
        dc, dax, rms = _errors(det, truth)
        assert dc < 0.03 and dax < 0.08, (seed, dc, dax)
        assert det.details["blur_px"] == pytest.approx(np.hypot(blur, 0.29), rel=0.1)


def test_oblique_reference_view_and_face_on_view():
    for ratio in (0.87, 1.0):
        img, truth = render_wheel(WheelSpec(axis_ratio=ratio, angle_rad=1.2), seed=3)
        det = detect_rim(img)
        dc, dax, rms = _errors(det, truth)
        assert dc < 0.05 and dax < 0.05 and rms < 0.1
        assert det.ellipse.axes_px[1] / det.ellipse.axes_px[0] == pytest.approx(ratio, abs=1e-3)


def test_rim_not_tyre_outline_on_a_dark_background():
    # background darker than the tyre: the tyre outline is bright-inside too, like the rim
    spec = WheelSpec(background_level=8, tyre_level=60, clutter=0, tyre_scale=1.4, rim_a_px=260)
    img, truth = render_wheel(spec, seed=5)
    det = detect_rim(img)
    assert np.abs(det.ellipse.axes_px - truth.axes_px).max() < 0.05
    tyre_cands = [c for c in det.details["candidates"] if c["ellipse"]["axes_px"][0] > 1.3 * 260]
    assert tyre_cands, "the tyre outline should have been a candidate"


def test_colour_and_16_bit_inputs_give_the_same_rim():
    img, truth = render_wheel(WheelSpec(clutter=4), seed=8)
    grey = detect_rim(img)
    bgr = detect_rim(cv2.merge([img, img, img]))  # eq. 36 of equal channels is the grey itself
    deep = detect_rim(img.astype(np.uint16) * 257)
    # (compare the curves: the angle of a near-circle is ill-defined). Eq. 36 of equal
    # channels differs from the grey by float rounding (1.5e-5 grey levels), which may tip a
    # profile in or out of the fit: the same rim to well under a thousandth of a pixel
    assert np.abs(bgr.ellipse.distance(grey.ellipse.points(64))[0]).max() < 1e-3
    assert np.abs(deep.ellipse.distance(grey.ellipse.points(64))[0]).max() < 1e-3


def test_prior_takes_the_fast_path_and_agrees():
    img, truth = render_wheel(WheelSpec(axis_ratio=0.9), seed=9)
    full = detect_rim(img)
    prior = Ellipse(truth.center_px + (3.0, -2.0), truth.axes_px * 1.02, truth.angle_rad + 0.05)
    fast = detect_rim(img, prior=prior)
    assert fast.details["path"] == "prior" and full.details["path"] == "search"
    np.testing.assert_allclose(fast.ellipse.params[:4], full.ellipse.params[:4], atol=0.01)
    np.testing.assert_allclose(fast.ellipse.params[:4], truth.params[:4], atol=0.03)
    far = Ellipse((200, 200), (80, 80), 0.0)  # a wrong prior must not be required to be right
    assert np.linalg.norm(detect_rim(img, prior=far).ellipse.center_px - truth.center_px) < 0.05


def test_tracking_from_the_previous_frame_agrees_and_lets_go_when_the_rim_moved():
    img, truth = render_wheel(WheelSpec(axis_ratio=0.9), seed=9)
    full = detect_rim(img)
    moved = np.roll(img, (1, 1), axis=(0, 1))  # the next frame: the rim moved by (1, 1) px
    track = detect_rim(moved, previous=full)
    assert track.details["path"] == "track"
    np.testing.assert_allclose(track.ellipse.center_px, truth.center_px + 1.0, atol=0.03)
    np.testing.assert_allclose(track.ellipse.axes_px, truth.axes_px, atol=0.03)
    assert track.details["blur_px"] == full.details["blur_px"]
    jumped = np.roll(img, (40, 40), axis=(0, 1))  # far beyond the tracking window
    lost = detect_rim(jumped, previous=full)
    assert lost.details["path"] in ("prior", "search")
    np.testing.assert_allclose(lost.ellipse.center_px, truth.center_px + 40.0, atol=0.05)


def test_lens_distortion_is_corrected_on_the_points():
    cam = CameraModel("cam3", 1280, 1024, K=np.array([[1500.0, 0, 641.0], [0, 1500.0, 510.0], [0, 0, 1]]),
                      dist=np.array([-0.25, 0.12, 0.001, -0.0008, 0.0]))
    ideal, truth = render_wheel(WheelSpec(center_px=(700.4, 480.6), rim_a_px=330, axis_ratio=0.88, clutter=3), seed=4)
    # the distorted photograph: each distorted pixel shows the ideal image at its undistorted place
    vv, uu = np.mgrid[0:1024, 0:1280].astype(float)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
    from station.rim.preprocess import PixelMap
    src = PixelMap(cam).undistort(uv).reshape(1024, 1280, 2).astype(np.float32)
    photo = cv2.remap(ideal, src[..., 0], src[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    det = detect_rim(photo, camera=cam, camera_id="cam3")
    assert det.ellipse_frame == "ideal_pixels"
    assert np.linalg.norm(det.ellipse.center_px - truth.center_px) < 0.1
    assert np.abs(det.ellipse.axes_px - truth.axes_px).max() < 0.1
    # points are in distorted pixels; their normalised coordinates lie on the true ellipse
    K = cam.K
    ideal_pts = det.points_norm * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    d, _ = truth.distance(ideal_pts)
    assert np.sqrt(np.mean(d**2)) < 0.15
    d_dist, _ = truth.distance(det.points_px)
    assert np.abs(d_dist).max() > 1.0  # the raw points really are distorted
    # without the camera the ellipse fitted to the distorted rim is off the ideal one
    raw = detect_rim(photo)
    assert np.linalg.norm(raw.ellipse.center_px - truth.center_px) > 1.0
    assert raw.point_sigma_px > det.point_sigma_px


def test_black_image_names_the_camera():
    with pytest.raises(RimNotFound, match="cam5: image is black"):
        detect_rim(np.zeros((1024, 1280), np.uint8), camera_id="cam5")


def test_flat_and_saturated_images():
    with pytest.raises(RimNotFound, match="no contrast"):
        detect_rim(np.full((600, 800), 128, np.uint8), camera_id="cam2")
    with pytest.raises(RimNotFound, match="saturated"):
        detect_rim(np.full((600, 800), 255, np.uint8), camera_id="cam2")


def test_image_without_a_wheel():
    rng = np.random.default_rng(2)
    img = np.full((1024, 1280), 110, np.float32)
    for _ in range(30):
        p = rng.uniform([0, 0], [1280, 1024]).astype(int)
        q = p + rng.integers(-300, 300, 2)
        cv2.rectangle(img, tuple(map(int, p)), tuple(map(int, q)), float(rng.uniform(20, 230)), -1)
    cv2.circle(img, (300, 300), 40, 200, -1)  # a small bright disc: closed, but no tyre
    img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
    with pytest.raises(RimNotFound, match="cam6: no closed rim contour"):
        detect_rim(img, camera_id="cam6")


def test_two_wheels_are_refused():
    a = WheelSpec(center_px=(330, 512), rim_a_px=190, tyre_scale=1.45, clutter=0)
    b = WheelSpec(center_px=(960, 500), rim_a_px=185, tyre_scale=1.45, clutter=0, angle_rad=0.1)
    img, _ = render_wheel(a, seed=6, extra=[b])
    with pytest.raises(RimNotFound, match="cam7: two wheel-like ellipses"):
        detect_rim(img, camera_id="cam7")


def test_bad_arrays():
    with pytest.raises(ImageError, match="too small"):
        detect_rim(np.zeros((20, 30), np.uint8), camera_id="cam1")
    with pytest.raises(ImageError, match="shape"):
        detect_rim(np.zeros((100, 100, 5), np.uint8))
    with pytest.raises(ImageError, match="pixel type"):
        detect_rim(np.zeros((100, 100), np.int32))


def test_a_hub_loses_to_a_concentric_dark_rim_seen_on_less_than_80_percent(monkeypatch):
    """An anthracite rim (candidates as a simulated dark rim gives them): the hub's contour is
    closed (82 %), the rim's flange shows on 77 % of its perimeter with a weak tyre band. A
    contour over HUB_RATIO times larger and concentric, closed as well as any chosen rim must
    be, makes the small one the hub."""
    import station.rim.choice as choice
    from station.rim.hough import Candidate

    hub = Candidate(Ellipse((684, 473), (80.4, 72.8), 0.1), 50.0, 0.82, 300)
    rim = Candidate(Ellipse((692, 467), (309.1, 287.6), 0.1), 40.0, 0.77, 900)
    looks = {80.4: (0.66, 0.68), 309.1: (0.47, 0.94)}                       # (ring, outer) measured
    monkeypatch.setattr(choice, "ring_darkness", lambda sc, e: looks[e.axes_px[0]][0])
    monkeypatch.setattr(choice, "outer_contour", lambda sc, e: looks[e.axes_px[0]][1])

    class Scene:
        s = 1.0

    best, info = choice.choose(Scene(), [hub, rim], "cam4")
    assert best is rim, info["candidates"]
    monkeypatch.setattr(choice, "MIN_COVERAGE", 0.8)        # asking the rim for 80 % instead: the hub wins
    assert choice.choose(Scene(), [hub, rim], "cam4")[0] is hub


def test_an_ellipse_inside_the_rim_is_not_another_wheel(monkeypatch):
    """A dark rim whose spoke arcs make a flat ellipse inside the rim that scores within
    AMBIGUITY_RATIO of it. Two wheels never hold each other's centre, so that is no second
    wheel; the same ellipse beside the rim still is."""
    import station.rim.choice as choice
    from station.rim.hough import Candidate

    monkeypatch.setattr(choice, "ring_darkness", lambda sc, e: 0.5)
    monkeypatch.setattr(choice, "outer_contour", lambda sc, e: 0.5)

    class Scene:
        s = 1.0

    rim = Candidate(Ellipse((677, 448), (339.0, 337.0), 0.0), 40.0, 0.62, 900)
    inside = Candidate(Ellipse((640, 260), (267.0, 169.0), 0.0), 40.0, 0.58, 500)
    assert choice.choose(Scene(), [rim, inside], "cam7")[0] is rim
    beside = Candidate(Ellipse((1400, 448), (267.0, 169.0), 0.0), 40.0, 0.58, 500)
    with pytest.raises(RimNotFound, match="two wheel-like ellipses"):
        choice.choose(Scene(), [rim, beside], "cam7")


def test_a_large_photograph_with_edges_spread_over_pixels_is_refined_where_the_edge_model_fits(monkeypatch):
    """A rim rendered at 1280x1024 and upscaled 3.125x (a 12-Mpx photograph whose edges spread
    over ~3 px, JPEG-compressed, in colour): the sub-pixel stage at a third of the resolution,
    which fits its points better in full-resolution pixels, finds it to a few hundredths.
    Refined at full resolution alone, with the windows grown with the blur, the rim is within
    0.3 px too, but the smaller scale fits its points better."""
    import station.rim.detector as detector

    img, truth = render_wheel(WheelSpec(clutter=4), seed=8)
    k = 4000 / img.shape[1]
    big = cv2.resize(img, (4000, round(img.shape[0] * k)), interpolation=cv2.INTER_CUBIC)
    ok, jpeg = cv2.imencode(".jpg", cv2.merge([big, big, big]), [cv2.IMWRITE_JPEG_QUALITY, 80])
    photo = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)
    truth_big = truth.scaled(k)
    det = detect_rim(photo)
    assert det.details.get("working_scale", 1) > 1
    assert np.linalg.norm(det.ellipse.center_px - truth_big.center_px) < 0.3
    assert np.abs(det.ellipse.axes_px - truth_big.axes_px).max() < 0.3
    monkeypatch.setattr(detector, "WORKING_SCALE_STEP", 1000)  # full resolution only
    full = detect_rim(photo)
    assert np.abs(full.ellipse.axes_px - truth_big.axes_px).max() < 0.3
    assert full.point_sigma_px > det.point_sigma_px


def test_a_sharp_image_keeps_its_full_resolution_fit_within_noise():
    img, truth = render_wheel(WheelSpec(clutter=4), seed=8)
    det = detect_rim(img)
    assert det.details.get("working_scale") is None  # 1280 px: the search scale is 3, no second try


def test_the_share_of_the_rim_at_the_sensors_white_is_measured():
    from dataclasses import replace

    from station.rim.white_edge import white_share

    spec = random_spec(np.random.default_rng(12))
    img, truth = render_wheel(replace(spec, glare=False), seed=12)
    assert detect_rim(img).details["white_share"] == 0.0
    # the metal over twice the white: every rim point has a white pixel beside it
    img, truth = render_wheel(replace(spec, rim_level=2.2 * spec.rim_level, face_level=2.2 * spec.face_level,
                                      glare=False), seed=12)
    det = detect_rim(img)
    assert det.details["white_share"] > 0.9 and det.to_dict()["white_share"] > 0.9
    # one white pixel: the points within 2 px of it
    grey = np.zeros((50, 50), np.float32)
    grey[20, 30] = 255
    pts = np.array([[30.0, 20.0], [32.4, 21.6], [33.0, 20.0], [10.0, 10.0]])
    assert white_share(grey, pts) == pytest.approx(0.5)
    assert white_share(grey, pts[:0]) == 0.0


def test_the_edge_model_cache_does_not_remember_which_blur_came_first():
    """Two blurs that share a cache entry get the projector of that entry's blur, whichever of
    them came first: a detection must not depend on the images a process saw before it."""
    from station.rim import subpixel

    s, grid = np.arange(-4.0, 5.0), np.arange(-2.0, 2.01, 0.25)
    subpixel._PROJECTORS.clear()
    first = subpixel._kink_projector(s, grid, 0.7000001)[1]
    subpixel._PROJECTORS.clear()
    subpixel._kink_projector(s, grid, 0.7000004)
    second = subpixel._kink_projector(s, grid, 0.7000001)[1]
    np.testing.assert_array_equal(first, second)


def test_the_edges_of_an_image_do_not_depend_on_where_it_sits_in_memory():
    """The same image gives bit-identical edge gradients however the allocator has moved on
    (cv2.magnitude's float32 result moved by an ulp with the arrays' alignment, and a cycle
    then measured a wheel differently after other cycles: a dark rim by 0.7 deg)."""
    import hashlib

    from station.rim.edges import detect_edges

    img, _ = render_wheel(random_spec(np.random.default_rng(3), (341, 426)), (341, 426), seed=3)
    img = np.clip(img, 0, 255).astype(np.uint8)
    rng, seen, kept = np.random.default_rng(0), set(), []
    for _ in range(25):
        kept.append(np.empty(int(rng.integers(1, 200_000)), np.uint8))  # move the allocator along
        e = detect_edges(img.copy())
        seen.add(hashlib.md5(e.points.tobytes() + e.grad.tobytes() + e.mag.tobytes()).hexdigest())
    assert len(seen) == 1


def test_the_read_noise_is_estimated_from_the_image_itself():
    from station.rim.preprocess import noise_grey, to_grey
    for sigma in (0.7, 2.0, 5.0):
        img, truth = render_wheel(WheelSpec(noise_sigma=sigma), seed=2)
        box = truth.point_at(np.linspace(0, 2 * np.pi, 64))
        # edges, spokes and glare are a minority of the box: within 15 % (plus the 8-bit steps)
        assert noise_grey(to_grey(img), box) == pytest.approx(np.hypot(sigma, 0.29), rel=0.15)


def test_a_quiet_image_reaches_less_into_the_tyre(monkeypatch):
    """Where the read noise is under QUIET_NOISE_SHARE of the edge step (here a step of 155
    grey levels) the final profiles take the shorter window (the tyre's bead band stays out
    of the kink model); over LONG_NOISE_SHARE the longer one; between them both, their edges
    weighted by where the noise lies between the two."""
    from station.rim import detector
    windows = []
    real = detector.repositioned

    def spy(grey, anchors, normals, window_px=(-3.0, 4.5), step_px=0.5):
        windows.append(window_px)
        return real(grey, anchors, normals, window_px, step_px)

    monkeypatch.setattr(detector, "repositioned", spy)
    short, long = detector.QUIET_WINDOW_PX, detector.REPOSITION_WINDOW_PX
    for sigma, taken in ((0.7, [short]), (5.0, [short, long]), (8.0, [long])):
        windows.clear()
        img, truth = render_wheel(WheelSpec(noise_sigma=sigma), seed=4)
        det = detect_rim(img, camera=_camera_of(img))
        assert windows == taken, (sigma, windows)
        share = det.details["noise_grey"] / np.median(det.points_contrast)
        assert det.details["long_window_share"] == pytest.approx(detector.window_blend(share), abs=0.02)
        assert 0.2 < det.details["long_window_share"] < 0.9 if len(taken) == 2 else \
            det.details["long_window_share"] == (0.0 if taken == [short] else 1.0)
        assert det.details["quiet_window"] == (taken != [long])
        assert det.details["noise_grey"] == pytest.approx(np.hypot(sigma, 0.29), rel=0.15)
        assert _errors(det, truth)[0] < 0.05


def test_window_blend_weights_the_long_window_between_the_two_shares():
    from station.rim.detector import LONG_NOISE_SHARE as hi, QUIET_NOISE_SHARE as lo, window_blend
    assert window_blend(0.0) == 0.0 and window_blend(lo * 0.99) == 0.0
    assert window_blend(hi) == 1.0 and window_blend(10 * hi) == 1.0
    assert window_blend((lo + hi) / 2) == pytest.approx(0.5)
    assert window_blend(float("nan")) == 1.0 and window_blend(float("inf")) == 1.0  # no estimate: the long window
    shares = np.linspace(0, 2 * hi, 41)
    assert np.all(np.diff([window_blend(x) for x in shares]) >= 0)


def _camera_of(img):
    h, w = img.shape[:2]
    K = np.array([[1800.0, 0, w / 2], [0, 1800.0, h / 2], [0, 0, 1]])
    return CameraModel("cam1", w, h, K, np.zeros(5), np.eye(3), np.zeros(3))


def test_a_rim_edge_held_on_too_little_is_refined_once_more_with_a_tolerant_misfit_test(monkeypatch):
    """When the profiles' misfit test (3x the median misfit) leaves too little of the rim - in
    a quiet image, where glare-bent profiles fail it - the search refines once more with the
    test as tolerant as in one frame's noise (RESCUE_MISFIT_GREY) instead of refusing."""
    from station.rim import detector
    real = detector.edge_points
    floors = []

    def strict_loses_most(*a, misfit_floor=0.0, **k):
        samples, blur = real(*a, misfit_floor=misfit_floor, **k)
        floors.append(misfit_floor)
        if misfit_floor == 0.0:  # the strict test: keep a quarter of the rim only
            keep = np.zeros_like(samples.ok)
            keep[: len(keep) // 4] = True
            samples.ok &= keep
        return samples, blur

    monkeypatch.setattr(detector, "edge_points", strict_loses_most)
    img, truth = render_wheel(WheelSpec(noise_sigma=0.7), seed=5)
    det = detect_rim(img)
    assert det.details.get("misfit_rescue") and detector.RESCUE_MISFIT_GREY in floors
    assert det.coverage > 0.9 and _errors(det, truth)[0] < 0.05
    monkeypatch.setattr(detector, "RESCUE_MISFIT_GREY", 0.0)
    with pytest.raises(RimNotFound, match="no closed rim contour"):
        detect_rim(img)


def test_the_misfit_floor_only_lets_more_profiles_through():
    from station.rim.subpixel import edge_points
    img, truth = render_wheel(WheelSpec(noise_sigma=0.5), seed=6)
    from station.rim.preprocess import to_grey
    grey = to_grey(img)
    strict, _ = edge_points(grey, truth, window_px=(-3.0, 4.5))
    tolerant, _ = edge_points(grey, truth, window_px=(-3.0, 4.5), misfit_floor=2.0)
    assert np.all(tolerant.ok[strict.ok]) and tolerant.ok.sum() >= strict.ok.sum()
