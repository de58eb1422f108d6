"""Odometry end to end on a small rendered sequence: both layouts, the command, bad input."""

import json
import shutil

import cv2
import numpy as np
import pytest

from simulators.odometry_scene import Rig, path, write_sequence
from station import cli
from station.errors import OdometryError
from station.odometry.pipeline import run_odometry
from station.odometry.poses_io import read_poses
from station.odometry.sequence_io import open_sequence
from station.odometry.trajectory import summarize

SMALL_RIG = Rig(width=360, height=240, f_px=240.0)
N_IMAGES = 4


@pytest.fixture(scope="module")
def small_seq(tmp_path_factory):
    d = tmp_path_factory.mktemp("odo") / "seq"
    write_sequence(d, "short", seed=0, rig=SMALL_RIG, poses_xy_yaw=path("short")[:N_IMAGES])
    return d


@pytest.fixture
def seq_copy(small_seq, tmp_path):
    d = tmp_path / "seq"
    shutil.copytree(small_seq, d)
    return d


def test_written_format(small_seq):
    meta = json.loads((small_seq / "sequence.json").read_text())
    assert meta["n_images"] == N_IMAGES and meta["image_size"] == [360, 240]
    img = cv2.imread(str(small_seq / "left" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (240, 360) and img.dtype == np.uint8 and img.std() > 20
    T = read_poses(small_seq / "poses.txt")
    np.testing.assert_allclose(T[0], np.eye(4), atol=1e-12)
    # 0.4 m per step along the floor; the camera is pitched down, so it moves in y and z
    assert np.linalg.norm(T[1, :3, 3]) == pytest.approx(0.4, abs=1e-9)


def test_robust_beats_paper_and_meets_target(small_seq):
    seq = open_sequence(small_seq)
    runs = run_odometry(seq, ("paper", "robust"))
    B_true = seq.truth[:, :3, 3]
    assert all(r.error is None for r in runs.values())
    s_rob = summarize(runs["robust"].trajectory.positions, B_true)
    s_pap = summarize(runs["paper"].trajectory.positions, B_true)
    assert s_rob.n_steps == N_IMAGES - 1
    assert s_rob.mean_m < 0.02
    assert s_pap.mean_m > 2 * s_rob.mean_m


def test_kitti_layout_reads_the_same(small_seq, tmp_path):
    d = tmp_path / "kitti"
    shutil.copytree(small_seq / "left", d / "image_0")
    shutil.copytree(small_seq / "right", d / "image_1")
    shutil.copy(small_seq / "poses.txt", d / "poses.txt")
    K = SMALL_RIG.K()
    P0 = np.hstack([K, np.zeros((3, 1))])
    P1 = np.hstack([K, (K @ np.array([-SMALL_RIG.baseline_m, 0, 0]))[:, None]])
    (d / "calib.txt").write_text("".join(f"{n}: " + " ".join(f"{v:.12e}" for v in P.ravel()) + "\n"
                                         for n, P in (("P0", P0), ("P1", P1), ("P2", P0))))
    kitti = open_sequence(d)
    ours = open_sequence(small_seq)
    assert kitti.layout == "kitti" and len(kitti) == N_IMAGES
    np.testing.assert_allclose(kitti.right.t_cam_station, ours.right.t_cam_station, atol=1e-12)
    np.testing.assert_allclose(kitti.left.K, ours.left.K, atol=1e-9)
    runs = run_odometry(kitti, ("robust",), max_steps=1)
    assert len(runs["robust"].trajectory) == 2


def test_command_writes_trajectory_and_recording(small_seq, tmp_path, capsys):
    out = tmp_path / "traj.txt"
    rrd = tmp_path / "run.rrd"
    rc = cli.main(["odometry", str(small_seq), "--method", "robust", "--out", str(out),
                   "--rerun", str(rrd)])
    text = capsys.readouterr().out
    assert rc == 0
    assert "errors against the truth" in text and "drift: final error / path (%)" in text
    T = read_poses(out)
    assert T.shape == (N_IMAGES, 4, 4)
    truth = read_poses(small_seq / "poses.txt")
    assert np.linalg.norm(T[-1, :3, 3] - truth[-1, :3, 3]) < 0.03
    assert not rrd.with_name(rrd.name + ".part").exists()
    import rerun as rr
    paths = {ch.entity_path for ch in rr.chunk.RrdReader(str(rrd)).stream()}
    assert {"/world/truth/path", "/world/robust/path", "/world/robust/camera",
            "/world/robust/points", "/error/robust"} <= paths


def _expect_failure(d, capsys, tmp_path, step_text):
    out = tmp_path / "partial.txt"
    rc = cli.main(["odometry", str(d), "--method", "robust", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == cli.EXIT_ERROR
    assert "error 700 (odometry)" in err and step_text in err and "Traceback" not in err
    return out, err


def test_blank_frame_names_the_step_and_keeps_the_trajectory(seq_copy, capsys, tmp_path):
    cv2.imwrite(str(seq_copy / "right" / "000002.png"), np.full((240, 360), 128, np.uint8))
    out, err = _expect_failure(seq_copy, capsys, tmp_path, "step 2")
    assert "blank" in err
    assert read_poses(out).shape[0] == 2          # images 0 and 1: one good step kept


def test_repeated_frame_is_refused(seq_copy, capsys, tmp_path):
    shutil.copy(seq_copy / "right" / "000001.png", seq_copy / "right" / "000002.png")
    out, err = _expect_failure(seq_copy, capsys, tmp_path, "step 2")
    assert "right image 2 repeats image 1" in err
    assert read_poses(out).shape[0] == 2


def test_mismatched_sizes_are_refused(seq_copy, capsys, tmp_path):
    img = cv2.imread(str(seq_copy / "right" / "000001.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(seq_copy / "right" / "000001.png"), img[:, :300])
    out, err = _expect_failure(seq_copy, capsys, tmp_path, "step 1")
    assert "300x240" in err and "360x240" in err
    assert read_poses(out).shape[0] == 1


def test_too_few_keypoints_names_the_step(seq_copy, capsys, tmp_path):
    # a smooth gradient is not blank but has (almost) no SIFT keypoints
    grad = np.tile(np.linspace(40, 200, 360), (240, 1)).astype(np.uint8)
    for side in ("left", "right"):
        cv2.imwrite(str(seq_copy / side / "000003.png"), grad)
    out, err = _expect_failure(seq_copy, capsys, tmp_path, "step 3")
    assert "keypoints" in err
    assert read_poses(out).shape[0] == 3


def test_missing_calibration_and_folders(seq_copy, tmp_path):
    (seq_copy / "stereo.json").unlink()
    with pytest.raises(OdometryError, match="missing calibration"):
        open_sequence(seq_copy)
    with pytest.raises(OdometryError, match="has folders seq/: expected image_0/ image_1/"):
        open_sequence(tmp_path)
    (seq_copy / "right" / "000003.png").unlink()
    shutil.copy(seq_copy / "left" / "000003.png", seq_copy / "left" / "000009.png")
    with pytest.raises(OdometryError, match="do not pair up"):
        open_sequence(seq_copy)


def test_the_sequence_renderer_refuses_a_non_empty_folder(small_seq, capsys):
    from simulators.odometry_scene import main

    rc = main([str(small_seq), "--kind", "short"])
    assert rc == 2
    assert "not a new or empty folder" in capsys.readouterr().err


def test_unwritable_output_is_a_clear_error(small_seq, tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    rc = cli.main(["odometry", str(small_seq), "--method", "robust", "--max-steps", "1",
                   "--out", str(blocker / "traj.txt"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == cli.EXIT_ERROR
    assert "cannot write the trajectory" in err and "Traceback" not in err


def test_lens_distortion_is_undone(tmp_path):
    rig = Rig(width=360, height=240, f_px=240.0, dist=(-0.12, 0.03, 5e-4, -3e-4, 0.0))
    d = write_sequence(tmp_path / "dist", "short", seed=0, rig=rig, poses_xy_yaw=path("short")[:N_IMAGES])
    seq = open_sequence(d)
    assert np.allclose(seq.left.dist, rig.dist)
    good = summarize(run_odometry(seq, ("robust",))["robust"].trajectory.positions, seq.truth[:, :3, 3])
    assert good.mean_m < 0.01
    spec = json.loads((d / "stereo.json").read_text())
    for side in ("left", "right"):
        spec[side]["dist"] = [0.0] * 5             # pretend the lens were a pinhole
    (d / "stereo.json").write_text(json.dumps(spec))
    seq = open_sequence(d)
    bad = summarize(run_odometry(seq, ("robust",))["robust"].trajectory.positions, seq.truth[:, :3, 3])
    assert bad.mean_m > 1.5 * good.mean_m
