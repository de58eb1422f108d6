"""Runout compensation: the spin-axis fit (station/wheel/runout.py), the rim pattern's turn
(station/wheel/rim_pattern.py) and the rolling procedure on a small simulated station
(station/procedures/runout.py), with its refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from simulators.vehicle import Runout
from station.capture.frame_average import mean_image
from station.errors import CarMovedSideways, RollTooShort, WheelSlipped
from station.measure import measure_frames
from station.procedures.runout import ROLL_PLAN, compensated, wheel_rolls
from station.wheel.face_motion import MIN_POINTS as MIN_FACE_POINTS
from station.wheel.rim_pattern import rotation_between
from station.wheel.runout import fit_cone, fit_spin_axis, rotate
from tests.station_fixtures import small_station_config


def _angle_deg(a, b) -> float:
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)))


def _rim(rng, tilt_deg):
    """(spin axis (3,), rim normal at roll 0 (3,)) of a wheel on the car's right side."""
    a = np.array([1.0, *rng.normal(0, 0.03, 2)])
    a /= np.linalg.norm(a)
    side = np.cross(a, [0.0, 0.0, 1.0])
    m = rotate(side / np.linalg.norm(side), np.array([np.radians(tilt_deg)]), a)[0]
    return a, rotate(a, np.array([rng.uniform(0, 2 * np.pi)]), m)[0]


def test_the_spin_axis_fit_on_exact_normals_returns_the_axis_and_the_runout():
    rng = np.random.default_rng(1)
    for _ in range(50):
        tilt = rng.uniform(0.01, 0.5)
        a, m = _rim(rng, tilt)
        theta = np.radians(rng.uniform(-30, 30, int(rng.integers(3, 7))))
        spin = fit_spin_axis(rotate(a, theta, m), theta, lip_radius_m=0.2)
        assert _angle_deg(spin.axis_station, a) < 1e-6
        assert spin.runout_deg == pytest.approx(tilt, abs=1e-9)
        assert spin.runout_mm == pytest.approx(400 * np.sin(np.radians(tilt)), rel=1e-9)
        assert _angle_deg(fit_cone(rotate(a, theta, m)), a) < 1e-6  # exact normals lie on the cone too


def test_the_stated_axis_uncertainty_matches_the_spread_of_noisy_fits():
    rng = np.random.default_rng(2)
    a, m = _rim(rng, 0.2)
    theta = np.radians(np.array([0.0, -27.0, 27.0, 0.0]))
    sigma = np.radians(0.01)
    cov = np.tile(np.eye(3) * sigma ** 2, (4, 1, 1))
    axes, stated = [], None
    for _ in range(300):
        n = rotate(a, theta, m) + rng.normal(0, sigma, (4, 3))
        spin = fit_spin_axis(n / np.linalg.norm(n, axis=1, keepdims=True), theta, cov)
        axes.append(spin.axis_station - a)
        stated = spin.cov_axis
    ratio = np.trace(np.cov(np.array(axes).T)) / np.trace(stated)
    assert 0.75 < ratio < 1.33, ratio


def test_a_rim_pattern_turn_is_found_and_its_symmetry_resolved_by_the_prior():
    s = 2048
    phi = np.arange(s) * 2 * np.pi / s
    rng = np.random.default_rng(3)
    face = np.cos(5 * phi) + 0.05 * rng.normal(size=s)            # five spokes: 72 deg alike
    turned = np.roll(face, int(round(np.radians(20.0) / (2 * np.pi / s))))
    angle, peak = rotation_between(face, turned, prior_rad=np.radians(18))
    assert np.degrees(angle) == pytest.approx(20.0, abs=0.2) and peak > 0.9
    alias, _ = rotation_between(face, turned, prior_rad=np.radians(18 + 72))
    assert np.degrees(alias) == pytest.approx(92.0, abs=0.5)      # the prior picks among the alike peaks


# --- the procedure on the simulated station ------------------------------------------------------
RUNOUTS = {w: Runout(t, p, 0.0003) for w, t, p in zip(("FL", "FR", "RL", "RR"), (0.3, 0.15, 0.25, 0.05),
                                                       (30.0, 200.0, 110.0, 300.0))}


def _station(tmp_path, scale):
    """(config, world, scene of vehicle 4 with ``RUNOUTS``) of the built-in station at ``scale``."""
    from simulators.world import SimWorld

    config = small_station_config(tmp_path, scale=scale)
    world = SimWorld.from_config(config)
    base = world.vehicle_scene(4)
    return config, world, replace(base, vehicle=replace(base.vehicle, runout=RUNOUTS))


