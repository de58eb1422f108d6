"""Errors against the truth (`station odometry DIR --truth FILE`): the numbers match a hand
computation on tiny trajectories, and the command prints what the written trajectory gives."""

from __future__ import annotations

import io
import re
from contextlib import redirect_stdout

import numpy as np
import pytest

from simulators.odometry_scene import Rig, path, write_sequence
from station import cli
from station.odometry.poses_io import read_poses
from station.odometry.truth_errors import (compare, nearest_rotation, rotation_angle_deg,
                                           segment_errors)


def _rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _poses(B, R=None) -> np.ndarray:
    T = np.tile(np.eye(4), (len(B), 1, 1))
    T[:, :3, 3] = B
    if R is not None:
        T[:, :3, :3] = R
    return T


B_TRUE = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 3.0]])     # 1 m steps forward
B_EST = np.array([[0, 0, 0], [0, 0, 1.1], [0, 0, 2.2], [0.4, 0, 3.3]])     # errors 0.1, 0.2, 0.5
# the 3 m path's segments: 10 %..80 % of it, 0.3 .. 2.4 m; the end image is the first one more
# than L further along: from image 0, L = 0.3-0.9 ends at 1, 1.2-1.8 at 2, 2.1-2.4 at 3, ...
SEGMENTS = ([(0, 1, L) for L in (0.3, 0.6, 0.9)] + [(0, 2, L) for L in (1.2, 1.5, 1.8)]
            + [(0, 3, L) for L in (2.1, 2.4)] + [(1, 2, L) for L in (0.3, 0.6, 0.9)]
            + [(1, 3, L) for L in (1.2, 1.5, 1.8)] + [(2, 3, L) for L in (0.3, 0.6, 0.9)])


def test_translation_and_drift_by_hand():
    e = compare(_poses(B_EST), _poses(B_TRUE))
    t = e.translation
    assert t.n_steps == 3 and t.distance_m == pytest.approx(3.0)
    assert t.mean_m == pytest.approx((0.1 + 0.2 + 0.5) / 3)
    assert t.final_m == pytest.approx(0.5) and t.max_m == pytest.approx(0.5)
    assert t.drift_pct == pytest.approx(100 * 0.5 / 3)
    assert e.rot_mean_deg == pytest.approx(0, abs=1e-12) and e.rot_final_deg == pytest.approx(0, abs=1e-12)


def test_segment_translation_errors_by_hand():
    s = segment_errors(_poses(B_EST), _poses(B_TRUE))
    assert not s.kitti_lengths
    np.testing.assert_allclose(s.lengths_m, [0.3, 0.6, 0.9, 1.2, 1.5, 1.8, 2.1, 2.4])
    # no rotation: the error of a segment is the change of the position error along it
    err = B_EST - B_TRUE
    by_hand = [np.linalg.norm(err[b] - err[a]) / L for a, b, L in SEGMENTS]
    assert s.n_segments == len(SEGMENTS) == 17
    assert s.t_pct == pytest.approx(100 * np.mean(by_hand))
    assert s.r_deg_per_m == pytest.approx(0, abs=1e-12)


def test_rotation_errors_by_hand():
    yaw = [0.0, 0.0, 1.0, 2.0]                       # the estimate turns 1 then 2 deg too much
    e = compare(_poses(B_TRUE, np.array([_rot_y(a) for a in yaw])), _poses(B_TRUE))
    assert e.rot_mean_deg == pytest.approx((0 + 1 + 2) / 3)
    assert e.rot_final_deg == pytest.approx(2.0)
    assert e.translation.mean_m == pytest.approx(0, abs=1e-12)
    by_hand = [abs(yaw[b] - yaw[a]) / L for a, b, L in SEGMENTS]
    assert e.segments.r_deg_per_m == pytest.approx(np.mean(by_hand))


def test_kitti_segments_on_a_long_path():
    B = np.zeros((121, 3))
    B[:, 2] = np.arange(121.0)                       # 120 m straight, 1 m per image
    s = segment_errors(_poses(1.01 * B), _poses(B))  # the estimate 1 % too long
    # KITTI's 100 m only fits; from images 0 and 10 (every 10th) to 101 and 111 (101 m on)
    assert s.kitti_lengths and s.n_segments == 2
    assert s.t_pct == pytest.approx(100 * 0.01 * 101 / 100)


