"""The 3-D circle fit with the points weighted by their edge step, and the second fit
without a view's faint points (station.wheel.circle_fit.contrast_weights, _without_faint)."""

import numpy as np
import pytest

from simulators.vehicle import random_vehicle
import station.wheel.circle_fit as circle_fit
from station.wheel.circle_fit import CircleFitSettings, refine_circle
from station.wheel.paper import reconstruct_paper
from tests.wheel_fixtures import angle_deg as _angle_deg, pair_cameras as _pair, rim_points as _rim


def test_contrast_weights_are_the_step_over_the_median_step_at_most_one():
    w = circle_fit.contrast_weights(np.array([10.0, 20.0, 40.0, 40.0, 80.0]))
    np.testing.assert_allclose(w, [0.25, 0.5, 1.0, 1.0, 1.0])
    assert circle_fit.contrast_weights(np.array([0.0, 40.0, 40.0]))[0] == circle_fit.MIN_CONTRAST_WEIGHT
    np.testing.assert_array_equal(circle_fit.contrast_weights(np.zeros(4)), np.ones(4))  # no step at all: unweighted


def test_a_faint_arc_pulled_off_the_flange_moves_the_contrast_weighted_fit_less():
    """A dark rim's shaded arc: there the flange edge is faint and the sub-pixel point sits
    0.6 px outside it (on the tyre bead's shading), in both views, under every outlier test.
    Weighted by their edge step, those points pull the axis far less; with equal steps the
    weighted fit is the plain one."""
    rng = np.random.default_rng(5)
    v = random_vehicle(np.random.default_rng(12))
    c, w, X = _rim(v, "FR")
    cl, cr = _pair(c[0], c[1])
    faint = (np.arange(len(X)) * 2 * np.pi / len(X) + 0.3) % (2 * np.pi) < np.radians(70)  # one 70-degree arc
    views, contrast = [], []
    for cam in (cl, cr):
        p_true = cam.project(X)
        p = p_true.copy()
        d = p_true - p_true.mean(axis=0)
        p[faint] += 0.6 * d[faint] / np.linalg.norm(d[faint], axis=1, keepdims=True)
        views.append(p + rng.normal(0, 0.08, p.shape))
        contrast.append(np.where(faint, 8.0, 40.0) + rng.uniform(-2, 2, len(X)))
    paper = reconstruct_paper(views[0], views[1], cl, cr)
    settings = CircleFitSettings(stray_arc_passes=0, grazing_test=False)
    plain = refine_circle(views[0], views[1], cl, cr, paper, settings=settings)
    weighted = refine_circle(views[0], views[1], cl, cr, paper, contrast=tuple(contrast),
                             settings=settings)
    err_p, err_w = _angle_deg(plain.axis_station, w), _angle_deg(weighted.axis_station, w)
    assert err_w < 0.5 * err_p, (err_w, err_p)
    equal = refine_circle(views[0], views[1], cl, cr, paper,
                          contrast=(np.full(len(X), 40.0), np.full(len(X), 40.0)), settings=settings)
    np.testing.assert_allclose(equal.axis_station, plain.axis_station, atol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.trace(equal.cov_axis)), np.sqrt(np.trace(plain.cov_axis)), rtol=1e-9)


def _one_view_faint_arc(seed, offset_px):
    """A pair where the reference view does not see a 100-degree stretch of the rim and the
    precision view sees it only faintly (a twelfth of the median edge step: 4 against 50), its points
    ``offset_px`` outside the flange: (views, contrast, cameras, true axis, paper fit)."""
    rng = np.random.default_rng(seed)
    v = random_vehicle(np.random.default_rng(seed + 20))
    c, w, X = _rim(v, "RL")
    cl, cr = _pair(c[0], c[1])
    stretch = (np.arange(len(X)) * 2 * np.pi / len(X) + 0.5) % (2 * np.pi) < np.radians(100)
    p = cl.project(X)
    d = p - p.mean(axis=0)
    p[stretch] += offset_px * d[stretch] / np.linalg.norm(d[stretch], axis=1, keepdims=True)
    pl = p + rng.normal(0, 0.05, p.shape)
    pr = cr.project(X[~stretch]) + rng.normal(0, 0.05, (int((~stretch).sum()), 2))
    con_l = np.where(stretch, 4.0, 50.0) + rng.uniform(-1, 1, len(X))
    con_r = 50.0 + rng.uniform(-1, 1, len(pr))
    return (pl, pr), (con_l, con_r), (cl, cr), w, reconstruct_paper(pl, pr, cl, cr)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_faint_arc_one_view_alone_sees_is_weighed_against_the_fit_without_it(seed):
    """The faint points count little in the final solve, but the outlier tests before it are
    unweighted: an arc 1.2 px off that only one view sees tilts the circle they judge by
    (0.01-0.06 deg here). The fit without the faint points is weighed against it
    (``_without_faint``), and the axis comes out as if the arc were not there; where the faint
    arc lies on the flange, it changes little."""
    views, contrast, (cl, cr), w, paper = _one_view_faint_arc(seed, 1.2)
    err, fits = {}, {}
    for on in (False, True):
        fits[on] = refine_circle(*views, cl, cr, paper, contrast=contrast,
                                 settings=CircleFitSettings(faint_test=on))
        err[on] = _angle_deg(fits[on].axis_station, w)
    assert err[True] < 0.006, err
    if err[False] > 0.008:  # (seed 2: the arc hardly tilts it)
        assert err[True] < 0.6 * err[False] and fits[True].faint_left_out, err
    views, contrast, (cl, cr), w, paper = _one_view_faint_arc(seed, 0.0)
    on_flange = refine_circle(*views, cl, cr, paper, contrast=contrast)
    without_test = refine_circle(*views, cl, cr, paper, contrast=contrast,
                                 settings=CircleFitSettings(faint_test=False))
    assert _angle_deg(on_flange.axis_station, w) < 0.006 and not on_flange.faint_left_out
    assert _angle_deg(on_flange.axis_station, without_test.axis_station) < 0.004


def test_live_keeps_the_faint_choice_without_a_second_fit(monkeypatch):
    """``station live`` leaves out the points ``not_faint`` rejects when its baseline did, and
    fits once (``faint_test=False``): the update matches the baseline's fit without them."""
    views, contrast, (cl, cr), w, paper = _one_view_faint_arc(0, 1.2)
    base = refine_circle(*views, cl, cr, paper, contrast=contrast, settings=CircleFitSettings(grazing_test=False))
    assert base.faint_left_out
    keep = [circle_fit.not_faint(c) for c in contrast]
    assert not keep[0].all() and keep[1].all()
    fits = []
    real = circle_fit._fit_circle
    monkeypatch.setattr(circle_fit, "_fit_circle", lambda *a, **k: fits.append(1) or real(*a, **k))
    update = refine_circle(views[0][keep[0]], views[1][keep[1]], cl, cr, base, init_is_fitted=True,
                           contrast=(contrast[0][keep[0]], contrast[1][keep[1]]),
                           settings=CircleFitSettings(grazing_test=False, faint_test=False))
    assert len(fits) == 1 and not update.faint_left_out
    assert _angle_deg(update.axis_station, base.axis_station) < 0.003
