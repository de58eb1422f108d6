"""Signed alignment angles recover a simulated vehicle's toe and camber exactly."""

from dataclasses import replace

import numpy as np
import pytest

from calibration.station_frame import WHEELS
from simulators.vehicle import Vehicle, random_vehicle
from station.alignment import angle_covariance, angle_vector, compute_angles, paper_front_angles
from station.result import ANGLE_NAMES


def _wheels(vehicle):
    frames = {w: vehicle.wheel_frame_station(w) for w in WHEELS}
    return {w: f[0] for w, f in frames.items()}, {w: f[1][:, 2] for w, f in frames.items()}


@pytest.mark.parametrize("seed", range(8))
def test_signed_angles_recover_truth(seed):
    vehicle = random_vehicle(np.random.default_rng(seed))
    centers, axes = _wheels(vehicle)
    angles = compute_angles(centers, axes)
    for w in WHEELS:
        assert angles["wheels"][w]["toe_deg"] == pytest.approx(vehicle.toe_deg[w], abs=1e-9)
        assert angles["wheels"][w]["camber_deg"] == pytest.approx(vehicle.camber_deg[w], abs=1e-9)
    t = vehicle.toe_deg
    assert angles["axles"]["front"]["total_toe_deg"] == pytest.approx(t["FL"] + t["FR"], abs=1e-9)
    assert angles["thrust_deg"] == pytest.approx((t["RL"] - t["RR"]) / 2, abs=1e-9)
    assert angles["axles"]["front"]["track_m"] == pytest.approx(vehicle.track_front_m, abs=1e-9)
    assert angles["wheelbase_m"]["left"] == pytest.approx(vehicle.wheelbase_m, abs=1e-9)


def test_signs_as_technicians_read_them():
    # Right front wheel turned front-inward and leaning out at the top.
    v = Vehicle(toe_deg={"FL": 0, "FR": 0.5, "RL": 0, "RR": 0}, camber_deg={"FL": 0, "FR": 1.0, "RL": 0, "RR": 0})
    c, R = v.wheel_frame_station("FR")
    axis = R[:, 2]
    forward_of_wheel = np.cross(np.array([0, 0, 1.0]), axis)  # rolling direction for a right wheel
    assert forward_of_wheel[0] < 0, "toe-in: the front of the right wheel points toward the centreline (-x)"
    top_of_wheel = np.cross(axis, forward_of_wheel)
    assert top_of_wheel[0] > 0, "positive camber: the top leans away from the car (+x for a right wheel)"
    assert compute_angles(*_wheels(v))["wheels"]["FR"]["toe_deg"] == pytest.approx(0.5)


def test_thrust_line_and_front_toe_against_it():
    v = Vehicle(toe_deg={"FL": 0.1, "FR": 0.1, "RL": 0.3, "RR": -0.1})
    a = compute_angles(*_wheels(v))
    assert a["thrust_deg"] == pytest.approx(0.2)
    assert a["wheels"]["FR"]["toe_thrust_deg"] == pytest.approx(0.3)
    assert a["wheels"]["FL"]["toe_thrust_deg"] == pytest.approx(-0.1)


def test_setback_sign():
    v = Vehicle()
    centers, axes = _wheels(v)
    centers["FR"] = centers["FR"] + np.array([0, 0.01, 0])
    a = compute_angles(centers, axes)
    assert a["axles"]["front"]["setback_m"] == pytest.approx(0.01, abs=1e-6)


@pytest.mark.parametrize("wheel", WHEELS)
def test_camber_is_read_against_the_runways_not_the_wheel_centres(wheel):
    # one tyre 4 mm lower (less air), or a lip centred off its hub: the wheels still stand on
    # the same runways, and no wheel's camber or toe moves; through the plane of the wheel
    # centres the left and right cambers would move apart by about 0.15 deg
    v = random_vehicle(np.random.default_rng(3))
    centers, axes = _wheels(v)
    before = compute_angles(centers, axes)
    centers[wheel] = centers[wheel] + np.array([0.0, 0.0, -0.004])
    after = compute_angles(centers, axes)
    for w in WHEELS:
        assert after["wheels"][w]["camber_deg"] == pytest.approx(before["wheels"][w]["camber_deg"], abs=1e-9)
        assert after["wheels"][w]["toe_deg"] == pytest.approx(before["wheels"][w]["toe_deg"], abs=1e-9)
    np.testing.assert_allclose(after["R_station_align"][:, 2], [0.0, 0.0, 1.0], atol=1e-12)


