"""A whole measurement on simulated images: angles near the truth, failures named, CLI output.
The pairs' checks and the rims of an axle are in test_measure_pairs.py."""

import io
import json
import subprocess
import sys

import numpy as np
import pytest

from station.measure import measure_frames
from station.result import Measurement, WarningFlag
from tests.station_fixtures import rendered_small_station, small_station_config


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    return rendered_small_station(tmp_path_factory.mktemp("station"), seed=3)


@pytest.mark.slow
def test_angles_match_the_simulated_vehicle(sim):
    cfg, world, scene, images = sim
    result = measure_frames(images, world.cameras, cfg)
    assert result.valid, result.failure
    result.add_truth(world.truth(scene))
    for w in ("FL", "FR", "RL", "RR"):
        # Half resolution and a single vehicle: a loose bound that a sign or frame error breaks.
        assert abs(result.errors[w]["toe_error_deg"]) < 0.4
        assert abs(result.errors[w]["camber_error_deg"]) < 0.4
        assert result.wheels[w].toe_std_deg > 0
    truth_toe = np.array([scene.vehicle.toe_deg[w] for w in ("FL", "FR", "RL", "RR")])
    measured = np.array([result.wheels[w].toe_deg for w in ("FL", "FR", "RL", "RR")])
    assert np.corrcoef(truth_toe, measured)[0, 1] > 0.95
    json.dumps(result.to_json())  # JSON-ready


@pytest.mark.slow
def test_a_black_camera_invalidates_the_cycle_and_is_named(sim):
    cfg, world, scene, images = sim
    broken = dict(images, cam5=np.zeros_like(images["cam5"]))
    result = measure_frames(broken, world.cameras, cfg)
    assert not result.valid
    assert result.failure.camera == "cam5" and result.failure.wheel == "RL"
    assert "cam5" in result.failure.message
    assert not result.wheels, "no angle of an invalid cycle is reported"
    from station.commands.measure import print_result  # the technician reads what to do, not only what failed
    out = io.StringIO()
    print_result(result, out)
    assert "MEASUREMENT FAILED" in out.getvalue() and f"what to do: {result.failure.hint}" in out.getvalue()
    assert result.failure.hint


def test_unknown_method_is_refused(sim):
    from station.errors import MeasurementError

    cfg, world, _, images = sim
    with pytest.raises(MeasurementError, match="unknown method"):
        measure_frames(images, world.cameras, cfg, method="magic")


