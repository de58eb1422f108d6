"""Ellipse parametrisation (eqs 1-3), conic form, distances, the direct and geometric fits,
and the blurred-step profile fit behind the sub-pixel edge points."""

import cv2
import numpy as np
import pytest
from scipy.special import erf

from station.rim.ellipse import Ellipse
from station.rim.ellipse_fit import fit_direct, fit_geometric
from station.rim.subpixel import fit_steps

E = Ellipse((412.25, 300.5), (250.0, 217.5), 0.4)


def test_points_satisfy_eqs_1_to_3_and_the_conic():
    pts = E.points(200)
    u_e = (pts[:, 0] - 412.25) * np.cos(0.4) + (pts[:, 1] - 300.5) * np.sin(0.4)
    v_e = -(pts[:, 0] - 412.25) * np.sin(0.4) + (pts[:, 1] - 300.5) * np.cos(0.4)
    np.testing.assert_allclose(u_e**2 / 250**2 + v_e**2 / 217.5**2, 1.0, atol=1e-12)
    A, B, C, D, F_, G = E.to_conic()
    u, v = pts.T
    np.testing.assert_allclose(A * u * u + B * u * v + C * v * v + D * u + F_ * v + G, 0, atol=1e-12)
    back = Ellipse.from_conic(E.to_conic())
    np.testing.assert_allclose(back.params, E.params, atol=1e-9)


def test_axes_are_ordered_and_angle_wrapped():
    e = Ellipse((0, 0), (100, 150), 0.2)  # b > a: swapped, turned by 90 degrees
    assert e.axes_px[0] == 150 and e.axes_px[1] == 100
    assert e.angle_rad == pytest.approx(0.2 + np.pi / 2 - np.pi)
    np.testing.assert_allclose(Ellipse.from_conic(e.to_conic()).to_conic(), e.to_conic(), atol=1e-12)


def test_orthogonal_distance_matches_brute_force():
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 2 * np.pi, 300)
    off = rng.uniform(-5, 5, 300)
    pts = E.point_at(t) + off[:, None] * E.normal_at(t)
    d, _ = E.distance(pts)
    dense = E.points(100000)

    # brute force by chunks
    mins = np.empty(len(pts))
    for i in range(0, len(pts), 20):
        dd = ((pts[i:i + 20, None, :] - dense[None]) ** 2).sum(-1)
        mins[i:i + 20] = np.sqrt(dd.min(1))
    np.testing.assert_allclose(np.abs(d), mins, atol=2e-3)  # the dense polyline is 0.016 px coarse
    np.testing.assert_allclose(d, off, atol=1e-9)  # offset along the normal is the distance


def test_scaling_keeps_pixel_centre_convention():
    e2 = E.scaled(2.0)
    np.testing.assert_allclose(e2.center_px, (E.center_px + 0.5) * 2 - 0.5)
    np.testing.assert_allclose(e2.scaled(0.5).params, E.params, atol=1e-12)


def test_direct_fit_exact_on_clean_points_and_agrees_with_opencv_convention():
    pts = E.points(50)
    np.testing.assert_allclose(fit_direct(pts).params, E.params, atol=1e-6)
    (cx, cy), (d1, d2), ang = cv2.fitEllipseDirect(pts.astype(np.float32))
    ocv = Ellipse((cx, cy), (d1 / 2, d2 / 2), np.radians(ang))
    np.testing.assert_allclose(ocv.params, E.params, atol=2e-3)


def test_geometric_fit_rejects_outliers_and_its_covariance_matches_the_spread():
    rng = np.random.default_rng(7)
    errs, sds = [], []
    for trial in range(30):
        t = rng.uniform(0, 2 * np.pi, 600)
        pts = E.point_at(t) + rng.normal(0, 0.1, (600, 1)) * E.normal_at(t)
        bad = rng.choice(600, 40, replace=False)
        pts[bad] += rng.normal(0, 6, (40, 2))  # 7 % gross outliers
        fit = fit_geometric(pts, init=Ellipse(E.center_px + 2, E.axes_px * 1.01, E.angle_rad + 0.02))
        errs.append(fit.ellipse.params - E.params)
        sds.append(np.sqrt(np.diag(fit.cov)))
        assert fit.sigma_px == pytest.approx(0.1, rel=0.2)
        assert (~fit.inliers[bad]).mean() > 0.8
    errs, sds = np.array(errs), np.array(sds)
    assert np.abs(errs[:, :4]).max() < 0.05
    ratio = errs.std(axis=0) / sds.mean(axis=0)
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio


def test_step_fit_finds_the_50_percent_crossing_without_bias():
    rng = np.random.default_rng(3)
    n = 4000
    s = np.arange(-4, 4.01, 0.5)
    s0 = rng.uniform(-1.0, 1.0, n)
    w = rng.uniform(0.6, 1.5, n)
    prof = 100 - 30 * s[None, :] * 0.1 - 60 * erf((s[None, :] - s0[:, None]) / (np.sqrt(2) * w[:, None]))
    p, rms, ok = fit_steps(prof, s)
    assert ok.all()
    np.testing.assert_allclose(p[:, 3], s0, atol=2e-4)
    noisy = prof + rng.normal(0, 2.0, prof.shape)
    p, rms, ok = fit_steps(noisy, s)
    err = p[ok, 3] - s0[ok]
    assert abs(err.mean()) < 0.005 and err.std() < 0.06
    assert rms[ok].mean() == pytest.approx(2.0, rel=0.25)


def _kink_profiles(rng, n, s, sigma, metal_slope, tyre_slope, jump=-120.0):
    """Blurred piecewise-linear profiles with a jump at s0 (the model of subpixel.fit_kinks)."""
    from scipy.stats import norm
    s0 = rng.uniform(-0.8, 0.8, n)
    x = s[None, :] - s0[:, None]
    Phi, phi = norm.cdf(x / sigma), norm.pdf(x / sigma)
    ramp = metal_slope * (x - x * Phi - sigma * phi) + tyre_slope * (x * Phi + sigma * phi)
    return 150 + jump * Phi + ramp, s0


def test_kink_fit_is_unbiased_where_the_lip_is_shaded_as_a_ramp():
    from station.rim.subpixel import estimate_blur, fit_kinks
    rng = np.random.default_rng(5)
    s = np.arange(-3, 4.51, 0.5)
    # metal side darkening toward the edge (rounded lip), flat tyre
    prof, s0 = _kink_profiles(rng, 2000, s, 0.85, metal_slope=-25.0, tyre_slope=0.0)
    noisy = prof + rng.normal(0, 2.0, prof.shape)
    sigma = estimate_blur(noisy[:100], s)
    assert sigma == pytest.approx(0.85, abs=0.05)
    est, h, rms, ok = fit_kinks(noisy, s, sigma, grid_step=0.125, refine=False)
    err = est[ok] - s0[ok]
    assert ok.mean() > 0.98 and abs(err.mean()) < 0.02 and err.std() < 0.12
    # a plain blurred step with one common slope is pulled inside by the ramp
    p, _, ok2 = fit_steps(noisy, s)
    assert (p[ok2, 3] - s0[ok2]).mean() < -0.1


def _kink_edge_image(theta, offset_px, sigma, metal_slope=-25.0, jump=-120.0, size=48, width=None):
    """(size, width or size) float32 image of the blurred step-and-kink edge (the model of
    fit_kinks) at pixel centres: bright, shaded metal up to a straight edge with outward
    normal at angle ``theta`` through the image centre moved ``offset_px`` along it; and that
    normal (2,)."""
    from scipy.stats import norm
    width = width or size
    n = np.array([np.cos(theta), np.sin(theta)])
    yy, xx = np.mgrid[0:size, 0:width].astype(float)
    x = (xx - width / 2) * n[0] + (yy - size / 2) * n[1] - offset_px   # px past the edge
    Phi, phi = norm.cdf(x / sigma), norm.pdf(x / sigma)
    return (150 + jump * Phi + metal_slope * (x - x * Phi - sigma * phi)).astype(np.float32), n


def _edge_profiles_setup(rng, theta, offset, n=40, size=48, half_length=8.0, width=None):
    """Profile origins (n,2) along the straight kink edge of ``_kink_edge_image`` of that
    size (jittered +/-0.5 px across it), their unit normals (n,2) and the edge's distance
    from each, along the normal (n,)."""
    n_vec = np.array([np.cos(theta), np.sin(theta)])
    t = np.array([-n_vec[1], n_vec[0]])
    along = rng.uniform(-0.5, 0.5, (n, 1)) * n_vec + np.linspace(-half_length, half_length, n)[:, None] * t
    centre = np.array([(width or size) / 2, size / 2])
    return centre + offset * n_vec + along, np.repeat(n_vec[None, :], n, 0), -(along @ n_vec)