def _capture(world, scene, k, roll_m, change=None):
    """(measurement, images) of ``scene`` rolled ``roll_m`` (the k-th capture, its own noise);
    ``change(vehicle)`` may alter the vehicle first."""
    vehicle = replace(scene.vehicle, roll_m=roll_m)
    world.set_scene(replace(scene, vehicle=change(vehicle) if change else vehicle))
    burst = [world.render_all(np.random.default_rng([4, k, j])) for j in range(8)]  # the scene rendered once
    images = {c: mean_image([b[c] for b in burst]) for c in burst[0]}
    result = measure_frames(images, world.cameras, world.config)
    assert result.valid, result.failure
    return result, images


def _captures(world, scene, offsets):
    """(measurements, images, truth at the last) of ``scene`` rolled to each of ``offsets`` (m)."""
    pairs = [_capture(world, scene, k, d) for k, d in enumerate(offsets)]
    return [r for r, _ in pairs], [i for _, i in pairs], world.truth()


@pytest.mark.slow
def test_rolling_finds_each_wheels_spin_axis_and_runout(tmp_path):
    """The built-in station (full resolution, true cameras): the spin axes to a few hundredths of
    a degree, where the rim planes are off by their runout."""
    config, world, scene = _station(tmp_path, 1.0)
    results, images, truth = _captures(world, scene, [p * 0.15 for p in ROLL_PLAN])
    rolls = wheel_rolls(results, images, world.cameras, config)
    result = compensated(results[-1], rolls, config)
    assert result.runout_compensated and result.to_json()["runout_compensated"]
    for w in ("FL", "FR", "RL", "RR"):
        t = truth["wheels"][w]
        assert rolls[w].spin.runout_deg == pytest.approx(t["runout_deg"], abs=0.04), w
        spin = np.hypot(result.wheels[w].camber_deg - t["camber_deg"], result.wheels[w].toe_deg - t["toe_deg"])
        rim = np.hypot(results[-1].wheels[w].camber_deg - t["camber_deg"], results[-1].wheels[w].toe_deg - t["toe_deg"])
        assert spin < 0.05, (w, spin)
        assert rolls[w].face_points >= MIN_FACE_POINTS, w  # the face's own motion joined the lip's
        if t["runout_deg"] >= 0.15:
            assert spin < 0.5 * rim, (w, spin, rim)  # the rim plane is off by its runout
        assert np.ptp(rolls[w].roll_deg) == pytest.approx(2 * np.degrees(0.15 / scene.vehicle.wheel.tyre_radius_m),
                                                           abs=0.1)


@pytest.mark.slow
def test_a_roll_too_short_a_slipped_wheel_and_a_car_moved_across_are_refused(tmp_path):
    config, world, scene = _station(tmp_path, 0.5)
    short, short_images, _ = _captures(world, scene, [p * 0.015 for p in ROLL_PLAN])
    with pytest.raises(RollTooShort, match="turned the wheel through only"):
        wheel_rolls(short, short_images, world.cameras, config)

    results, images, _ = _captures(world, scene, [p * 0.15 for p in ROLL_PLAN])

    def swapped(k, change):  # the plan's captures with the k-th one taken of a changed car
        result, image = _capture(world, scene, k, ROLL_PLAN[k] * 0.15, change)
        return results[:k] + [result] + results[k + 1:], images[:k] + [image] + images[k + 1:]

    # RL's wheel turned 8 deg more than the car's travel at the second capture
    slipped = swapped(1, lambda v: replace(v, spin_phase_deg={**v.spin_phase_deg, "RL": v.spin_phase_deg["RL"] + 8.0}))
    with pytest.raises(WheelSlipped, match="RL"):
        wheel_rolls(*slipped, world.cameras, config)
    # the car pushed 4 cm sideways at the third capture
    across = swapped(2, lambda v: replace(v, position_m=(v.position_m[0] + 0.04, v.position_m[1])))
    with pytest.raises(CarMovedSideways, match="across the line of the car's travel"):
        wheel_rolls(*across, world.cameras, config)


