"""The odometry simulator: the paths the issue asks for, determinism, and true geometry."""

import numpy as np
import pytest

from simulators.odometry_scene import Rig, Room, path, render, turtle_path


def test_paths_have_the_required_shape():
    short, long = path("short"), path("long")
    assert len(short) - 1 == 11 and len(long) - 1 >= 200
    for P, step in ((short, 0.4), (long, 0.15)):
        # the chord of an arc is shorter than the arc: every step is at most its length
        d = np.linalg.norm(np.diff(P[:, :2], axis=0), axis=1)
        assert np.all(d <= step + 1e-12) and np.all(d > 0.97 * step)
    turns = np.degrees(np.diff(long[:, 2]))
    assert (np.abs(turns) < 1e-9).sum() > 100            # straight legs
    assert turns.max() > 0 and turns.min() < 0            # turns both ways
    assert np.degrees(long[-1, 2] - long[0, 2]) == pytest.approx(360.0)
    with pytest.raises(ValueError):
        path("medium")


def test_paths_stay_clear_of_the_furniture_and_walls():
    room = Room(0, tex_size=64)
    for kind in ("short", "long"):
        P = path(kind)[:, :2]
        assert np.all(np.abs(P[:, 0]) < room.half_x - 1.0) and np.all(np.abs(P[:, 1]) < room.half_y - 1.0)
        for lo, hi in room.obstacles:
            gap = np.linalg.norm(np.maximum(np.maximum(lo - P, P - hi), 0), axis=1)
            assert gap.min() > 0.8, (kind, lo, hi)


def test_turtle_arc_is_exact():
    P = turtle_path((0.0, 0.0, 0.0), [("turn", 90, 9)], 1.0)
    r = 9 * 1.0 / (np.pi / 2)                               # arc length / angle
    np.testing.assert_allclose(P[-1], [r, r, np.pi / 2], atol=1e-12)


def test_render_is_deterministic_and_geometric():
    room = Room(3, tex_size=256)
    rig = Rig(width=160, height=120, f_px=100.0)
    left, right = rig.cameras_world(0.0, -2.0, np.pi / 2)   # facing +y (north wall)
    a = render(room, left, np.random.default_rng(1))
    b = render(room, left, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    assert a.dtype == np.uint8 and a.shape == (120, 160) and a.std() > 10
    # the window on the north wall (x 3.0..4.6, z 1.0..2.3) is bright where it projects
    centre = np.array([[3.8, room.half_y - 0.01, 1.65]])
    u, v = np.round(left.project(centre)[0]).astype(int)
    if 0 <= u < 160 and 0 <= v < 120:
        assert a[v, u] > 200
    else:
        pytest.fail("the window should be in view")