def test_profiles_sampled_without_interpolation_blur_put_a_shaded_edge_where_it_is():
    """Bilinear interpolation blurs a profile by up to 1/4 px^2 more, by how far its samples
    fall between pixels: against a kink model at the image's blur, a lip shaded as a ramp
    then moves the edge outward by ~k sigma dsigma / h (0.06 px here), differently round a
    rim. Lanczos-sampled profiles reproduce the blurred image and put it where it is."""
    from station.rim.subpixel import fit_kinks, sample_profiles
    rng = np.random.default_rng(1)
    sigma, s = 0.8, np.arange(-3, 4.51, 0.5)
    errors = {cv2.INTER_LANCZOS4: [], cv2.INTER_LINEAR: []}
    for theta in np.radians([0, 10, 30, 45, 60, 80]):
        for offset in (0.0, 0.25, 0.5, 0.75):
            img, _ = _kink_edge_image(theta, offset, sigma)
            base, normals, edge = _edge_profiles_setup(rng, theta, offset)
            for interp, errs in errors.items():
                s0, _, _, ok = fit_kinks(sample_profiles(img, base, normals, s, interp), s, sigma,
                                         grid_step=0.125, refine=False)
                errs.append(s0[ok] - edge[ok])
    lanczos, linear = (np.concatenate(errors[k]) for k in (cv2.INTER_LANCZOS4, cv2.INTER_LINEAR))
    assert len(lanczos) > 0.98 * 6 * 4 * 40
    assert abs(lanczos.mean()) < 0.01 and np.abs(lanczos).max() < 0.06
    assert linear.mean() > 0.03  # what repositioned's sampling avoids


@pytest.mark.parametrize("noise", [0.0, 5.0])
def test_repositioned_finds_the_edge_at_the_blur_of_its_own_profiles(noise):
    """From anchors on a curve 0.4 px inside the edge (as a fitted ellipse may run), the edge
    is found where it is, at the blur the Lanczos profiles have, estimated from arc averages
    aligned on the anchors, also at a noise of 5 grey levels."""
    from station.rim.subpixel import repositioned
    rng = np.random.default_rng(2)
    sigma = 0.8
    errs, blurs = [], []
    for theta in np.radians([88.5, 89.3, 91.2]):  # (not 90: one sub-pixel phase all along)
        # an edge as long as a rim, a profile every 1.5 px as the final pass takes them
        img, _ = _kink_edge_image(theta, 0.3, sigma, size=64, width=1600)
        img = img + rng.normal(0, noise, img.shape).astype(np.float32)
        base, normals, edge = _edge_profiles_setup(rng, theta, 0.3, n=1000, size=64, half_length=750.0,
                                                   width=1600)
        anchors = base + (edge - 0.4)[:, None] * normals                  # 0.4 px inside the edge
        d, found, blur = repositioned(img, anchors, normals)
        assert found.mean() > 0.95
        errs.append(d[found] - 0.4)
        blurs.append(blur)
    e = np.concatenate(errs)
    assert abs(e.mean()) < (0.01 if noise == 0 else 0.02)
    assert np.array(blurs) == pytest.approx(sigma, rel=0.02 if noise == 0 else 0.04)


def test_a_lip_rounded_across_the_window_takes_the_curved_model_and_an_ordinary_one_does_not():
    """A narrow lip shaded as rounded: the profile rises to the lip's top 1.5 px inside the
    edge and falls to it. The straight metal side puts the edge 0.35 px inside; the curved
    model, taken where its residual falls significantly on most of the arc, finds it. A lip
    shaded as a straight ramp keeps the straight model, profile for profile."""
    from scipy.stats import norm

    from station.rim.subpixel import _curved_where_needed, fit_kinks
    rng = np.random.default_rng(7)
    s = np.arange(-3, 4.51, 0.5)
    sigma, n = 0.85, 720
    s0 = rng.uniform(-0.8, 0.8, n)
    x = s[None, :] - s0[:, None]
    Phi, phi = norm.cdf(x / sigma), norm.pdf(x / sigma)
    lin = x - x * Phi - sigma * phi                              # x on the metal side, blurred
    quad = (x * x + sigma ** 2) * (1 - Phi) - x * sigma * phi    # x^2 on the metal side, blurred
    rounded = 150 - 120 * Phi - 25.0 * (quad + 3.0 * lin) + rng.normal(0, 2.0, (n, len(s)))  # top at -1.5 px
    straight = fit_kinks(rounded, s, sigma, grid_step=0.125, refine=False)
    auto = _curved_where_needed(rounded, s, sigma, *straight)
    assert (straight[0] - s0)[straight[3]].mean() < -0.25
    err = (auto[0] - s0)[auto[3]]
    assert auto[3].mean() > 0.98 and abs(err.mean()) < 0.05 and err.std() < 0.15
    ramp, s0r = _kink_profiles(rng, n, s, sigma, metal_slope=-25.0, tyre_slope=0.0)
    ramp = ramp + rng.normal(0, 2.0, ramp.shape)
    plain = fit_kinks(ramp, s, sigma, grid_step=0.125, refine=False)
    kept = _curved_where_needed(ramp, s, sigma, *plain)
    assert np.mean(kept[0] == plain[0]) > 0.98


