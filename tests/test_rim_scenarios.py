"""bench/rim_scenarios.py: every named scenario renders, the same for a seed, and shows in the
image what it says; and bench/accuracy.py measures one of them end to end.

One camera (cam1, the FR wheel's precision camera) of the half-resolution station. The lip and
the tyre are sampled round the wheel at points projected from the wheel frame and kept where
the renderer's labels say that part is what the pixel sees.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace

import numpy as np
import pytest

from bench import outside_envelope, rim_scenarios
from simulators.render import render_radiance
from simulators.render_wheel import FLANGE, RIDGE, TYRE, TYRE_TEXT, tyre_profile
from simulators.scene import Appearance
from simulators.shading import LABEL_BODY, LABEL_WHEEL
from tests.station_fixtures import small_station_config

SEED = 7000
CAM, WHEEL, WHEEL_INDEX = "cam1", "FR", 1          # WHEELS order: FL, FR, RL, RR
# sha1 of cam1's image of vehicle 3 (small station, render_all's noise from seed 3) as the renderer drew it
# before scenes had an Appearance: the default Appearance must leave every image as it was.
# A deliberate change of the renderer's default images changes it too.
SILVER_SHA1 = "57081587ffd5b8cecb2003a13a9d44842b175362"


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    from simulators.world import SimWorld

    cfg = small_station_config(tmp_path_factory.mktemp("station"))
    return cfg, SimWorld.from_config(cfg)


_views: dict = {}


def view(station, kind: str, scene=None):
    """(clean image (H,W) float32 with exposure and glare, labels (H,W), scene) of cam1."""
    cfg, world = station
    scene = scene if scene is not None else rim_scenarios.scene_for(world, kind, SEED, cfg.nominal_vehicle)
    key = (kind, id(scene) if kind is None else None)
    if key not in _views:
        cam = world.cameras[CAM]
        _, label = render_radiance(cam, scene, world.lighting_for(CAM, scene), supersample=1)
        _views[key] = (world.clean_image(CAM, scene).copy(), label, scene)
    return _views[key]


def ring(station, scene, where: str, n: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """(angles (n,) rad, pixels (n,2) int (u, v)) of cam1 round the FR wheel: the lip's outer
    part ("lip"), the tyre 12 mm beyond the lip ("tyre") or the tyre 3-25 mm beyond ("near")."""
    g = scene.vehicle.wheel
    center, R = scene.vehicle.wheel_frame_station(WHEEL)
    theta = np.linspace(-np.pi, np.pi, n, endpoint=False)
    profile, n_outer, _ = tyre_profile(g)
    if where == "lip":
        r, w = g.rim_radius_m - 0.3 * g.flange_width_m, 0.0
    else:
        r = g.rim_radius_m + 0.012
        w = float(np.interp(r, profile[:n_outer + 1, 0], profile[:n_outer + 1, 1]))
    local = np.stack([r * np.cos(theta), r * np.sin(theta), np.full(n, w)], axis=1)
    uv = station[1].cameras[CAM].project(local @ R.T + center)
    return theta, np.round(uv).astype(int)


def lip_and_tyre(station, kind, scene=None):
    """(lip grey (n,), tyre grey (n,)) at the angles where cam1 sees both (NaN elsewhere)."""
    image, label, scene = view(station, kind, scene)
    out = []
    for where, part in (("lip", FLANGE), ("tyre", TYRE)):
        _, px = ring(station, scene, where)
        vals = image[px[:, 1], px[:, 0]].astype(float)
        vals[label[px[:, 1], px[:, 0]] != LABEL_WHEEL + 40 * WHEEL_INDEX + part] = np.nan
        out.append(vals)
    return out


@pytest.mark.parametrize("kind", rim_scenarios.KINDS)
def test_every_scenario_renders_the_same_for_a_seed(station, kind):
    cfg, world = station
    a = rim_scenarios.scene_for(world, kind, SEED, cfg.nominal_vehicle)
    b = rim_scenarios.scene_for(world, kind, SEED, cfg.nominal_vehicle)
    assert a == b and a.vehicle.toe_deg == world.vehicle_scene(SEED).vehicle.toe_deg   # the seed's car
    image = view(station, kind)[0]
    world._clean.clear()
    again = world.clean_image(CAM, b)
    assert np.array_equal(image, again)
    assert image.shape == (world.cameras[CAM].height, world.cameras[CAM].width) and np.isfinite(image).all()


def without(station, kind: str, **look):
    """cam1's view of scenario ``kind``'s scene with some of its Appearance set back."""
    scene = view(station, kind)[2]
    return view(station, None, replace(scene, appearance=replace(scene.appearance, **look)))


def test_silver_is_the_random_vehicle_rendered_as_before(station):
    cfg, world = station
    silver = rim_scenarios.scene_for(world, "silver", SEED, cfg.nominal_vehicle)
    assert silver == outside_envelope.scene_for(world, None, SEED, cfg.nominal_vehicle)
    assert silver.appearance == Appearance() and rim_scenarios.images_of("silver") == "sigma2"
    scene = world.vehicle_scene(3)
    image = world.render(CAM, np.random.default_rng(3).spawn(len(world.cameras))[0], scene)   # as render_all
    assert hashlib.sha1(image.tobytes()).hexdigest() == SILVER_SHA1


def test_finishes_order_the_lip_from_matt_black_to_polished(station):
    med = {k: np.nanmedian(lip_and_tyre(station, k)[0]) for k in ("matt-black", "gunmetal", "silver", "polished")}
    assert med["matt-black"] < med["gunmetal"] < med["silver"] < med["polished"]


def test_gloss_black_lip_is_darker_than_the_tyre_on_one_arc_and_brighter_on_another(station):
    lip, tyre = lip_and_tyre(station, "gloss-black")
    ok = ~np.isnan(lip) & ~np.isnan(tyre)
    assert ok.mean() > 0.8
    darker, brighter = np.mean(lip[ok] < tyre[ok] - 3), np.mean(lip[ok] > tyre[ok] + 3)
    assert darker > 0.3 and brighter > 0.05, (darker, brighter)
    matt = lip_and_tyre(station, "matt-black")[0]
    assert np.nanmax(lip) > 2 * np.nanmax(matt)          # the clear coat mirrors the lights


def test_chrome_lip_shows_the_workshop_in_bands(station):
    lip = lip_and_tyre(station, "chrome")[0]
    plain = lip_and_tyre(station, None, without(station, "chrome", rim_mirror=0.0)[2])[0]
    mirrored = (lip - plain)[~np.isnan(lip)]
    assert mirrored.min() < 20 and mirrored.max() > 100, (mirrored.min(), mirrored.max())
    # several bands: the mirrored light crosses its middle level many times round the wheel
    crossings = np.count_nonzero(np.diff(np.sign(mirrored - 0.5 * (mirrored.min() + mirrored.max()))))
    assert crossings >= 4


def test_diffuse_panels_take_the_lamps_bands_off_a_glossy_lip(station):
    """Under the panels the polished lip mirrors a smooth surround (and the cameras' slot):
    its mirrored light is much more even round the wheel than the bands the workshop's lamps
    and floor make of it."""
    _, _, panels = view(station, "polished-diffuse")
    _, _, workshop = view(station, "polished")
    assert panels.vehicle == workshop.vehicle and 0.3 <= panels.appearance.surround <= 0.6
    assert replace(panels.appearance, surround=0.0) == workshop.appearance   # only what it mirrors differs
    plain = lip_and_tyre(station, None, without(station, "polished", rim_mirror=0.0)[2])[0]
    spread = {}
    for kind in ("polished", "polished-diffuse"):
        lip = lip_and_tyre(station, kind)[0]
        mirrored = (lip - plain)[~np.isnan(lip) & ~np.isnan(plain)]
        assert mirrored.min() > 0                                 # the metal mirrors something everywhere
        spread[kind] = np.percentile(mirrored, 95) - np.percentile(mirrored, 5)
    assert spread["polished-diffuse"] < 0.4 * spread["polished"], spread


def test_brake_dust_darkens_the_lip_over_its_span_only(station):
    _, _, scene = view(station, "brake-dust")
    look = scene.appearance
    lip = lip_and_tyre(station, "brake-dust")[0]
    clean = lip_and_tyre(station, None, without(station, "brake-dust", dust=0.0)[2])[0]
    theta, _ = ring(station, scene, "lip")
    off = np.abs(np.mod(theta - look.dust_center_rad + np.pi, 2 * np.pi) - np.pi)
    middle, outside = off < 0.15 * look.dust_span_rad, off > 0.55 * look.dust_span_rad
    ratio = lip / clean
    assert np.nanmax(ratio[middle]) < 0.85 and np.allclose(ratio[outside & ~np.isnan(ratio)], 1.0, atol=1e-3)


def test_dirt_darkens_blotches_of_the_lip(station):
    ratio = lip_and_tyre(station, "dirt")[0] / lip_and_tyre(station, None, without(station, "dirt", dirt=0.0)[2])[0]
    ratio = ratio[~np.isnan(ratio)]
    assert 0.1 < np.mean(ratio < 0.8) < 0.7 and np.mean(np.abs(ratio - 1) < 1e-3) > 0.2


def _near_lip(station, kind, part):
    """(image, mask of the FR wheel's pixels labelled ``part`` within 3-25 mm beyond the lip)."""
    image, label, scene = view(station, kind)
    g = scene.vehicle.wheel
    center, R = scene.vehicle.wheel_frame_station(WHEEL)
    cam = station[1].cameras[CAM]
    uv_c = cam.project(center[None])[0]
    v, u = np.mgrid[:image.shape[0], :image.shape[1]]
    rad = np.hypot(u - uv_c[0], v - uv_c[1])
    scale = np.median(np.hypot(*(ring(station, scene, "lip")[1] - uv_c).T)) / (g.rim_radius_m - 0.3 * g.flange_width_m)
    band = (rad > (g.rim_radius_m + 0.003) * scale) & (rad < (g.rim_radius_m + 0.025) * scale)
    return image, band & (label == LABEL_WHEEL + 40 * WHEEL_INDEX + part)


def test_tyre_lettering_is_bright_and_close_to_the_lip(station):
    image, letters = _near_lip(station, "tyre-lettering", TYRE_TEXT)
    _, rubber = _near_lip(station, "tyre-lettering", TYRE)
    assert letters.sum() > 50 and np.median(image[letters]) > np.median(image[rubber]) + 25
    assert _near_lip(station, "silver", TYRE_TEXT)[1].sum() == 0     # the tyre's own letters sit further out


def test_protector_ridge_stands_beyond_the_lip_with_edges_of_its_own(station):
    image, rib = _near_lip(station, "protector-ridge", RIDGE)
    plain, _ = _near_lip(station, "silver", TYRE)
    assert rib.sum() > 200
    assert np.percentile(np.abs(image - plain)[rib], 90) > 5      # its faces shade differently from the sidewall


def test_low_contrast_lip_is_close_to_the_tyre(station):
    lip, tyre = lip_and_tyre(station, "low-contrast")
    s_lip, s_tyre = lip_and_tyre(station, "silver")
    assert np.nanmedian(np.abs(lip - tyre)) < 0.4 * np.nanmedian(np.abs(s_lip - s_tyre))


def test_arch_shadow_darkens_the_rim_above_its_line(station):
    _, _, scene = view(station, "arch-shadow")
    lip = lip_and_tyre(station, "arch-shadow")[0]
    lit = lip_and_tyre(station, None, without(station, "arch-shadow", shadow_height=None)[2])[0]
    ratio = lip / lit
    assert np.nanmin(ratio) < 0.35 and np.nanmax(ratio) > 0.999   # in the shadow the ambient light alone
    # the shadow is above: the rim's top in it, its bottom not
    theta, px = ring(station, scene, "lip")
    top, bottom = px[:, 1] < np.percentile(px[:, 1], 15), px[:, 1] > np.percentile(px[:, 1], 85)
    assert np.nanmean(ratio[top]) < 0.5 < np.nanmean(ratio[bottom])


def test_the_sun_drives_the_lit_lip_to_white_at_fixed_exposure_and_auto_exposure_meters(station):
    cfg, world = station
    fixed = view(station, "sun-fixed-exposure")
    lip = lip_and_tyre(station, "sun-fixed-exposure")[0]
    assert np.mean(lip >= 255) > 0.02 and np.nanmedian(lip) < 100
    image = world.render(CAM, np.random.default_rng(1), fixed[2])
    _, px = ring(station, fixed[2], "lip")
    assert (image[px[:, 1], px[:, 0]] == 255).sum() >= 3
    auto_image, _, auto = view(station, "sun-auto-exposure")
    assert auto.lighting[CAM].key_direction_station == fixed[2].lighting[CAM].key_direction_station  # one sun
    assert np.percentile(auto_image, 99.5) == pytest.approx(auto.appearance.auto_exposure, rel=1e-3)
    # veiling glare lifts the darks: the image without it is darker where nothing is lit
    no_glare = without(station, "sun-fixed-exposure", veiling_glare=0.0)[0]
    assert np.percentile(fixed[0] - no_glare, 50) > 1.0


def test_shop_reflections_brighten_the_paint_in_bands(station):
    image, label, _ = view(station, "shop-reflections")
    plain, _, _ = view(station, "silver")
    panel = label == LABEL_BODY
    lift = (image - plain)[panel]
    assert panel.sum() > 1000 and lift.min() >= 0 and np.percentile(lift, 95) > 15 > np.percentile(lift, 5)


def test_the_accuracy_bench_measures_a_scenario_end_to_end(station, capsys):
    from bench import accuracy

    cfg, world = station
    assert set(rim_scenarios.KINDS) <= set(accuracy.SCENARIOS)
    rows = accuracy.run(cfg, {"truth": world.cameras}, 1, "brake-dust", SEED, ["circle"])
    r = rows[("truth", "circle")]
    assert r["failed"] + len(r["err"]) == 1
    assert r["judged"] == 4 * len(r["err"]) and len(r["silent"]) <= r["judged"]  # wheels of valid cycles only
    if r["err"]:
        assert max(abs(r["err"][0][f"{w}.{a}"]) for w in ("FL", "FR", "RL", "RR") for a in ("toe", "camber")) < 0.5
    accuracy.print_table("brake-dust", rows, 1)
    out = capsys.readouterr().out
    assert "refused, truth/circle: " in out and "silent wrong (> 3 stated, no warning): " in out


def test_refused_and_silently_wrong_wheels_are_told_apart():
    from bench.accuracy import _refused_and_silent
    from station.result import Failure, Measurement, WarningFlag, WheelResult

    truth = {"wheels": {w: {"toe_deg": 0.0, "camber_deg": 0.0, "rim_toe_deg": 0.1, "rim_camber_deg": 0.0}
                        for w in ("FL", "FR", "RL", "RR")}}
    res = Measurement("s", valid=False, failure=Failure(404, "wheel uncertain", wheel="FL,RR"))
    for w, toe in (("FL", 0.5), ("FR", 0.1), ("RL", 0.2), ("RR", 0.1)):
        res.wheels[w] = WheelResult(toe_deg=toe, camber_deg=0.0, toe_std_deg=0.01, camber_std_deg=0.01)
    refused, silent, judged, withheld = _refused_and_silent(res, truth)
    # the refused cycle reports no angle: RL (0.1 off, 10 stated) is withheld with it, not silent
    assert set(refused) == {"FL", "RR"} and silent == [] and judged == 0 and withheld == ["RL"]
    res.valid, res.failure = True, None                                          # the same wheels reported
    assert _refused_and_silent(res, truth) == ({}, ["FL", "RL"], 4, [])
    res.warning_flags.append(WarningFlag("uncertain", "RL"))
    assert _refused_and_silent(res, truth)[1] == ["FL"]
    other = Measurement("s", valid=False, failure=Failure(401, "cam1: no closed rim contour"))
    refused, silent, judged, withheld = _refused_and_silent(other, truth)
    assert refused == {w: "401 RimNotFound, cycle" for w in ("FL", "FR", "RL", "RR")} and judged == 0


def test_a_black_rims_refusal_says_the_station_cannot_find_a_rim_no_brighter_than_its_tyre(station):
    from station.measure import measure_frames
    from station.rim.choice import DARK_RIM_NOTE

    cfg, world = station
    world.set_scene(rim_scenarios.scene_for(world, "matt-black", SEED, cfg.nominal_vehicle))
    result = measure_frames(world.render_all(np.random.default_rng(SEED)), world.cameras, cfg)
    assert not result.valid and result.failure.code in (400, 401)  # a wrong contour taken, or none
    assert result.failure.hint.endswith(DARK_RIM_NOTE)
