"""The station's search on a photograph stretched round a candidate (station/rim/photo_stretch.py,
the photograph search's second route): the affine map makes the candidate a circle and carries
ellipses back exactly; from an inner contour of a steep wheel the rim itself is found; a rim
larger than its canvas can judge is not taken. Synthetic images only."""

import numpy as np
import pytest

from station.errors import RimNotFound
from station.rim import photo_candidates as pc
from station.rim import photo_search as ps
from station.rim.ellipse import Ellipse
from station.rim.ellipse_fit import fit_direct
from station.rim.photo_stretch import CANVAS_PX, REACHES, TYRE_ROOM, back_to_photo, stretched_search, to_canvas
from tests.synthetic_wheel import WheelSpec, render_wheel

UPRIGHT = np.pi / 2


def _steep_wheel(seed=5):
    spec = WheelSpec(axis_ratio=0.32, rim_a_px=210.0, center_px=(430.4, 350.2), angle_rad=UPRIGHT - 0.05,
                     tyre_scale=1.45, background_level=170.0, clutter=8, glare=False)
    return render_wheel(spec, shape=(720, 900), seed=seed)


def _about_centre(e: Ellipse, k: float) -> Ellipse:
    return Ellipse(e.center_px, e.axes_px * k, e.angle_rad)


@pytest.mark.parametrize("reach", REACHES)
def test_the_candidate_becomes_a_circle_and_ellipses_come_back_exactly(reach):
    e = Ellipse((431.7, 352.9), (205.0, 61.0), UPRIGHT + 0.2)
    affine = to_canvas(e, reach)
    pts = e.points(64)                                                   # (64,2) on the candidate
    on_canvas = pts @ affine[:, :2].T + affine[:, 2]
    radius = np.linalg.norm(on_canvas - CANVAS_PX / 2, axis=1)
    np.testing.assert_allclose(radius, CANVAS_PX / (2 * reach), rtol=1e-9)  # a circle at the centre
    for k in (0.6, 1.0, 1.7):                                             # any concentric ellipse, and off centre
        other = Ellipse(e.center_px + [3.0, -7.0], e.axes_px * k, e.angle_rad - 0.1)
        q = other.points(32) @ affine[:, :2].T + affine[:, 2]
        back = back_to_photo(fit_direct(q), affine)
        np.testing.assert_allclose(back.params, other.params, atol=1e-6)


def test_from_an_inner_contour_the_rim_itself_is_found():
    img, truth = _steep_wheel()
    grey = img.astype(np.float32)
    found = stretched_search(grey, _about_centre(truth, 0.7))          # a disc or the lip's inner edge
    assert found, "the station's search found nothing on the stretched wheel"
    best = min(found, key=lambda f: np.linalg.norm(f.center_px - truth.center_px))
    assert np.linalg.norm(best.center_px - truth.center_px) < 3.0
    np.testing.assert_allclose(best.axes_px, truth.axes_px, rtol=0.03)   # the lip, not the tyre (x1.45)


def test_a_rim_too_large_for_its_canvas_to_judge_is_not_taken():
    img, truth = _steep_wheel()
    candidate = _about_centre(truth, 0.9 * TYRE_ROOM / max(REACHES))   # the rim 1.8x its candidate: on the
    assert stretched_search(img.astype(np.float32), candidate) == []   # canvas, but its tyre's outline is not


def test_the_photograph_search_takes_the_stretched_rim_when_no_candidate_is_the_lip(monkeypatch):
    """With an inner contour for its only candidate (as round a spoke star or a dark barrel),
    the photograph search returns the rim, refined on the photograph and judged as any rim."""
    img, truth = _steep_wheel(seed=6)
    L, s = pc.search_image(img.astype(np.float32))
    inner = _about_centre(truth, 0.7).scaled(1 / s)
    monkeypatch.setattr(pc, "candidates", lambda *a, **k: [{"ellipse": inner, "cover": 0.9, "support": 3,
                                                             "level": 0.0}])
    monkeypatch.setattr(ps, "structure", _inner_fails(ps.structure, inner))
    det = ps.detect_in_photo(img, camera_id="steep")
    assert np.linalg.norm(det.ellipse.center_px - truth.center_px) < 1.5
    np.testing.assert_allclose(det.ellipse.axes_px, truth.axes_px, atol=1.5)
    assert det.details["path"] == "photo" and det.details["outside_share"] >= 0.5


def test_a_rim_the_stations_search_took_twice_needs_no_2x_step_to_its_tyre(monkeypatch):
    """A sunlit tyre beside a shaded lip is not twice darker than the lip on half the turn. A
    rim the station's search took on two canvases (here both reaches round one candidate: once
    with its tyre on the canvas, once too large for it) is taken without that step, the tyre
    still rubber-dark for the photo and ending; the same rim seen on one canvas only is not."""
    img, truth = _steep_wheel(seed=6)
    L, s = pc.search_image(img.astype(np.float32))
    inner = _about_centre(truth, 0.7).scaled(1 / s)
    monkeypatch.setattr(pc, "candidates", lambda *a, **k: [{"ellipse": inner, "cover": 0.9, "support": 3,
                                                             "level": 0.0}])
    structure = _inner_fails(ps.structure, inner)

    def sunlit(L, e, rubber_level):
        st = structure(L, e, rubber_level)
        return {**st, "dark": min(st["dark"], 0.2)}

    monkeypatch.setattr(ps, "structure", sunlit)
    det = ps.detect_in_photo(img, camera_id="sunlit")
    assert np.linalg.norm(det.ellipse.center_px - truth.center_px) < 1.5
    np.testing.assert_allclose(det.ellipse.axes_px, truth.axes_px, atol=1.5)

    once = ps.stretched_search
    monkeypatch.setattr(ps, "stretched_search", lambda grey, e, cut=None: once(grey, e)[:1])
    with pytest.raises(RimNotFound) as ex:
        ps.detect_in_photo(img, camera_id="sunlit")
    assert "no dark tyre" in str(ex.value)