def test_profiles_whose_tyre_side_climbs_back_are_rejected():
    from station.rim.subpixel import _tyre_side_flat, fit_kinks
    rng = np.random.default_rng(6)
    s = np.arange(-3, 4.51, 0.5)
    good, _ = _kink_profiles(rng, 200, s, 0.9, metal_slope=0.0, tyre_slope=0.0)
    bright_bead, _ = _kink_profiles(rng, 200, s, 0.9, metal_slope=-10.0, tyre_slope=12.0, jump=-20.0)
    for prof, expect in ((good, 1.0), (bright_bead, 0.0)):
        est, h, rms, ok = fit_kinks(prof, s, 0.9)
        assert _tyre_side_flat(prof, s, est, h, 0.9).mean() == pytest.approx(expect, abs=0.05)


def test_blur_estimate_ignores_profiles_with_a_highlight_up_to_the_edge():
    """Where a specular highlight on the lip runs down into the edge, the profile looks like a
    broad step of high contrast. The blur is the median of the per-profile estimates: a
    quarter of such profiles moves it little, while a least-squares blur over all profiles
    (where the highest-contrast ones weigh the most) is pulled."""
    from scipy.ndimage import gaussian_filter1d

    from station.rim.subpixel import BLUR_GRID_PX, estimate_blur, fit_kinks
    rng = np.random.default_rng(12)
    s = np.arange(-3, 4.51, 0.5)
    clean, _ = _kink_profiles(rng, 150, s, 0.85, metal_slope=-5.0, tyre_slope=0.0, jump=-50.0)
    fine = np.arange(-6, 7.5, 0.05)  # rendered finely, blurred by the same PSF, then sampled
    x = fine[None, :] - rng.uniform(-0.5, 0.5, 50)[:, None]
    sharp = np.where(x < 0, 60 + 150 * np.exp(-((x + 3.0) / 2.0) ** 2), 20.0)
    lit = np.stack([np.interp(s, fine, row) for row in gaussian_filter1d(sharp, 0.85 / 0.05, axis=1)])
    prof = np.vstack([clean, lit]) + rng.normal(0, 2.0, (200, len(s)))
    assert estimate_blur(prof, s) == pytest.approx(0.85, abs=0.08)
    total = [np.sum(fit_kinks(prof, s, sg, refine=False)[2] ** 2) for sg in BLUR_GRID_PX]
    assert BLUR_GRID_PX[int(np.argmin(total))] > 1.0


def test_repositioned_with_too_few_points_finds_nothing_and_moves_nothing():
    from station.rim.subpixel import repositioned
    img, n = _kink_edge_image(0.3, 0.0, 0.8)
    anchors = np.full((5, 2), 24.0)
    d, found, blur = repositioned(img, anchors, np.repeat(n[None, :], 5, 0))
    assert not found.any() and np.all(d == 0) and np.isnan(blur)


def test_a_soft_image_keeps_the_passes_points():
    """Above WIDE_BLUR_PX the bilinear samples' own blur is a small share of the edge's: the
    detector's final points are the passes' (and the soft-focus decisions as measured)."""
    from types import SimpleNamespace

    from station.rim import detector
    from station.rim.subpixel import WIDE_BLUR_PX
    fit, samples, mask = SimpleNamespace(), SimpleNamespace(), np.ones(3, bool)
    out = detector._repositioned(np.zeros((8, 8), np.float32), fit, samples, mask, None, WIDE_BLUR_PX + 0.1)
    assert out[0] is fit and out[1] is samples and out[2] is mask


def test_points_within_the_same_contour_floor_stay_inliers_whatever_the_noise():
    """In a quiet image (an 8-frame mean) the points scatter 0.02 px: 3.5 robust sigmas then
    leave out an arc that a lamp biases by 0.15 px, though it is the same edge; the floor
    (detector.SAME_CONTOUR_PX) keeps it, and an arc 1 px off (another contour) stays out."""
    from station.rim.detector import SAME_CONTOUR_PX
    rng = np.random.default_rng(3)
    e = Ellipse(np.array([600.0, 500.0]), np.array([300.0, 280.0]), 0.2)
    t = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    pts = e.point_at(t)
    normals = e.normal_at(t)
    offset = rng.normal(0, 0.02, len(t))
    biased = (t > 1.0) & (t < 1.6)
    other = (t > 4.0) & (t < 4.3)
    offset[biased] += 0.15
    offset[other] += 1.0
    pts = pts + offset[:, None] * normals
    strict = fit_geometric(pts, init=e)
    floored = fit_geometric(pts, init=e, reject_floor_px=SAME_CONTOUR_PX)
    assert strict.inliers[biased].mean() < 0.2
    assert floored.inliers[biased].mean() > 0.95
    assert not floored.inliers[other].any() and not strict.inliers[other].any()
