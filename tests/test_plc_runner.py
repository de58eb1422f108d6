"""station/plc/runner.py on the simulated station: without a seed, each PLC cycle measures the
vehicle of its cycle number (docs/plc.md), not an empty lift."""

from __future__ import annotations

import pytest

from station.plc.runner import CycleRequest, measurement_runner
from tests.station_fixtures import small_station_config, truth_calibration


def test_placing_a_vehicle_changes_what_the_simulated_cameras_see(tmp_path):
    from simulators.sim_station import SimulatedStation
    from simulators.world import SimWorld

    config = small_station_config(tmp_path)
    world = SimWorld.from_config(config)
    sim = SimulatedStation(world)
    for seed in (4, 9):
        sim.place_vehicle(seed)
        want = world.vehicle_scene(seed).vehicle
        assert sim.vehicle_seed == seed and world.scene.vehicle == want
        assert sim.truth()["wheels"]["RR"]["camber_deg"] == pytest.approx(want.camber_deg["RR"], abs=1e-9)


@pytest.mark.slow
def test_a_plc_cycle_without_a_seed_measures_the_vehicle_of_its_cycle_number(tmp_path):
    config = small_station_config(tmp_path, capture__frames_averaged=1, recording__enabled=False)
    truth_calibration(config)
    run = measurement_runner(config)
    try:
        result = run(CycleRequest("measure", "JOB-000002", None, 2))
    finally:
        run.close()
    assert result.valid, result.failure  # an empty lift faults 401
    from simulators.world import SimWorld

    want = SimWorld.from_config(config).vehicle_scene(2).vehicle.toe_deg
    for wheel in ("FL", "FR", "RL", "RR"):  # the cameras saw vehicle 2, and it was measured
        assert result.truth["wheels"][wheel]["toe_deg"] == pytest.approx(want[wheel], abs=1e-9)
        assert result.wheels[wheel].toe_deg == pytest.approx(want[wheel], abs=0.5)