def test_rotation_helpers():
    assert rotation_angle_deg(_rot_y(1e-6)) == pytest.approx(1e-6, rel=1e-6)
    assert rotation_angle_deg(_rot_y(179.0)) == pytest.approx(179.0)
    sheared = _rot_y(10.0) @ np.array([[1.02, 0.01, 0], [0, 0.99, 0], [0, 0, 1.0]])
    R = nearest_rotation(sheared)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert rotation_angle_deg(R) == pytest.approx(10.0, abs=0.6)


def test_a_method_that_stopped_is_compared_up_to_where_it_stopped():
    e = compare(_poses(B_EST[:3]), _poses(B_TRUE))
    assert e.translation.n_steps == 2 and e.translation.final_m == pytest.approx(0.2)
    assert e.translation.distance_m == pytest.approx(2.0)
    e = compare(_poses(B_EST[:1]), _poses(B_TRUE))
    assert e.translation.n_steps == 0 and np.isnan(e.translation.mean_m) and e.segments.n_segments == 0


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("truth") / "seq"
    write_sequence(d, "short", seed=0, rig=Rig(width=360, height=240, f_px=240.0),
                   poses_xy_yaw=path("short")[2:6])
    return d


def _value(text: str, label: str) -> list[float]:
    line = next(ln for ln in text.splitlines() if ln.startswith(label))
    return [float(v) for v in line[len(label):].split()]


def test_the_command_prints_the_errors_of_the_written_trajectories(seq_dir, tmp_path):
    truth_file = tmp_path / "truth.txt"
    truth_file.write_text((seq_dir / "poses.txt").read_text())
    (seq_dir / "poses.txt").rename(seq_dir / "poses.off")          # only --truth gives it
    try:
        out = io.StringIO()
        with redirect_stdout(out):
            rc = cli.main(["odometry", str(seq_dir), "--truth", str(truth_file), "--quiet",
                           "--out", str(tmp_path / "t.txt")])
    finally:
        (seq_dir / "poses.off").rename(seq_dir / "poses.txt")
    text = out.getvalue()
    assert rc == 0
    assert f"errors against the truth ({truth_file}):" in text
    assert re.search(r"^ +paper +robust$", text, re.M)
    T_true = read_poses(truth_file)
    path_m = np.linalg.norm(np.diff(T_true[:, :3, 3], axis=0), axis=1).sum()
    for col, m in enumerate(("paper", "robust")):
        T = read_poses(tmp_path / f"t_{m}.txt")
        e = np.linalg.norm(T[1:, :3, 3] - T_true[1:, :3, 3], axis=1)
        R_err = np.einsum("nji,njk->nik", T_true[1:, :3, :3], nearest_rotation(T[1:, :3, :3]))
        rot = np.degrees(np.arccos(np.clip((np.trace(R_err, axis1=1, axis2=2) - 1) / 2, -1, 1)))
        assert _value(text, "true path length (m)")[col] == pytest.approx(path_m, abs=6e-4)
        assert _value(text, "mean translation error (m)")[col] == pytest.approx(e.mean(), abs=6e-5)
        assert _value(text, "final translation error (m)")[col] == pytest.approx(e[-1], abs=6e-5)
        assert _value(text, "drift: final error / path (%)")[col] == pytest.approx(100 * e[-1] / path_m, abs=6e-3)
        assert _value(text, "mean rotation error (deg)")[col] == pytest.approx(rot.mean(), abs=6e-4)
        assert _value(text, "final rotation error (deg)")[col] == pytest.approx(rot[-1], abs=6e-4)
    assert _value(text, "final translation error (m)")[1] < 0.03          # the robust variant
    assert "segments: " in text and "m (10-80 % of the path" in text


def test_a_single_image_has_no_errors_to_print(seq_dir, tmp_path):
    d = tmp_path / "one"
    for side in ("left", "right"):
        (d / side).mkdir(parents=True)
        (d / side / "000000.png").write_bytes((seq_dir / side / "000000.png").read_bytes())
    (d / "stereo.json").write_text((seq_dir / "stereo.json").read_text())
    (d / "poses.txt").write_text((seq_dir / "poses.txt").read_text().splitlines()[0] + "\n")
    out = io.StringIO()
    with redirect_stdout(out):
        rc = cli.main(["odometry", str(d), "--quiet", "--method", "robust"])
    text = out.getvalue()
    assert rc == 0
    assert _value(text, "steps compared") == [0] and _value(text, "segments compared") == [0]
    assert "mean translation error (m)             -" in text
    assert "segments: none (too few images along the path)" in text
