"""Steering geometry: the steering-axis fit on exact poses, and a sweep too small refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from simulators.vehicle import random_kingpins, random_vehicle
from station.wheel.rim_pattern import ring_basis
from station.wheel.steering_axis import fit_steering_axis


def _exact_poses(vehicle, wheel, steer_plan_deg):
    """(normals (K,3), face turns (K,) rad against the last pose, centres (K,3)) of ``wheel``
    steered to each angle, from the simulator's exact frames."""
    frames = [replace(vehicle, steer_deg=s).wheel_frame_station(wheel) for s in steer_plan_deg]
    c_ref, R_ref = frames[-1]
    e1_ref, _ = ring_basis(R_ref[:, 2])
    normals, psi, centers = [], [], []
    for c, R in frames:
        a = R[:, 2]
        f = R @ R_ref.T @ e1_ref          # the reference's in-plane direction, carried by the wheel
        e1, e2 = ring_basis(a)
        normals.append(a)
        psi.append(np.arctan2(f @ e2, f @ e1))
        centers.append(c)
    return np.array(normals), np.array(psi), np.array(centers)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_axis_fit_on_exact_poses_returns_caster_and_sai_to_a_micro_degree(seed):
    rng = np.random.default_rng(seed)
    kingpins, ackermann = random_kingpins(np.random.default_rng([seed, 33]))
    vehicle = replace(random_vehicle(rng), kingpin=kingpins, ackermann=ackermann, yaw_deg=float(rng.uniform(-2, 2)))
    for wheel in ("FL", "FR"):
        normals, psi, centers = _exact_poses(vehicle, wheel, (0.0, 10.0, -10.0, 0.0))
        axis = fit_steering_axis(normals, psi, centers, reference=len(psi) - 1)
        truth = vehicle.truth()["wheels"][wheel]
        u_true = np.asarray(truth["kingpin_axis_station"])
        R = vehicle.R_station_vehicle
        side = 1.0 if wheel == "FR" else -1.0
        x, y, z = R.T @ axis.direction_station
        assert np.degrees(np.arctan2(-y, z)) == pytest.approx(truth["caster_deg"], abs=1e-6)
        assert np.degrees(np.arctan2(-side * x, z)) == pytest.approx(truth["sai_deg"], abs=1e-6)
        assert np.degrees(np.arccos(min(1.0, axis.direction_station @ u_true))) < 1e-6
        d = axis.point_station - np.asarray(truth["kingpin_point_station_m"])
        assert np.linalg.norm(d - (d @ u_true) * u_true) < 1e-9  # the point lies on the true axis
        steer = [replace(vehicle, steer_deg=s).steer_angles_deg()[wheel] for s in (0.0, 10.0, -10.0, 0.0)]
        assert axis.steer_deg == pytest.approx(steer, abs=1e-6)


def test_the_rim_normals_alone_leave_sai_weak_and_the_face_turn_fixes_it():
    """With noise on the normals only, the fit without the face's turn scatters in SAI, the
    full pose does not: the turn about the wheel's own axis carries SAI."""
    rng = np.random.default_rng(7)
    kingpins, ackermann = random_kingpins(np.random.default_rng([7, 33]))
    vehicle = replace(random_vehicle(rng), kingpin=kingpins, ackermann=ackermann)
    normals, psi, centers = _exact_poses(vehicle, "FL", (0.0, 10.0, -10.0, 0.0))
    cov = np.repeat((np.radians(0.01) ** 2 * np.eye(3))[None], 4, axis=0)
    sai_full, sai_alone = [], []
    for k in range(40):
        noisy = normals + np.random.default_rng(k).normal(0, np.radians(0.01), normals.shape)
        noisy /= np.linalg.norm(noisy, axis=1, keepdims=True)
        turns = psi + np.random.default_rng(100 + k).normal(0, np.radians(0.01), psi.shape)
        for out, var in ((sai_full, np.full(4, np.radians(0.01) ** 2)), (sai_alone, np.full(4, 1e6))):
            u = fit_steering_axis(noisy, turns, centers, cov, var, reference=3).direction_station
            out.append(np.degrees(np.arctan2(u[0], u[2])))
    assert np.std(sai_full) < 0.05 and np.std(sai_alone) > 3 * np.std(sai_full)


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    from station.cycle import Station
    from tests.station_fixtures import small_station_config, truth_calibration

    # full resolution (the half-resolution station loses the rims' detail at a steer); square
    # rims, so that the included angle's camber is the spin axis'; one frame per capture
    config = small_station_config(tmp_path_factory.mktemp("steering"), 1.0, capture__frames_averaged=1,
                                  simulation__runout_max_deg=0.0)
    truth_calibration(config)
    with Station(config, seed=3301, progress=lambda msg: None, workers=0) as s:
        yield s


@pytest.mark.slow
def test_a_guided_sweep_gives_caster_sai_and_included_angle(station):
    from station.procedures.steer_guide import GuidedSteering
    from station.records.recording import read_recording_summary

    shown = []
    guide = GuidedSteering(station, mover=station.context.simulation, show=shown.append)
    result = station.caster(guide, sweep_deg=10.0, job_id="JOB-S1")
    assert result.valid, result.failure
    s = result.steering
    assert s is not None and s.sweep_deg == 10.0
    for w in ("FL", "FR"):
        t = result.truth["wheels"][w]
        r = s.wheels[w]
        assert r.caster_deg == pytest.approx(t["caster_deg"], abs=0.15), w
        assert r.sai_deg == pytest.approx(t["sai_deg"], abs=0.25), w
        assert r.included_angle_deg == pytest.approx(t["included_angle_deg"], abs=0.25), w
        assert 8.0 < r.steer_left_deg < 12.0 and -12.0 < r.steer_right_deg < -8.0
        assert abs(result.errors[w]["caster_error_deg"]) < 0.15
    assert any("left: " in line and "of 10 deg" in line for line in shown)
    assert sum("hold still: capturing" in line for line in shown) == 3
    assert result.to_json()["steering"]["wheels"]["FL"]["caster_deg"] == s.wheels["FL"].caster_deg
    entities = read_recording_summary(result.recording)["entities"]
    assert {"/vehicle/FL/steering/axis", "/vehicle/FR/steering/axis"} <= set(entities)


class _SteersLittle:
    """An operator who steers a fifth of what is asked."""

    def __init__(self, simulation):
        self.simulation = simulation

    def roll_car(self, distance_m: float) -> None:
        pass

    def steer(self, angle_deg: float) -> None:
        self.simulation.steer(0.2 * angle_deg)


@pytest.mark.slow
def test_a_sweep_too_small_is_refused_with_its_code_and_kept(station):
    from station.errors import SweepTooSmall
    from station.records.history import History

    result = station.caster(_SteersLittle(station.context.simulation), sweep_deg=10.0, job_id="JOB-S2")
    assert not result.valid and result.failure.code == SweepTooSmall.code
    assert "at least 4 deg each way" in result.failure.message and result.failure.hint
    with History(station.config.data_path("history.sqlite"), read_only=True) as h:
        assert not h.get(result.cycle_id)["valid"]
