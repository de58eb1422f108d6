"""`station odometry DIR` on KITTI's layout and its common variants without renaming anything:
one rendered sequence rearranged into each layout gives the same trajectory; a layout that
cannot be read is a sentence saying what was found and what to rename, never a traceback."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from simulators.odometry_scene import Rig, path, write_sequence
from station import cli
from station.errors import OdometryError
from station.odometry.calib_txt import decompose
from station.odometry.image_folders import natural_key
from station.odometry.poses_io import read_poses, write_poses
from station.odometry.sequence_io import open_sequence

SMALL_RIG = Rig(width=360, height=240, f_px=240.0)
N_IMAGES = 4
FIRST_NUMBER = 8            # files frame_8 .. frame_11: a plain text sort would put 10, 11 first
P0_FROM_LEFT_M = 0.06       # colour KITTI: P0's camera 6 cm right of the left (P2) camera


def _P(t_left_cam: np.ndarray) -> np.ndarray:
    """Rectified projection matrix K [I | t] of a camera with x_cam = x_left + t."""
    K = SMALL_RIG.K()
    return np.hstack([K, (K @ t_left_cam)[:, None]])


P_LEFT = _P(np.zeros(3))
P_RIGHT = _P(np.array([-SMALL_RIG.baseline_m, 0.0, 0.0]))


def _matrix(P: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in P.ravel())


@pytest.fixture(scope="module")
def station_seq(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("layouts") / "station"
    # from the third pose: a straight step, then a 45 deg turn (the truth moves between cameras)
    write_sequence(d, "short", seed=0, rig=SMALL_RIG, poses_xy_yaw=path("short")[2:2 + N_IMAGES])
    return d


def _copy_images(src: Path, d: Path, left: str, right: str, name=lambda i: f"{i:06d}.png") -> None:
    for side, folder in (("left", left), ("right", right)):
        (d / folder).mkdir(parents=True)
        for i in range(N_IMAGES):
            shutil.copy(src / side / f"{i:06d}.png", d / folder / name(i))


def make_image_lr(src: Path, d: Path) -> Path:
    """image_l/ image_r/, files frame_8.png ..., calib.txt with two unlabelled lines, the
    poses outside the folder."""
    _copy_images(src, d, "image_l", "image_r", lambda i: f"frame_{FIRST_NUMBER + i}.png")
    (d / "calib.txt").write_text(f"{_matrix(P_LEFT)}\n{_matrix(P_RIGHT)}\n")
    shutil.copy(src / "poses.txt", d.parent / "truth_poses.txt")
    return d


def make_kitti(src: Path, d: Path) -> Path:
    """KITTI odometry: image_0/ image_1/, labelled P0..P3 and Tr, times.txt; poses in poses/00.txt."""
    _copy_images(src, d, "image_0", "image_1")
    lines = [f"{n}: {_matrix(P)}" for n, P in (("P0", P_LEFT), ("P1", P_RIGHT), ("P2", P_LEFT), ("P3", P_RIGHT))]
    lines.append("Tr: " + " ".join(["0.0"] * 12))
    (d / "calib.txt").write_text("\n".join(lines) + "\n")
    (d / "times.txt").write_text("".join(f"{0.1 * i:.6e}\n" for i in range(N_IMAGES)))
    (d.parent / "poses").mkdir(exist_ok=True)
    shutil.copy(src / "poses.txt", d.parent / "poses" / "00.txt")
    return d


def make_left_right_calib(src: Path, d: Path) -> Path:
    """left/ right/ with a labelled calib.txt instead of stereo.json."""
    _copy_images(src, d, "left", "right")
    (d / "calib.txt").write_text(f"P0: {_matrix(P_LEFT)}\nP1: {_matrix(P_RIGHT)}\n")
    shutil.copy(src / "poses.txt", d / "poses.txt")
    return d


def make_kitti_colour(src: Path, d: Path) -> Path:
    """KITTI raw colour: image_02/data/ image_03/data/, P_rect_00 .. P_rect_03 where P0's camera
    is not the left one; poses.txt describes P0's camera, as KITTI's do."""
    _copy_images(src, d, "image_02/data", "image_03/data")
    off = np.array([P0_FROM_LEFT_M, 0.0, 0.0])   # x_P0 = x_left - off: P0 is 6 cm to the right
    mats = (("P_rect_00", _P(-off)), ("P_rect_01", _P(-off - [SMALL_RIG.baseline_m, 0, 0])),
            ("P_rect_02", P_LEFT), ("P_rect_03", P_RIGHT))
    (d / "calib.txt").write_text("calib_time: 09-Jan-2012 13:57:47\n"
                                 + "".join(f"{n}: {_matrix(P)}\n" for n, P in mats))
    X = np.eye(4)
    X[:3, 3] = -off                                # left coordinates -> P0's
    T_left = read_poses(src / "poses.txt")
    write_poses(d / "poses.txt", X @ T_left @ np.linalg.inv(X))
    return d


LAYOUTS = {"image_l": make_image_lr, "kitti": make_kitti, "left_right_calib": make_left_right_calib,
           "kitti_colour": make_kitti_colour}
TRUTH_OUTSIDE = {"image_l": "truth_poses.txt", "kitti": "poses/00.txt"}   # else DIR/poses.txt


def _truth_args(layout: str, d: Path) -> tuple[str, ...]:
    return ("--truth", str(d.parent / TRUTH_OUTSIDE[layout])) if layout in TRUTH_OUTSIDE else ()


def _run(d: Path, out: Path, *extra: str) -> tuple[int, str, str]:
    import io
    from contextlib import redirect_stderr, redirect_stdout

    o, e = io.StringIO(), io.StringIO()
    with redirect_stdout(o), redirect_stderr(e):
        rc = cli.main(["odometry", str(d), "--quiet", "--out", str(out), *extra])
    return rc, o.getvalue(), e.getvalue()


def test_natural_order():
    names = ["10.png", "000000.png", "2.png", "1.png", "frame_11.png", "frame_9.png", "B1.png", "a2.png"]
    assert sorted(names, key=natural_key) == ["000000.png", "1.png", "2.png", "10.png", "a2.png",
                                              "B1.png", "frame_9.png", "frame_11.png"]


def test_projection_matrix_decomposition_recovers_K_R_t():
    K = np.array([[700.0, 0, 600], [0, 710, 180], [0, 0, 1]])
    a = np.array([0.1, -0.3, 0.2])
    th = np.linalg.norm(a)
    k = a / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx
    t = np.array([-0.54, 0.02, 0.3])
    for scale in (1.0, -2.5):                      # a projection matrix is known up to scale
        K2, R2, t2 = decompose(scale * K @ np.hstack([R, t[:, None]]), "P")
        np.testing.assert_allclose(K2, K, atol=1e-9)
        np.testing.assert_allclose(R2, R, atol=1e-12)
        np.testing.assert_allclose(t2, t, atol=1e-12)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_every_layout_reads_the_same_sequence(station_seq, tmp_path, layout):
    d = LAYOUTS[layout](station_seq, tmp_path / "seq")
    seq = open_sequence(d, *_truth_args(layout, d)[1:])
    ours = open_sequence(station_seq)
    assert seq.layout == "kitti" and len(seq) == N_IMAGES
    np.testing.assert_allclose(seq.left.K, ours.left.K, atol=1e-9)
    np.testing.assert_allclose(seq.right.R_cam_station, ours.right.R_cam_station, atol=1e-12)
    np.testing.assert_allclose(seq.right.t_cam_station, ours.right.t_cam_station, atol=1e-12)
    np.testing.assert_allclose(seq.truth, ours.truth, atol=1e-9)    # the left camera's, always
    assert [p.read_bytes() for p in seq.left_files] == [p.read_bytes() for p in ours.left_files]


def test_sources_are_named(station_seq, tmp_path):
    seq = open_sequence(make_image_lr(station_seq, tmp_path / "a"))
    assert seq.source == "image_l/ image_r/ + calib.txt lines 1 and 2 (unlabelled)"
    assert [p.name for p in seq.left_files] == ["frame_8.png", "frame_9.png", "frame_10.png", "frame_11.png"]
    seq = open_sequence(make_kitti(station_seq, tmp_path / "b"))
    assert seq.source == "image_0/ image_1/ + calib.txt P0/P1" and seq.truth is None
    np.testing.assert_allclose(seq.times_s, [0, 0.1, 0.2, 0.3])
    seq = open_sequence(make_kitti_colour(station_seq, tmp_path / "c"))
    assert seq.source == "image_02/ image_03/ + calib.txt P2/P3"
    assert any("moved to the left camera, 0.060 m" in n for n in seq.notes)


def test_the_command_gives_the_same_trajectory_in_every_layout(station_seq, tmp_path):
    rc, text, err = _run(station_seq, tmp_path / "station.txt")
    assert rc == 0, err
    expected = {m: read_poses(tmp_path / f"station_{m}.txt") for m in ("paper", "robust")}
    truth = read_poses(station_seq / "poses.txt")
    assert np.linalg.norm(expected["robust"][-1, :3, 3] - truth[-1, :3, 3]) < 0.03
    for layout, make in LAYOUTS.items():
        d = make(station_seq, tmp_path / layout / "seq")
        rc, text, err = _run(d, tmp_path / f"{layout}.txt", *_truth_args(layout, d))
        assert rc == 0, (layout, err)
        assert "errors against the truth" in text, layout
        for m in ("paper", "robust"):
            np.testing.assert_allclose(read_poses(tmp_path / f"{layout}_{m}.txt"), expected[m],
                                       atol=1e-9, err_msg=f"{layout} {m}")


# --- layouts that cannot be read -------------------------------------------------------------
def _fails(d: Path, tmp_path: Path, *extra: str) -> str:
    rc, _, err = _run(d, tmp_path / "out.txt", *extra)
    assert rc == cli.EXIT_ERROR
    assert err.startswith("error 700 (odometry)") and "Traceback" not in err
    return err


def test_unknown_folders_say_what_to_rename(station_seq, tmp_path):
    d = tmp_path / "seq"
    _copy_images(station_seq, d, "cam_a", "cam_b")
    shutil.copy(station_seq / "stereo.json", d)
    err = _fails(d, tmp_path)
    assert (f"{d} has folders cam_a/ cam_b/: expected image_0/ image_1/, image_l/ image_r/ or "
            "left/ right/") in err
    assert "what to do: rename cam_a/ to left/ and cam_b/ to right/" in err


def test_one_folder_of_a_pair(station_seq, tmp_path):
    d = make_image_lr(station_seq, tmp_path / "seq")
    shutil.rmtree(d / "image_r")
    assert f"{d} has image_l/ but no image_r/" in _fails(d, tmp_path)


def test_empty_folder_and_no_folders(tmp_path):
    (tmp_path / "seq" / "left").mkdir(parents=True)
    (tmp_path / "seq" / "right").mkdir()
    assert "seq/left: no images" in _fails(tmp_path / "seq", tmp_path)
    (tmp_path / "flat").mkdir()
    (tmp_path / "flat" / "0.png").write_bytes(b"")
    assert "flat has no folders (1 image directly in it): expected" in _fails(tmp_path / "flat", tmp_path)


def test_image_counts_that_differ(station_seq, tmp_path):
    d = make_image_lr(station_seq, tmp_path / "seq")
    (d / "image_r" / "frame_11.png").unlink()
    err = _fails(d, tmp_path)
    assert "image_l/ has 4 images, image_r/ has 3 (unpaired: frame_11.png)" in err


def test_files_named_differently_pair_by_number(station_seq, tmp_path):
    d = tmp_path / "seq"
    _copy_images(station_seq, d, "left", "right")
    for p in (d / "right").iterdir():
        p.rename(p.with_name(f"R_{int(p.stem)}.png"))
    shutil.copy(station_seq / "stereo.json", d)
    assert len(open_sequence(d)) == N_IMAGES
    (d / "right" / "R_3.png").rename(d / "right" / "R_7.png")
    with pytest.raises(OdometryError, match=r"4 images each \(unpaired: 000003.png, R_7.png\)"):
        open_sequence(d)


def test_unreadable_images(station_seq, tmp_path):
    d = make_image_lr(station_seq, tmp_path / "seq")
    good = (d / "image_r" / "frame_10.png").read_bytes()
    (d / "image_r" / "frame_10.png").write_bytes(good[: len(good) // 2])
    err = _fails(d, tmp_path, "--method", "robust")
    assert "step 2" in err and "the right image" in err and "frame_10.png cannot be read: not a readable image" in err
    (d / "image_l" / "frame_8.png").write_bytes(b"")      # the first image: found on opening
    err = _fails(d, tmp_path)
    assert "frame_8.png cannot be read: an empty file" in err


@pytest.mark.parametrize("calib, message", [
    ("1 2 3\n", "calib.txt line 1: 3 numbers, expected 12 (a 3x4 projection matrix, row-major)"),
    (f"{_matrix(P_LEFT)}\n{_matrix(P_RIGHT)} 7\n", "calib.txt line 2: 13 numbers, expected 12"),
    (f"{_matrix(P_LEFT)}\n", "calib.txt: 1 projection matrix line(s), need two (left, then right)"),
    (f"P0: {_matrix(P_LEFT)}\nP1: {_matrix(P_RIGHT)[:-4]}\n", "calib.txt line 2 (P1): 11 numbers, expected 12"),
    (f"P0: {_matrix(P_LEFT)}\nP2: {_matrix(P_RIGHT)}\n",
     "calib.txt: has P0, P2 but no P1: image_l/ image_r/ need P0 (left) and P1 (right)"),
    (f"{_matrix(P_LEFT)}\n{_matrix(P_LEFT).replace('240.0', 'x', 1)}\n", "calib.txt line 2: not 12 numbers (x 0.0"),
    (f"{_matrix(P_LEFT)}\n{_matrix(P_LEFT)}\n", "are the same camera (no baseline)"),
    (f"{_matrix(np.zeros((3, 4)))}\n{_matrix(P_RIGHT)}\n", "line 1: not a projection matrix"),
])
def test_broken_calibration(station_seq, tmp_path, calib, message):
    d = make_image_lr(station_seq, tmp_path / "seq")
    (d / "calib.txt").write_text(calib)
    assert message in _fails(d, tmp_path)


@pytest.mark.parametrize("poses, message", [
    ("drop", "poses.txt: 3 poses for 4 images: the truth needs one line per image"),
    ("short_row", "poses.txt line 2: 11 numbers, expected 12"),
    ("word", "poses.txt line 3: 'nan?' is not a number"),
    ("not_rotation", "poses.txt line 4: the first 3 columns are not a rotation"),
    ("missing", "cannot read the poses (No such file or directory)"),
])
def test_broken_truth(station_seq, tmp_path, poses, message):
    d = make_image_lr(station_seq, tmp_path / "seq")
    f = tmp_path / "poses.txt"
    lines = (station_seq / "poses.txt").read_text().splitlines()
    if poses == "drop":
        lines = lines[:-1]
    elif poses == "short_row":
        lines[1] = " ".join(lines[1].split()[:11])
    elif poses == "word":
        lines[2] = " ".join(["nan?"] + lines[2].split()[1:])
    elif poses == "not_rotation":
        lines[3] = " ".join(["2.0"] + lines[3].split()[1:])
    if poses != "missing":
        f.write_text("\n".join(lines) + "\n")
    assert message in _fails(d, tmp_path, "--truth", str(f))


def test_poses_alias_and_longer_truth(station_seq, tmp_path):
    d = make_image_lr(station_seq, tmp_path / "seq")
    f = tmp_path / "poses.txt"
    f.write_text((station_seq / "poses.txt").read_text() * 2)
    rc, text, err = _run(d, tmp_path / "o.txt", "--poses", str(f), "--method", "robust", "--max-steps", "1")
    assert rc == 0, err
    assert "note: poses.txt: 8 poses for 4 images; the first 4 are used" in text
    assert f"errors against the truth ({f})" in text