def test_measure_without_calibration_names_the_file_and_what_to_do(tmp_path):
    cfg = small_station_config(tmp_path)
    out = subprocess.run([sys.executable, "-m", "station.cli", "--config", str(cfg.path), "measure", "--seed", "1"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert "calibration file not found" in out.stderr and "station calibrate" in out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.slow
def test_a_knocked_camera_is_reported_as_calibration_drift(sim):
    from calibration.camera_model import rodrigues_to_matrix

    cfg, world, scene, images = sim
    cams = dict(world.cameras)
    c = cams["cam2"]
    # The reference camera of FR was knocked (tilted 0.15 deg about its own centre) after calibration.
    R = rodrigues_to_matrix([np.radians(0.15), 0, 0]) @ c.R_cam_station
    cams["cam2"] = c.with_pose(R, -R @ c.center_station)
    result = measure_frames(images, cams, cfg)
    drift = [w for w in result.warnings if "may have moved" in w]
    assert any("pair FR (cam1, cam2)" in w for w in drift), result.warnings
    assert WarningFlag("drift", "FR") in result.warning_flags
    assert not any("pair RL" in w for w in result.warnings)


@pytest.mark.slow
def test_a_rim_seen_on_part_of_its_perimeter_is_measured_and_its_unchecked_pair_named(sim, monkeypatch):
    """One 3-D circle fits both views, but the epipolar tangents of a rim seen on part of its
    perimeter, not where the epipolar planes touch it, are extrapolated (9 px): the wheel is
    measured, with a warning that this cycle could not check the pair's calibration. Were the
    circle not to fit one view, it is refused. Where both cameras saw the tangent points,
    nothing is extrapolated: the same residual is a camera moved since calibration (drift)."""
    from dataclasses import replace

    import station.wheel.pair as wheel_pair
    from station.errors import MeasurementError

    cfg, world, scene, images = sim
    fit = wheel_pair.refine_circle
    detect = wheel_pair.detect_one
    missed = {"tangent_gap_deg": (0.3, 40.0)}  # cam6 saw no rim within 40 deg of a tangent point
    residual = {"epipolar_rms_px": 9.0}

    def extrapolated(pl, pr, cl, cr, init, **kw):
        c = fit(pl, pr, cl, cr, init, **kw)
        return replace(c, **residual, **missed) if cl.name == "cam5" else c

    def partly_seen(image, camera, cam_id):
        d = detect(image, camera, cam_id)
        return replace(d, coverage=0.6) if cam_id == "cam6" else d

    monkeypatch.setattr(wheel_pair, "refine_circle", extrapolated)
    monkeypatch.setattr(wheel_pair, "detect_one", partly_seen)
    result = measure_frames(images, world.cameras, cfg)
    assert result.valid, result.failure
    note = [w for w in result.warnings if w.startswith("pair RL")]
    assert len(note) == 1 and "too little to check the pair's calibration" in note[0], result.warnings
    assert WarningFlag("unchecked", "RL") in result.warning_flags
    assert not any("may have moved" in w for w in result.warnings)
    missed.clear()  # both saw the tangent points: however much of the rim cam6 sees, the residual is a moved camera
    seen_part = measure_frames(images, world.cameras, cfg)
    assert not seen_part.valid and "did not find the same rim" in seen_part.failure.message
    monkeypatch.setattr(wheel_pair, "detect_one", detect)
    seen = measure_frames(images, world.cameras, cfg)
    assert not seen.valid and "a camera may have moved" in seen.failure.hint
    residual["epipolar_rms_px"] = 3.0  # under the mismatch limit: measured, and the drift named
    drift = measure_frames(images, world.cameras, cfg)
    assert drift.valid and WarningFlag("drift", "RL") in drift.warning_flags, drift.warnings
    assert any(w.startswith("pair RL") and "whole cycle as suspect" in w for w in drift.warnings)
    o = result.observations["RL"]
    wrong = replace(o, circle=replace(o.circle, view_median_px=(o.circle.view_median_px[0], 3.0)))
    with pytest.raises(MeasurementError, match="did not find the same rim"):
        wheel_pair.check_same_rim(wrong, cfg)


@pytest.mark.slow
def test_a_pair_that_did_not_see_the_rim_where_the_epipolar_planes_touch_it_is_unchecked(sim, monkeypatch):
    """The epipolar check compares the tangents where the epipolar planes touch the rim; where a
    camera saw no edge near those points (a dark lip, the arch, arcs on another contour left
    out) the tangents are extrapolated: a residual over the limit there is no evidence that a
    camera moved. Seen there, the same residual is drift."""
    from dataclasses import replace

    import station.wheel.pair as wheel_pair

    cfg, world, scene, images = sim
    fit = wheel_pair.refine_circle
    gap = {"cam6": 40.0}

    def partial(pl, pr, cl, cr, init, **kw):
        c = fit(pl, pr, cl, cr, init, **kw)
        if cl.name != "cam5":
            return c
        assert max(c.tangent_gap_deg) < 15, "the simulated rim is seen all round"
        return replace(c, epipolar_rms_px=2.0, tangent_gap_deg=(c.tangent_gap_deg[0], gap["cam6"]))

    monkeypatch.setattr(wheel_pair, "refine_circle", partial)
    result = measure_frames(images, world.cameras, cfg)
    assert result.valid, result.failure
    assert WarningFlag("unchecked", "RL") in result.warning_flags
    assert WarningFlag("drift", "RL") not in result.warning_flags
    note = [w for w in result.warnings if w.startswith("pair RL")]
    assert len(note) == 1 and "cam6 did not see the rim where the epipolar planes touch it" in note[0]
    assert "40 deg" in note[0] and "too little to check" in note[0]
    gap["cam6"] = 5.0
    seen = measure_frames(images, world.cameras, cfg)
    assert WarningFlag("drift", "RL") in seen.warning_flags
    assert seen.wheels["RL"].quality.arcs_left_out is False
    assert all(isinstance(seen.wheels[w].quality.grazing_left_out, bool) for w in seen.wheels)


@pytest.mark.slow
def test_a_refused_wheels_reason_is_the_largest_part_of_its_statement(sim, monkeypatch):
    """``statement_parts`` splits a wheel's stated toe and camber into the views' disagreement,
    the calibration, the edges' noise and their slow unevenness; in quadrature they make up the
    statement (the centres' share aside), and the reason names the largest part. A wheel is
    refused by its views' bound, not by the share of their disagreement it states."""
    import dataclasses

    from station.stated_uncertainty import _why_uncertain, statement_parts

    cfg, world, scene, images = sim
    result = measure_frames(images, world.cameras, cfg)
    for w, o in result.observations.items():
        for angle in ("toe", "camber"):
            parts = statement_parts(o, angle, cfg)
            assert set(parts) == {"views", "calibration", "noise", "edge"} and min(parts.values()) >= 0
            stated = getattr(result.wheels[w], f"{angle}_std_deg")
            assert np.sqrt(sum(parts.values())) == pytest.approx(stated, rel=0.05), (w, angle, parts)
    o = result.observations["FR"]
    circle = o.circle
    big = dataclasses.replace(circle, calibration_share=(0.0, 2 * np.radians(0.5) ** 2),
                              cov_axis=circle.cov_axis + np.radians(0.5) ** 2 * np.eye(3))
    why, hint, reason = _why_uncertain(dataclasses.replace(o, circle=big), "camber", 0.5, cfg)
    assert "calibration" in why and "station calibrate" in hint and reason == "calibration"
    wavy = [np.zeros((3, 3)), np.radians(0.3) ** 2 * np.eye(3)]  # the reference camera's edge wavers
    big = dataclasses.replace(circle, cov_axis=circle.cov_axis + wavy[1], cov_axis_bias_views=tuple(wavy))
    why, _, reason = _why_uncertain(dataclasses.replace(o, circle=big), "toe", 0.3, cfg)
    assert f"wavers round the rim beyond its noise, most in {o.cams[1]}" in why and "+/-0.3" in why
    assert reason == "uneven_edge"
    alike = dataclasses.replace(big, cov_axis_bias_views=(0.8 * wavy[1], wavy[1]))
    why, _, _ = _why_uncertain(dataclasses.replace(o, circle=alike), "toe", 0.3, cfg)
    assert f"in {o.cams[0]} and {o.cams[1]} alike" in why
    broken = dataclasses.replace(circle, cov_axis=np.full((3, 3), np.inf), cov_axis_noise=None,
                                 cov_axis_bias_views=None, calibration_share=None)
    why, hint, reason = _why_uncertain(dataclasses.replace(o, circle=broken, views=None), "toe", float("inf"), cfg)
    assert reason in ("uneven_edge", "faint_edge") and why and hint  # a fit stating nothing finite: a reason too
    across = np.cross(circle.axis_station, [0, 0, 1])
    apart = dataclasses.replace(o.views, disagreement_station=np.radians(1.0) * across / np.linalg.norm(across))
    why, _, reason = _why_uncertain(dataclasses.replace(o, views=apart), "toe", 0.5, cfg)
    assert "each see the rim's axis differently, by 1.00 deg" in why
    assert reason in ("white_lip", "dark_lip", "faint_view")
    # views 1 deg apart, a limit between the wheel's toe with the share the pair follows and
    # with the bound (half of it, all in toe): the wheel is refused by the bound
    from station.stated_uncertainty import refuse_uncertain_wheels

    doubted = dataclasses.replace(o, views=apart)
    stated, bound = (statement_parts(doubted, "toe", cfg, bound=b)["views"] for b in (False, True))
    assert 0 < stated < 0.8 * bound
    toe2 = result.wheels["FR"].toe_std_deg ** 2
    monkeypatch.setattr(cfg.measurement, "uncertainty_limit_deg", float(np.sqrt(toe2 + (stated + bound) / 2)))
    failure = refuse_uncertain_wheels(result, {**result.observations, "FR": doubted}, cfg)
    assert failure is not None and failure.code == 404 and failure.wheel == "FR"
    assert refuse_uncertain_wheels(result, result.observations, cfg) is None


@pytest.mark.slow
def test_a_wheel_less_certain_than_the_limit_is_refused_with_why_and_what_to_do(sim, monkeypatch):
    cfg, world, scene, images = sim
    result = measure_frames(images, world.cameras, cfg)
    assert result.valid and not any(f.kind == "uncertain" for f in result.warning_flags)
    monkeypatch.setattr(cfg.measurement, "uncertainty_limit_deg", 0.001)  # every wheel is less certain
    refused = measure_frames(images, world.cameras, cfg)
    assert not refused.valid and refused.failure.code == 404
    assert refused.failure.wheel == "FL,FR,RL,RR"
    flags = sorted(f.wheel for f in refused.warning_flags if f.kind == "uncertain")
    assert flags == ["FL", "FR", "RL", "RR"]                     # the PLC's warning_bits 0-3
    message = refused.failure.message
    assert "0.001 deg uncertainty limit" in message and "no angle of this cycle is reported" in message
    from station.stated_uncertainty import UNCERTAIN_REASONS

    reasons = ("see the rim's axis differently", "wavers round the rim", "faint or noisy", "calibration")
    for f in refused.warning_flags:  # why: the largest part of the statement, naming a camera of the pair
        if f.kind == "uncertain":
            pair = cfg.pairs[f.wheel]
            assert f.text.startswith(f"{f.wheel}: ") and f.text[4:] in message
            assert sum(r in f.text for r in reasons) == 1 and f.reason in UNCERTAIN_REASONS
            assert f.to_json()["reason"] == f.reason
            assert pair.precision in f.text or pair.reference in f.text
    assert "measure again" in refused.failure.hint
    doc = refused.to_json()  # the refused angles stay on the object (recording, benchmarks), not in the JSON
    assert doc["valid"] is False and doc["wheels"] == {} and doc["thrust_deg"] is None
    assert set(refused.wheels) == {"FL", "FR", "RL", "RR"}


def test_result_json_to_an_unwritable_place_is_a_storage_error_and_leaves_no_file(tmp_path):
    from station.cycle import write_json
    from station.errors import StorageError

    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x")
    with pytest.raises(StorageError, match="cannot write the result JSON"):
        write_json(Measurement(station="s"), blocker / "r.json")
    out = write_json(Measurement(station="s", valid=True, thrust_deg=np.float64(0.5)), tmp_path / "ok" / "r.json")
    assert json.loads(out.read_text())["thrust_deg"] == 0.5
    assert [p.name for p in out.parent.iterdir()] == ["r.json"]


@pytest.mark.slow
def test_the_calibrations_covariance_adds_to_the_stated_uncertainty(sim):
    cfg, world, _, images = sim
    sd = np.array([0.1, 0.1, 0.2, 0.2, 1e-4, 3e-4, 1e-5, 1e-5, 5e-4, 3e-5, 3e-5, 3e-5, 1e-4, 1e-4, 1e-4])
    cov = np.diag(np.tile(sd, 2) ** 2)
    plain = measure_frames(images, world.cameras, cfg)
    with_cal = measure_frames(images, world.cameras, cfg, calibration_cov={"FR": cov})
    assert plain.valid and with_cal.valid
    fr0, fr1 = plain.wheels["FR"], with_cal.wheels["FR"]
    assert fr1.toe_deg == fr0.toe_deg  # the values do not move, their uncertainty grows
    assert fr0.toe_std_deg < fr1.toe_std_deg < 10 * fr0.toe_std_deg
    # the car frame is built from all four centres, so the other wheels' angles move a little
    rl0, rl1 = plain.wheels["RL"].toe_std_deg, with_cal.wheels["RL"].toe_std_deg
    assert rl1 / rl0 < fr1.toe_std_deg / fr0.toe_std_deg


@pytest.mark.slow
def test_the_uncertainty_floor_adds_in_quadrature_and_moves_no_value(sim, monkeypatch):
    cfg, world, _, images = sim
    floor = 0.012
    monkeypatch.setattr(cfg.measurement, "uncertainty_light_gain", 0.0)
    monkeypatch.setattr(cfg.measurement, "uncertainty_toe_scale", 1.0)
    monkeypatch.setattr(cfg.measurement, "uncertainty_floor_deg", floor)
    with_floor = measure_frames(images, world.cameras, cfg)
    monkeypatch.setattr(cfg.measurement, "uncertainty_floor_deg", 0.0)
    without = measure_frames(images, world.cameras, cfg)
    for w in ("FL", "FR", "RL", "RR"):
        a, b = with_floor.wheels[w], without.wheels[w]
        assert a.toe_deg == b.toe_deg and a.camber_deg == b.camber_deg
        for k in ("toe_std_deg", "camber_std_deg"):
            assert getattr(a, k) == pytest.approx(np.hypot(getattr(b, k), floor), rel=0.05)  # the axis' two directions
    # two wheels' floors in a total toe
    assert with_floor.axles["front"].total_toe_std_deg ** 2 == pytest.approx(
        without.axles["front"].total_toe_std_deg ** 2 + 2 * floor ** 2, rel=0.1)


def test_a_doubtful_rim_puts_the_other_wheels_toe_in_doubt():
    """Every toe is measured against the centreline through all four rim centres: a wheel whose
    rim is in doubt (uncertain, another size than its partner's) warns the three others; a
    drift warning already covers the cycle; runner-up and camera warnings do not count."""
    from station.measure import centreline_warnings

    def result(*flags):
        return Measurement(station="test", warning_flags=list(flags))

    r = result(WarningFlag("uncertain", "FL"), WarningFlag("rim_size", "FL"))
    centreline_warnings(r)
    assert [f.wheel for f in r.warning_flags if f.kind == "centreline"] == ["FR", "RL", "RR"]
    assert len(r.warnings) == 1 and r.warnings[0].startswith("FR, RL, RR: toe") and "FL's" in r.warnings[0]
    r = result(WarningFlag("rim_size", "RL"), WarningFlag("uncertain", "RR"))
    centreline_warnings(r)
    assert [f.wheel for f in r.warning_flags if f.kind == "centreline"] == ["FL", "FR"]
    for quiet in (result(), result(WarningFlag("runner_up", "FL"), WarningFlag("focus", "FL", camera="cam3")),
                  result(WarningFlag("uncertain", "FL"), WarningFlag("drift", "FR"))):
        before = list(quiet.warning_flags)
        centreline_warnings(quiet)
        assert quiet.warning_flags == before and quiet.warnings == []


def test_the_unseen_variance_takes_its_toe_share_across_the_horizontal():
    """``unseen_axis_shape``: nothing along the axis, 1 along the direction that tilts it up or
    down (camber), the toe scale squared along the horizontal (toe), for any axis."""
    from station.stated_uncertainty import unseen_axis_shape

    np.testing.assert_allclose(unseen_axis_shape(np.array([1.0, 0.0, 0.0]), 0.6), np.diag([0.0, 0.36, 1.0]), atol=1e-12)
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.normal(size=3) * [1, 0.05, 0.05] + [np.sign(rng.normal()), 0, 0]
        a /= np.linalg.norm(a)
        S = unseen_axis_shape(a, 0.6)
        np.testing.assert_allclose(S @ a, 0.0, atol=1e-12)
        horizontal = np.cross([0.0, 0.0, 1.0], a)
        horizontal /= np.linalg.norm(horizontal)
        assert horizontal @ S @ horizontal == pytest.approx(0.36)
        assert np.trace(S) == pytest.approx(1.36)
        np.testing.assert_allclose(unseen_axis_shape(a, 1.0), np.eye(3) - np.outer(a, a), atol=1e-12)
    np.testing.assert_allclose(unseen_axis_shape(np.array([0.0, 0.0, 2.0]), 0.6), np.diag([1.0, 1.0, 0.0]))


@pytest.mark.slow
def test_the_toe_scale_shrinks_only_toes_unseen_share(sim, monkeypatch):
    """With a floor F and ``uncertainty_toe_scale`` s, toe states (s F) in quadrature and
    camber F; no value moves."""
    cfg, world, _, images = sim
    floor, scale = 0.012, 0.5
    monkeypatch.setattr(cfg.measurement, "uncertainty_light_gain", 0.0)
    monkeypatch.setattr(cfg.measurement, "uncertainty_floor_deg", 0.0)
    plain = measure_frames(images, world.cameras, cfg)
    monkeypatch.setattr(cfg.measurement, "uncertainty_floor_deg", floor)
    monkeypatch.setattr(cfg.measurement, "uncertainty_toe_scale", scale)
    scaled = measure_frames(images, world.cameras, cfg)
    for w in ("FL", "FR", "RL", "RR"):
        a, b = scaled.wheels[w], plain.wheels[w]
        assert a.toe_deg == b.toe_deg and a.camber_deg == b.camber_deg
        assert a.toe_std_deg == pytest.approx(np.hypot(b.toe_std_deg, scale * floor), rel=0.05)
        assert a.camber_std_deg == pytest.approx(np.hypot(b.camber_std_deg, floor), rel=0.05)


@pytest.mark.slow
def test_the_unseen_error_grows_with_how_unevenly_each_lip_is_lit(sim, monkeypatch):
    """``uncertainty_light_gain`` l adds (l m q / a) rad in quadrature, m the mean of the wheel's
    two views' step modulation round the rim, q its circle's reprojection RMS and a its rim's
    semi-axis (px): a lip lit from one side states more, the more so the noisier its edges, and
    no value moves (station.stated_uncertainty.unseen_axis_variance)."""
    from station.stated_uncertainty import mean_step_modulation, unseen_axis_variance

    cfg, world, _, images = sim
    monkeypatch.setattr(cfg.measurement, "uncertainty_floor_deg", 0.0)
    monkeypatch.setattr(cfg.measurement, "uncertainty_toe_scale", 1.0)
    monkeypatch.setattr(cfg.measurement, "view_edge_bias_px", 100.0)  # the views' disagreement aside
    monkeypatch.setattr(cfg.measurement, "uncertainty_light_gain", 0.0)
    plain = measure_frames(images, world.cameras, cfg)
    monkeypatch.setattr(cfg.measurement, "uncertainty_light_gain", 0.6)
    gained = measure_frames(images, world.cameras, cfg)
    for w in ("FL", "FR", "RL", "RR"):
        o = gained.observations[w]
        m = mean_step_modulation(o)
        assert m > 0.1  # the simulator's lamps light each lip from one side
        a = np.mean([np.sqrt(np.prod(d.ellipse.axes_px)) for d in o.detections])
        term = np.degrees(0.6 * m * o.circle.reprojection_rms_px / a)
        assert unseen_axis_variance(o, cfg) == pytest.approx(np.radians(term) ** 2)
        g, p = gained.wheels[w], plain.wheels[w]
        assert g.toe_deg == p.toe_deg and g.camber_deg == p.camber_deg
        for k in ("toe_std_deg", "camber_std_deg"):
            assert getattr(g, k) == pytest.approx(np.hypot(getattr(p, k), term), rel=0.05)


def test_a_camera_out_of_focus_warns_and_is_named(sim):
    import cv2

    cfg, world, scene, images = sim
    sharp = measure_frames(images, world.cameras, cfg)
    assert not any("blurred" in w for w in sharp.warnings), sharp.warnings
    soft = dict(images, cam5=cv2.GaussianBlur(images["cam5"], (0, 0), 1.8))
    result = measure_frames(soft, world.cameras, cfg)
    assert result.valid, result.failure
    blurred = [w for w in result.warnings if "blurred" in w]
    assert len(blurred) == 1 and blurred[0].startswith("RL cam5: ") and "refocus cam5" in blurred[0], blurred
    result.add_truth(world.truth(scene))
    assert abs(result.errors["RL"]["toe_error_deg"]) < 0.4  # still measured


def test_a_camera_whose_rim_reaches_the_white_warns_and_is_named(sim):
    cfg, world, scene, images = sim
    plain = measure_frames(images, world.cameras, cfg)
    assert not any("sensor's white" in w for w in plain.warnings), plain.warnings
    assert plain.detections["cam6"].white_share < cfg.measurement.white_edge_limit
    bright = dict(images, cam6=np.clip(images["cam6"].astype(np.float64) * 2.5, 0, 255).astype(np.uint8))
    result = measure_frames(bright, world.cameras, cfg)
    white = [w for w in result.warnings if "sensor's white" in w]
    assert len(white) == 1 and white[0].startswith("RL cam6: ") and "shorten cam6's exposure" in white[0], white
    assert result.detections["cam6"].white_share > 0.5


@pytest.mark.slow
def test_a_circle_fit_that_ran_off_its_points_starts_again_from_the_image_ellipses(sim, monkeypatch):
    import dataclasses

    import station.wheel.pair as wheel_pair
    from station.rim import detect_rim

    cfg, world, scene, images = sim
    dets = {c: detect_rim(images[c], camera=world.cameras[c], camera_id=c) for c in ("cam1", "cam2")}
    good = wheel_pair.reconstruct_wheel("FR", ("cam1", "cam2"), dets, world.cameras).circle
    real, starts = wheel_pair.refine_circle, []

    def first_runs_off(*args, **kwargs):
        starts.append(args[4])
        fit = real(*args, **kwargs)
        if len(starts) == 1:  # as from a paper centroid 0.16 m off (a rim seen on two thirds of it)
            fit = dataclasses.replace(fit, center_station=fit.center_station + [0, 0, -3.0], radius_m=4.2,
                                      view_median_px=(13.5, 10.9))
        return fit

    monkeypatch.setattr(wheel_pair, "refine_circle", first_runs_off)
    obs = wheel_pair.reconstruct_wheel("FR", ("cam1", "cam2"), dets, world.cameras)
    assert len(starts) == 2 and starts[1].radius_m == pytest.approx(good.radius_m, rel=0.05)
    assert np.linalg.norm(starts[1].center_station - good.center_station) < 0.05
    assert np.linalg.norm(obs.circle.center_station - good.center_station) < 1e-6


def test_a_rim_too_small_in_its_image_warns_and_names_the_camera(sim, monkeypatch):
    cfg, world, scene, images = sim
    result = measure_frames(images, world.cameras, cfg)  # 640x512: rims of 150-180 px
    small = [w for w in result.warnings if "the rim spans only" in w]
    assert small and all(w.split(" ")[1].startswith("cam") and "longer lens" in w for w in small), result.warnings
    monkeypatch.setattr(cfg.measurement, "min_rim_axis_px", 0.0)
    assert not any("the rim spans only" in w for w in measure_frames(images, world.cameras, cfg).warnings)
