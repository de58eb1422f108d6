"""The photograph search (station/rim/photo_search.py, ``station detect --search photo``): a steep,
upright wheel in clutter is found on its lip; a lamp in a grey body, a lone dark ellipse (a
tyre without a rim), a wheel too oblique or too small are refused with the reason; bad input
is a message. Synthetic images only (CI has no photographs)."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from station.cli import main
from station.errors import ImageError, RimNotFound
from station.rim import photo_candidates as pc
from station.rim.ellipse import Ellipse
from station.rim.photo_search import _after_refinement, detect_in_photo, geometry_verdict, hidden_by
from tests.synthetic_wheel import WheelSpec, render_wheel

UPRIGHT = np.pi / 2  # major axis along the image's vertical: a wheel standing on the ground
SHAPE = (700, 900)


def _steep_wheel(seed=3, **kw):
    spec = dict(axis_ratio=0.3, rim_a_px=200.0, center_px=(420.3, 340.6), angle_rad=UPRIGHT + 0.03,
                tyre_scale=1.45, background_level=170.0, clutter=10, glare=False)
    spec.update(kw)
    return render_wheel(WheelSpec(**spec), shape=SHAPE, seed=seed)


def _scene(level=170.0, seed=0):
    """A light body with some clutter and no wheel: (H,W) float32."""
    img, _ = render_wheel(WheelSpec(rim_a_px=1.0, tyre_scale=1.0, center_px=(-50, -50), background_level=level,
                                    clutter=6, glare=False), shape=SHAPE, seed=seed)
    return img.astype(np.float32)


def test_steep_upright_wheel_in_clutter_is_found_on_its_lip():
    img, truth = _steep_wheel()
    det = detect_in_photo(img, camera_id="steep")
    e = det.ellipse
    assert det.details["path"] == "photo"
    assert np.linalg.norm(e.center_px - truth.center_px) < 1.0
    np.testing.assert_allclose(e.axes_px, truth.axes_px, atol=1.0)  # the lip, not the tyre (x1.45) nor the disc
    assert np.mean(np.abs(e.distance(truth.points(90))[0])) < 0.7
    assert det.coverage > 0.7


def test_the_station_path_is_the_station_search():
    from station.commands.detect_photograph import detect_photograph
    from station.rim import detect_rim

    img, _ = render_wheel(WheelSpec(axis_ratio=0.88, rim_a_px=200, center_px=(400.2, 300.6)), shape=(640, 800),
                          seed=21)
    a = detect_photograph(img, 1.0, "x", search="station")
    b = detect_rim(img, camera_id="x")
    np.testing.assert_array_equal(a.ellipse.params, b.ellipse.params)
    np.testing.assert_array_equal(a.points_px, b.points_px)


def test_station_detect_takes_the_station_search_first_then_the_photograph_search(tmp_path, capsys):
    from station.commands.detect_photograph import detect_photograph

    near, _ = render_wheel(WheelSpec(axis_ratio=0.88, rim_a_px=200, center_px=(400.2, 300.6), angle_rad=UPRIGHT),
                           shape=(640, 800), seed=21)
    a = detect_photograph(near, 1.0, "x")                                   # auto, the default
    assert a.details["search"] == "station"
    np.testing.assert_array_equal(a.ellipse.params, detect_photograph(near, 1.0, "x", search="station").ellipse.params)
    steep, truth = _steep_wheel()
    with pytest.raises(RimNotFound):
        detect_photograph(steep, 1.0, "steep", search="station")
    b = detect_photograph(steep, 1.0, "steep")
    assert b.details["search"] == "photo" and np.linalg.norm(b.ellipse.center_px - truth.center_px) < 1.0
    p = tmp_path / "street.png"
    cv2.imwrite(str(p), np.clip(steep, 0, 255).astype(np.uint8))
    assert main(["detect", str(p), "--json", str(tmp_path / "d.json")]) == 0
    assert "search            photo" in capsys.readouterr().out
    assert json.loads((tmp_path / "d.json").read_text())["search"] == "photo"
    cv2.imwrite(str(p), np.clip(_scene(), 0, 255).astype(np.uint8))        # no wheel at all
    assert main(["detect", str(p)]) != 0
    err = capsys.readouterr().err
    assert "The station's search:" in err and "the photograph search:" in err and "Traceback" not in err


def test_station_detect_refuses_an_oval_lying_on_its_side_found_by_the_station_search():
    from station.commands.detect_photograph import detect_photograph

    badge, _ = render_wheel(WheelSpec(axis_ratio=0.75, rim_a_px=200, center_px=(400.2, 300.6), angle_rad=0.0),
                            shape=(640, 800), seed=21)                       # a car's badge, not a wheel
    assert detect_photograph(badge, 1.0, "x", search="station").ellipse.axes_px[1] == pytest.approx(150, abs=1)
    with pytest.raises(RimNotFound, match="lies on its side"):
        detect_photograph(badge, 1.0, "x")
    upright, _ = render_wheel(WheelSpec(axis_ratio=0.75, rim_a_px=200, center_px=(400.2, 300.6),
                                        angle_rad=UPRIGHT), shape=(640, 800), seed=21)
    assert detect_photograph(upright, 1.0, "x").details["search"] == "station"


def test_station_detect_refuses_a_ragged_contour_of_the_station_search():
    """A near-frontal wheel whose edge wobbles 1.7 px rms about its ellipse (a contour pieced
    from a steel wheel's disc and flange, a tyre's bead and the lip): the station's search takes
    it, ``station detect`` does not; the same wheel with a smooth edge it takes."""
    from station.commands.detect_photograph import detect_photograph

    img, _ = render_wheel(WheelSpec(axis_ratio=0.9, rim_a_px=200, center_px=(400.2, 320.6), angle_rad=UPRIGHT),
                          shape=(640, 800), seed=21)
    vv, uu = np.mgrid[0:640, 0:800].astype(np.float32)
    du, dv = uu - 400.2, vv - 320.6
    wobble = 1 + 0.012 * np.sin(9 * np.arctan2(dv, du))     # the edge 2.4 px in and out, 9 times round
    ragged = cv2.remap(img, 400.2 + du * wobble, 320.6 + dv * wobble, cv2.INTER_LINEAR)
    assert detect_photograph(ragged, 1.0, "x", search="station").point_sigma_px > 1.0
    with pytest.raises(RimNotFound, match="not one smooth contour"):
        detect_photograph(ragged, 1.0, "x")
    assert detect_photograph(img, 1.0, "x").details["search"] == "station"


def test_station_detect_refuses_a_round_contour_of_the_station_search_that_does_not_fill_the_frame():
    """A near-round wheel-like contour 14 % of the photograph high (a round lamp beside a wheel
    in a photograph cut round the wheel): the station's search, made for a wheel filling the
    frame, takes it; ``station detect`` does not, and the photograph search refuses it as
    near-frontal. The same contour filling 28 % of a smaller photograph it takes."""
    from station.commands.detect_photograph import detect_photograph

    small, _ = render_wheel(WheelSpec(axis_ratio=0.9, rim_a_px=70, center_px=(600.3, 500.6), angle_rad=UPRIGHT),
                            shape=(1000, 1200), seed=21)
    assert detect_photograph(small, 1.0, "x", search="station").ellipse.axes_px[0] == pytest.approx(70, abs=1)
    with pytest.raises(RimNotFound, match="fills 14% of the photograph's 1000 px < 25%"):
        detect_photograph(small, 1.0, "x")
    framed = small[300:800, 350:850]
    assert detect_photograph(framed, 1.0, "x").details["search"] == "station"


def test_a_bright_lamp_in_a_grey_body_is_refused():
    img = _scene(110.0)
    lamp = Ellipse((450, 350), (110, 70), UPRIGHT)  # upright, 220 px high: only the surroundings tell
    rr = lamp.radius_ratio(np.stack(np.mgrid[0:SHAPE[0], 0:SHAPE[1]][::-1], -1).reshape(-1, 2)).reshape(SHAPE)
    img[rr < 1] = 250.0
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    with pytest.raises(RimNotFound) as ex:
        detect_in_photo(img, camera_id="lamp")
    assert "no dark tyre" in str(ex.value) or "rubber" in str(ex.value)


def test_a_lone_dark_ellipse_is_not_a_rim():
    img = _scene(170.0)
    tyre = Ellipse((450, 350), (260, 80), UPRIGHT)  # a tyre's outline with nothing bright inside
    rr = tyre.radius_ratio(np.stack(np.mgrid[0:SHAPE[0], 0:SHAPE[1]][::-1], -1).reshape(-1, 2)).reshape(SHAPE)
    img[rr < 1] = 25.0
    with pytest.raises(RimNotFound):
        detect_in_photo(cv2.GaussianBlur(img, (0, 0), 1.0), camera_id="tyre")


def test_a_too_oblique_wheel_is_refused_and_said_so():
    img, _ = _steep_wheel(axis_ratio=0.14)
    with pytest.raises(RimNotFound) as ex:
        detect_in_photo(img, camera_id="oblique")
    assert "too oblique" in str(ex.value) or "no rim-like" in str(ex.value)


def test_a_lying_ellipse_is_not_an_upright_wheel():
    assert geometry_verdict(Ellipse((0, 0), (200, 60), 0.0)).startswith("not upright")
    assert geometry_verdict(Ellipse((0, 0), (200, 60), UPRIGHT + 0.2)) is None
    assert geometry_verdict(Ellipse((0, 0), (200, 130), 0.0)).startswith("not upright")
    assert geometry_verdict(Ellipse((0, 0), (200, 180), UPRIGHT)).startswith("near-frontal")  # a round lamp too
    assert geometry_verdict(Ellipse((0, 0), (40, 20), UPRIGHT)).startswith("too small")
    assert geometry_verdict(Ellipse((0, 0), (200, 30), UPRIGHT)).startswith("too oblique")


def test_a_contour_pieced_from_several_curves_is_not_a_lip():
    """The lip edge of a synthetic wheel lies on one ellipse to tenths of a pixel; the same
    refinement with its points a pixel and a half off their ellipse (spokes' ends, the lip's
    arcs) is refused, the rest unchanged."""
    img, _ = _steep_wheel(seed=7)
    det = detect_in_photo(img, camera_id="smooth")
    assert det.point_sigma_px < 0.5
    L, s = pc.search_image(img.astype(np.float32))
    rubber = float(np.percentile(L, 35))
    assert _after_refinement(det, det.ellipse, L, s, rubber) is None
    rough = replace(det, point_sigma_px=1.5)
    assert _after_refinement(rough, det.ellipse, L, s, rubber).startswith("not one smooth contour")


def test_nesting_is_judged_on_the_larger_candidates_lip_edge():
    rim = Ellipse((400, 300), (200, 60), UPRIGHT)
    disc = Ellipse((402, 300), (150, 45), UPRIGHT)             # the disc inside the lip
    lamp = Ellipse((800, 300), (50, 48), UPRIGHT)
    assert hidden_by(disc, [(rim, rim)]) is rim                 # inside a rim: not the rim
    assert hidden_by(disc, [(rim, None)]) is rim                # inside a wheel whose lip was not found
    assert hidden_by(rim, [(Ellipse((400, 300), (240, 75), UPRIGHT), rim)]) is None  # one rim found twice
    assert hidden_by(lamp, [(rim, rim)]) is None                # elsewhere in the photo


def test_the_candidates_follow_a_bright_region_outline_at_several_levels():
    img, truth = _steep_wheel(seed=5)
    L, s = pc.search_image(img.astype(np.float32))
    assert s == 1 and L.dtype == np.float32
    cands = pc.candidates(L, 40, 400, 0.16)
    near = [c for c in cands if pc.same_ellipse(c["ellipse"], truth, 0.05)]
    assert near and near[0]["support"] >= 2 and near[0]["cover"] > 0.8


def test_profile_reads_concentric_ellipses():
    L = np.zeros((200, 200), np.float32)
    L[:, 100:] = 1.0
    P = pc.profile(L, Ellipse((100, 100), (50, 20), UPRIGHT), np.array([0.5, 1.0, 3.0]), n_angles=8)
    assert P.shape == (3, 8)
    assert np.isnan(P[2]).any() and np.isfinite(P[:2]).all()  # 3x the ellipse leaves the image


@pytest.mark.parametrize("case", ["tiny", "corrupt"])
def test_bad_input_is_a_message(tmp_path, capsys, case):
    p = tmp_path / "x.png"
    if case == "tiny":
        cv2.imwrite(str(p), np.full((20, 30), 128, np.uint8))
    else:
        p.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
    code = main(["detect", str(p), "--search", "photo"])
    err = capsys.readouterr().err
    assert code != 0 and "Traceback" not in err
    assert ("too small" in err) if case == "tiny" else ("truncated" in err or "not a readable" in err)
    with pytest.raises((ImageError, RimNotFound)):
        detect_in_photo(np.full((20, 30), 128, np.uint8))


@pytest.mark.parametrize("blur", [1.0, 6.0])
def test_the_edge_blur_is_read_along_a_candidate(blur):
    from station.rim.photo_search import BLURRED_PX, edge_blur_px

    img, truth = _steep_wheel(blur_sigma_px=blur, noise_sigma=1.0)
    found = edge_blur_px(img.astype(np.float32), truth)
    if blur > BLURRED_PX:
        assert abs(found - blur) < 0.2 * blur, found
    else:  # read at 1/3 scale, a sharp edge comes out about 2 px
        assert found < BLURRED_PX, found


def test_a_refusal_on_a_blurred_photograph_says_so():
    """A wheel blurred far beyond a sharp photograph's edges (sigma 9 px) is refused: the refusal
    names the blur as well as what its best candidate lacked."""
    img, _ = _steep_wheel(blur_sigma_px=9.0)
    with pytest.raises(RimNotFound) as ex:
        detect_in_photo(img, camera_id="soft")
    assert "the photograph is blurred there (edge blur" in str(ex.value), ex.value


def test_a_large_photograph_with_no_rim_found_is_searched_again_smaller(monkeypatch):
    """A photograph over SEARCH_SIDE_PX where the search finds nothing (a phone's 28 Mpx: the lip's
    edge spread over more pixels than the photograph search's limits allow) is searched again
    shrunk by an integer factor, its rim returned in the full photograph's pixels. Here the
    search at full size is made to fail; a station's search is never searched again, and the
    shrunk photograph is searched by the photograph search alone (the station's, run there on a
    near-frontal crop, took a tyre's outline that its roughness had refused at full size)."""
    from station.commands import detect_photograph as detect_cmd

    img, truth = _steep_wheel()
    f = 3.5  # 2450 x 3150 px: searched again at half
    big = cv2.resize(img.astype(np.float32), None, fx=f, fy=f, interpolation=cv2.INTER_CUBIC)
    real = detect_cmd._searched_once
    sizes, searches = [], []

    def failing_at_full_size(light, name, equalization, search):
        sizes.append(max(light.shape[:2]))
        searches.append(search)
        if max(light.shape[:2]) > detect_cmd.SEARCH_SIDE_PX:
            raise RimNotFound(f"{name}: nothing at full size")
        return real(light, name, equalization, search)

    monkeypatch.setattr(detect_cmd, "_searched_once", failing_at_full_size)
    det = detect_cmd.detect_photograph(big, 1.0, "big")
    assert sizes[0] == 3150 and sizes[1] == 3150 // 2
    assert searches[:2] == ["auto", "photo"]  # shrunk, only the photograph search's pixel limits are in question
    expected = Ellipse(truth.scaled(f).center_px + (f - 1) / 2, truth.axes_px * f, truth.angle_rad)  # pixel centres
    assert np.linalg.norm(det.ellipse.center_px - expected.center_px) < 2.0
    np.testing.assert_allclose(det.ellipse.axes_px, expected.axes_px, rtol=0.01)
    assert np.abs(det.ellipse.distance(det.points_px)[0]).mean() < 1.5  # the edge points in full-size pixels too
    with pytest.raises(RimNotFound, match="nothing at full size"):
        detect_cmd.detect_photograph(big, 1.0, "big", search="station")
    monkeypatch.setattr(detect_cmd, "_searched_once", lambda light, name, *a: (_ for _ in ()).throw(
        RimNotFound(f"{name}: nothing at {max(light.shape[:2])} px")))
    with pytest.raises(RimNotFound, match="nothing at 3150 px"):  # the full photograph's reason is given
        detect_cmd.detect_photograph(big, 1.0, "big")
