"""The face's turn of a steered wheel, found on the face's surface as the pair sees it.

Vehicle 3304's front-left rim shows its brake disc's radial pattern through wide windows, 35 mm
behind its dark spokes: a profile sampled in one plane reads its face's turn there up to half a
degree off once the wheel is steered; on the surface each camera reads it to a few hundredths.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from station.capture.frame_average import mean_image
from station.config import load_config
from station.rim.camera_response import linear_images
from station.wheel.face_surface import MIN_CELLS, face_surface, turn_on_surface
from station.wheel.rim_pattern import FacePose, ring_basis


def _pose(vehicle, wheel: str) -> FacePose:
    center, R = vehicle.wheel_frame_station(wheel)
    return FacePose(np.asarray(center, float), R[:, 2].copy(), float(vehicle.wheel.rim_radius_m))


@pytest.mark.slow
@pytest.mark.parametrize("steer_deg", [10.0, -10.0])
def test_a_steered_wheels_face_turn_is_found_to_hundredths_on_its_surface(steer_deg):
    from simulators.world import SimWorld

    config = load_config(None)
    world = SimWorld.from_config(config)
    scene = world.vehicle_scene(3304)
    cams = (config.pairs["FL"].precision, config.pairs["FL"].reference)
    steered = replace(scene, vehicle=replace(scene.vehicle, steer_deg=steer_deg))

    def images(s, k):          # the station's capture: the mean of its frames
        rng = np.random.default_rng([3304, k])
        frames = config.capture.frames_averaged
        return linear_images({c: mean_image([world.render(c, rng, s) for _ in range(frames)]) for c in cams}, config)

    straight_images, steered_images = images(scene, 0), images(steered, 1)
    straight, turned = _pose(scene.vehicle, "FL"), _pose(steered.vehicle, "FL")
    # the true turn: the straight pose's in-plane direction e1 carried by the wheel, in the turned pose's basis
    R0 = scene.vehicle.wheel_frame_station("FL")[1]
    R1 = steered.vehicle.wheel_frame_station("FL")[1]
    f = R1 @ R0.T @ ring_basis(straight.axis_station)[0]
    e1, e2 = ring_basis(turned.axis_station)
    true_psi = float(np.arctan2(f @ e2, f @ e1))
    assert abs(np.degrees(true_psi)) > 1.0          # SAI makes the face turn about its own axis

    surface = face_surface(straight_images, world.cameras, straight)
    assert surface.usable_cells > MIN_CELLS
    error_deg = [np.degrees(turn_on_surface(surface, straight_images[c], steered_images[c], world.cameras[c], turned,
                                            prior_rad=true_psi + np.radians(0.5)) - true_psi) for c in cams]
    assert np.abs(error_deg).max() < 0.06, error_deg      # each camera (the plane's profile: 0.5 deg)
    assert abs(np.mean(error_deg)) < 0.025, error_deg     # the pair, as the procedure takes it


def test_a_circle_on_the_wheels_face_is_refused_and_the_flange_is_not():
    from types import SimpleNamespace

    from simulators.world import SimWorld
    from station.errors import MeasurementError
    from station.wheel.pair import check_face_behind

    config = load_config(None)
    world = SimWorld.from_config(config)
    scene = world.vehicle_scene(3)
    cams = (config.pairs["FL"].precision, config.pairs["FL"].reference)
    rng = np.random.default_rng(3)
    images = linear_images({c: world.render(c, rng, scene) for c in cams}, config)
    flange = _pose(scene.vehicle, "FL")
    depth = scene.vehicle.wheel.rim_face_depth_m

    def observation(centre, radius):
        circle = SimpleNamespace(center_station=centre, axis_station=flange.axis_station, radius_m=radius)
        return SimpleNamespace(cams=cams, circle=circle)

    check_face_behind(observation(flange.center_station, flange.radius_m), images, world.cameras)
    # the ring where the spokes meet the barrel: in the face's plane, a fifth smaller
    on_face = observation(flange.center_station - depth * flange.axis_station, 0.8 * flange.radius_m)
    with pytest.raises(MeasurementError, match="not the flange"):
        check_face_behind(on_face, images, world.cameras)