def _inner_fails(structure, inner: Ellipse):
    """``structure`` as it is, but for the inner candidate: no tyre round it (a disc's dark
    surround is the rim's face, not rubber), so that only the stretched route can take the rim."""
    def wrapped(L, e, rubber_level):
        st = structure(L, e, rubber_level)
        return {**st, "dark": 0.0} if pc.same_ellipse(e, inner, 0.02) else st
    return wrapped


def test_an_accepted_rim_is_looked_round_by_the_stations_search():
    """A hubcap or a disc taken for the rim gives way to the rim round it, which the station's
    search sees on the wheel stretched round it; the rim itself is refined again from there
    where that covers more of its perimeter, and kept as it is where nothing does."""
    from types import SimpleNamespace

    img, truth = _steep_wheel(seed=7)
    grey = img.astype(np.float32)
    L, s = pc.search_image(grey)
    rubber = float(np.percentile(L[::2, ::2], ps.RUBBER_PERCENTILE))
    hubcap = SimpleNamespace(ellipse=_about_centre(truth, 0.65))
    det, record = ps._looked_round(grey, hubcap, {"support": 2}, L, s, rubber, "steep")
    assert det is not hubcap and record["stretched"] and record["support"] == 2
    assert np.linalg.norm(det.ellipse.center_px - truth.center_px) < 1.5
    np.testing.assert_allclose(det.ellipse.axes_px, truth.axes_px, atol=1.5)
    rim = SimpleNamespace(ellipse=truth, coverage=1.0)                   # nothing covers more of it
    assert ps._looked_round(grey, rim, {}, L, s, rubber, "steep") == (rim, {})
    off = SimpleNamespace(ellipse=_about_centre(truth, 1.04), coverage=0.4)  # the rim, its edge found on 40 %
    det, record = ps._looked_round(grey, off, {}, L, s, rubber, "steep")
    assert det is not off and det.coverage > 0.4 and record["stretched"]
    np.testing.assert_allclose(det.ellipse.axes_px, truth.axes_px, atol=1.5)


def test_an_accepted_contour_with_a_larger_rim_round_it_is_refused():
    """A disc half the rim's size, taken for the rim: on the wheel stretched round it the
    station's search sees the rim, but too large for its canvas to judge (its tyre's outline
    cut off), so the rim cannot replace it; the disc is refused rather than returned, since a
    closed contour holds it."""
    from types import SimpleNamespace

    img, truth = _steep_wheel(seed=7)
    grey = img.astype(np.float32)
    L, s = pc.search_image(grey)
    rubber = float(np.percentile(L[::2, ::2], ps.RUBBER_PERCENTILE))
    disc = SimpleNamespace(ellipse=_about_centre(truth, 0.5), coverage=0.9)
    why = ps._looked_round(grey, disc, {}, L, s, rubber, "steep")
    assert isinstance(why, str) and why.startswith("a larger contour round it")


def test_the_candidate_stretched_round_does_not_hide_the_rim_found_inside_it(monkeypatch):
    """A region lit beyond the lip (1.2 times the rim) that passes the tyre tests but whose own
    lip edge is not found: the station's search, round it, takes the rim inside it, and that
    rim is returned, not refused as the region's inner contour (step 5 would refuse it)."""
    from station.errors import RimNotFound

    img, truth = _steep_wheel(seed=6)
    L, s = pc.search_image(img.astype(np.float32))
    region = _about_centre(truth, 1.2)
    monkeypatch.setattr(pc, "candidates", lambda *a, **k: [{"ellipse": region.scaled(1 / s), "cover": 0.9,
                                                             "support": 3, "level": 0.0}])
    structure, refined = ps.structure, ps._refined

    def tyre_round_region(L, e, rubber_level):
        st = structure(L, e, rubber_level)
        return {**st, "dark": 1.0, "outside": 1.0, "rubber": True} if pc.same_ellipse(e, region.scaled(1 / s), 0.02) else st

    def no_lip_edge_on_region(grey, e, camera_id, verdict):
        if pc.same_ellipse(e, region, 0.02):
            raise RimNotFound("no closed rim contour")
        return refined(grey, e, camera_id, verdict)

    monkeypatch.setattr(ps, "structure", tyre_round_region)
    monkeypatch.setattr(ps, "_refined", no_lip_edge_on_region)
    det = ps.detect_in_photo(img, camera_id="steep")
    assert np.linalg.norm(det.ellipse.center_px - truth.center_px) < 1.5
    np.testing.assert_allclose(det.ellipse.axes_px, truth.axes_px, atol=1.5)