def test_the_hubs_are_found_from_the_lip_centres_of_a_rolled_car():
    from station.wheel.hub_center import hub_centers

    rng = np.random.default_rng(7)
    forward = np.array([0.02, 1.0, 0.0]) / np.hypot(0.02, 1.0)
    hubs = np.array([[-0.8, 1.4, 0.33], [0.8, 1.4, 0.33], [-0.8, -1.3, 0.34], [0.8, -1.3, 0.34]])
    axes = np.array([[-1.0, 0.003, -0.01], [1.0, 0.002, -0.012], [-1.0, -0.001, -0.008], [1.0, 0.0, -0.009]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    travel = np.array([0.0, -0.15, 0.15, 0.0]) + np.array([0.004, -0.002, 0.003, 0.0])
    radii = np.array([0.31, 0.312, 0.309, 0.311])
    offsets = rng.normal(0, 3e-4, (4, 3))
    offsets -= axes * np.sum(offsets * axes, axis=1, keepdims=True)       # across each axis
    centers, turns = [], []
    for h, a, e, r, side in zip(hubs, axes, offsets, radii, (-1, 1, -1, 1)):
        theta = -side * travel / r
        centers.append(h + np.outer(travel, forward) + rotate(a, theta, e))
        turns.append(theta)
    found = hub_centers(np.array(centers), np.array(turns), axes, forward)
    assert np.allclose(found.center_station, hubs, atol=1e-9)
    assert np.allclose(found.offset_station, offsets, atol=1e-9)
    assert np.allclose(found.travel_m, travel[:3], atol=1e-9)


def test_the_views_agreement_a_spin_axis_carries_is_its_typical_captures():
    """One capture whose two views disagree (an edge decided the other way under its noise) does
    not make the spin axis uncertain; the median capture's agreement is what it carries."""
    from types import SimpleNamespace

    from station.procedures.runout import _typical_views
    from station.wheel.view_agreement import ViewAgreement

    def views(deg):
        return ViewAgreement(np.zeros((2, 3)), np.zeros(2), np.zeros(2), np.array([0.0, np.radians(deg), 0.0]))

    angles = [0.05, 1.38, 0.08, 0.06, 0.04, 0.54]
    typical = _typical_views([SimpleNamespace(views=views(a)) for a in angles])
    assert typical.angle_deg == pytest.approx(0.06)
    assert _typical_views([SimpleNamespace(views=None)]) is None


def test_a_lip_whose_two_views_disagree_weighs_less_against_the_faces_axis():
    """The views' disagreement is a bias of the lip's edge, not of the face: it goes into the
    lip's spin axis before the two join, so the joined axis leans to the face's and is stated
    by what the face knows, not by the lip's doubt added afterwards."""
    from station.procedures.runout import lip_spin_axis
    from station.wheel.face_motion import FaceSpin, with_face
    from station.wheel.view_agreement import ViewAgreement, disagreement_bound_covariance

    rng = np.random.default_rng(4)
    a, m = _rim(rng, 0.2)
    theta = np.radians(np.array([0.0, -25.0, -12.5, 12.5, 25.0, 0.0]))
    cov = np.tile(np.eye(3) * np.radians(0.01) ** 2, (6, 1, 1))
    across = np.cross(a, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    views = ViewAgreement(np.array([a, a]), np.zeros(2), np.zeros(2), np.radians(0.16) * across)
    agreeing = lip_spin_axis(rotate(a, theta, m), theta, cov, 0.22, None, 0.05)
    doubted = lip_spin_axis(rotate(a, theta, m), theta, cov, 0.22, views, 0.05)
    np.testing.assert_allclose(doubted.cov_axis - agreeing.cov_axis, disagreement_bound_covariance(views, 0.05), atol=1e-15)
    assert np.sqrt(np.trace(doubted.cov_axis) / 2) > np.radians(0.16 / 2) * 0.99     # half the disagreement
    # a face axis 0.02 deg off the lip's, as sure as the lip's fit alone
    face_axis = a + np.radians(0.02) * np.cross(a, across)
    face = FaceSpin(face_axis / np.linalg.norm(face_axis), agreeing.cov_axis.copy(), 150)
    even = with_face(agreeing, face, 0.22)
    leaning = with_face(doubted, face, 0.22)
    assert _angle_deg(even.axis_station, a) == pytest.approx(0.01, rel=0.05)        # halfway
    assert _angle_deg(leaning.axis_station, face.axis_station) < 0.002               # nearly the face's
    assert np.trace(leaning.cov_axis) < np.trace(agreeing.cov_axis) * 1.01            # stated as sure as the face