def test_a_yawed_car_keeps_its_angles_and_the_runways_up():
    v = random_vehicle(np.random.default_rng(4))
    for yaw in (0.0, 3.0, -2.0):
        a = compute_angles(*_wheels(replace(v, yaw_deg=yaw)))
        for w in WHEELS:
            assert a["wheels"][w]["camber_deg"] == pytest.approx(v.camber_deg[w], abs=1e-9)
            assert a["wheels"][w]["toe_deg"] == pytest.approx(v.toe_deg[w], abs=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_paper_equations_equal_signed_angles_in_magnitude_with_square_rear_axle(seed):
    rng = np.random.default_rng(100 + seed)
    front = {w: rng.uniform(-2, 2) for w in ("FL", "FR")}
    camber = {w: rng.uniform(-3, 3) for w in ("FL", "FR")}
    v = Vehicle(yaw_deg=rng.uniform(-1, 1), position_m=(0.02, -0.03),
                toe_deg={**front, "RL": 0.0, "RR": 0.0}, camber_deg={**camber, "RL": 0.0, "RR": 0.0})
    centers, axes = _wheels(v)
    signed = compute_angles(centers, axes)["wheels"]
    paper = paper_front_angles(centers, axes)
    assert paper["toe_1_deg"] == pytest.approx(abs(signed["FR"]["toe_deg"]), abs=1e-6)
    assert paper["toe_2_deg"] == pytest.approx(abs(signed["FL"]["toe_deg"]), abs=1e-6)
    assert paper["camber_1_deg"] == pytest.approx(abs(signed["FR"]["camber_deg"]), abs=1e-6)
    assert paper["camber_2_deg"] == pytest.approx(abs(signed["FL"]["camber_deg"]), abs=1e-6)


def test_covariance_propagation_matches_monte_carlo():
    rng = np.random.default_rng(5)
    v = random_vehicle(rng)
    centers, axes = _wheels(v)
    s_axis, s_center = 1e-4, 2e-4
    cov = angle_covariance(centers, axes, {w: np.eye(3) * s_center**2 for w in WHEELS},
                           {w: np.eye(3) * s_axis**2 for w in WHEELS})
    samples = []
    for _ in range(800):
        c = {w: centers[w] + rng.normal(0, s_center, 3) for w in WHEELS}
        a = {w: axes[w] + rng.normal(0, s_axis, 3) for w in WHEELS}
        samples.append(angle_vector(compute_angles(c, a)))
    std_mc = np.std(samples, axis=0)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), std_mc, rtol=0.15)
    assert len(ANGLE_NAMES) == cov.shape[0]


def test_the_batched_angles_and_their_covariance_are_those_of_compute_angles():
    from calibration.station_frame import SIDE, WHEELS
    from station.alignment import angle_covariance, angle_vector, angle_vectors, compute_angles
    from station.result import ANGLE_NAMES

    rng = np.random.default_rng(11)
    nominal = {"FL": [-0.8, 1.4, 0.33], "FR": [0.8, 1.4, 0.33], "RL": [-0.8, -1.3, 0.33], "RR": [0.8, -1.3, 0.33]}
    centers = {w: np.array(c) + rng.normal(0, 0.03, 3) for w, c in nominal.items()}
    axes = {w: np.array([SIDE[w], 0, 0]) + rng.normal(0, 0.03, 3) for w in WHEELS}
    axes = {w: a / np.linalg.norm(a) for w, a in axes.items()}  # the covariance is of unit axes
    C = np.stack([centers[w] for w in WHEELS])[None]
    A = np.stack([axes[w] for w in WHEELS])[None]
    np.testing.assert_allclose(angle_vectors(C, A)[0], angle_vector(compute_angles(centers, axes)), atol=1e-12)
    cov_c = {w: np.diag(rng.uniform(1e-8, 1e-6, 3)) for w in WHEELS}
    cov_a = {w: np.diag(rng.uniform(1e-8, 1e-6, 3)) for w in WHEELS}
    # the reference: central differences of compute_angles, one coordinate at a time
    ref = np.zeros((len(ANGLE_NAMES),) * 2)
    h = 1e-7
    for w in WHEELS:
        for source, S in ((centers, cov_c[w]), (axes, cov_a[w])):
            J = np.empty((len(ANGLE_NAMES), 3))
            for k in range(3):
                plus, minus = dict(source), dict(source)
                plus[w] = source[w] + h * np.eye(3)[k]
                minus[w] = source[w] - h * np.eye(3)[k]
                args_p = (plus, axes) if source is centers else (centers, plus)
                args_m = (minus, axes) if source is centers else (centers, minus)
                J[:, k] = (angle_vector(compute_angles(*args_p)) - angle_vector(compute_angles(*args_m))) / (2 * h)
            ref += J @ S @ J.T
    np.testing.assert_allclose(angle_covariance(centers, axes, cov_c, cov_a), ref, rtol=1e-6, atol=1e-12)
