"""The operators that place the box, and the box as the simulator renders it."""

from __future__ import annotations

import io

import numpy as np
import pytest

from calibration.box_detect import BoxDetector
from calibration.box_target import box_pose_on_floor
from station.config import load_box, load_config
from station.operator import TerminalOperator


@pytest.fixture(scope="module")
def station():
    from simulators.sim_operator import SimOperator
    from simulators.world import SimWorld
    config = load_config()
    world = SimWorld.from_config(config)
    box = load_box(config.box_path)
    return config, world, box, SimOperator(world, box, config, seed=5)


def test_fixture_pose_is_exactly_the_configured_one(station):
    config, world, box, op = station
    op.place_box_at_fixture("RL")
    R, t = box_pose_on_floor(config.calibration.fixture["RL"].position_m, config.calibration.fixture["RL"].yaw_deg)
    quads = world.scene.quads
    assert len(quads) == len(box.faces)
    expected = box.face_quads(R, t)
    for q, (corners, tex) in zip(quads, expected):
        assert np.array_equal(q.corners_station, corners) and q.texture is tex
    # standing on the runway
    assert abs(min(q.corners_station[:, 2].min() for q in quads)) < 1e-12


def test_intrinsic_poses_differ_and_show_two_faces_to_both_cameras(station):
    config, world, box, op = station
    pair = config.pairs["FR"]
    ids = [pair.precision, pair.reference]
    poses = []
    for i in range(5):
        op.place_box_for_intrinsics(ids, i)
        R, t = op.poses[("intrinsics", "FR", i)]
        poses.append((R, t))
        for cam in ids:
            faces, frac = op._visible_fraction(cam, R, t)
            assert faces >= 2 and frac > 0.8
    tilts = [np.degrees(np.arccos(np.clip(R[2, 2], -1, 1))) for R, _ in poses]
    assert max(tilts) > 5        # tilted, not only yawed: distortion and focal are exercised
    assert len({round(float(t[1]), 4) for _, t in poses}) == 5
    op.done()
    assert world.scene.quads == ()


def test_terminal_operator_prompts_and_waits_for_enter():
    out = io.StringIO()
    op = TerminalOperator(io.StringIO("\n\n"), out)
    op.place_box_for_intrinsics(["cam1", "cam2"], 0)
    op.place_box_at_fixture("FR")
    op.done()
    text = out.getvalue()
    assert "cam1, cam2" in text and "FR fixture" in text and text.count("press Enter") == 2


@pytest.mark.slow
def test_the_simulator_renders_the_box_where_the_geometry_says(station):
    """Texture convention shared with simulators.scene: detected corners on a rendered image
    (noise sigma 2, distortion, blur) agree with the projected box geometry."""
    config, world, box, op = station
    op.place_box_at_fixture("FR")
    R, t = box_pose_on_floor(config.calibration.fixture["FR"].position_m, config.calibration.fixture["FR"].yaw_deg)
    det = BoxDetector(box).detect(world.render("cam1", np.random.default_rng(0)))
    assert set(det.faces) == {"px", "ny"} and det.n_points > 200
    err = det.pixels - world.cameras["cam1"].project(det.points_box @ R.T + t)
    assert np.sqrt(np.mean(err ** 2)) < 0.1          # per axis
    assert np.abs(err.mean(axis=0)).max() < 0.02     # no systematic offset (half a texel would be ~0.35 px)
