"""Rerun recordings: read back with Rerun's own reader and check what is inside; write faults."""

import json
import shutil
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from calibration.camera_model import CameraModel, look_at
from calibration.station_frame import WHEELS
from result_builder import make_result
from station.errors import StorageError
from station.records.recording import CycleRecorder, read_recording_summary

TESTS = Path(__file__).resolve().parent
CAM_WHEEL = {"cam1": "FR", "cam2": "FR", "cam3": "FL", "cam4": "FL",
             "cam5": "RL", "cam6": "RL", "cam7": "RR", "cam8": "RR"}


def station_cameras() -> dict[str, CameraModel]:
    cams = {}
    for i, (cam_id, wheel) in enumerate(CAM_WHEEL.items()):
        sx = 1 if wheel in ("FR", "RR") else -1
        sy = 1 if wheel[0] == "F" else -1
        pos = np.array([sx * 2.08, sy * (1.35 if i % 2 == 0 else 0.75), 0.33])
        R, t = look_at(pos, np.array([sx * 0.78, sy * 1.35, 0.33]))
        K = np.array([[1800.0 + i, 0, 640], [0, 1800.0 + i, 512], [0, 0, 1]])
        cams[cam_id] = CameraModel(cam_id, 1280, 1024, K, R_cam_station=R, t_cam_station=t)
    return cams


def images(seed=0, shape=(1024, 1280)):
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    out = {}
    for k, cam_id in enumerate(CAM_WHEEL):
        img = 90 + 60 * np.sin(u / 97.0 + k) * np.cos(v / 131.0)
        img += rng.normal(0, 2, shape)
        out[cam_id] = np.clip(img, 0, 255).astype(np.uint8)
    return out


def record_cycle(path, result, *, image_shape=(1024, 1280), **kw):
    rng = np.random.default_rng(1)
    with CycleRecorder(path, **kw) as rec:
        rec.log_event("cycle start")
        rec.log_cameras(station_cameras())
        rec.log_images(images(shape=image_shape))
        t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
        for cam_id in CAM_WHEEL:
            ell = np.c_[640 + 300 * np.cos(t), 512 + 280 * np.sin(t)]
            rec.log_detection(cam_id, ell, ell[::2] + rng.normal(0, 0.3, (100, 2)))
        for w in WHEELS:
            d = result.wheels[w]
            c, ax = np.array(d.center_station_m), np.array(d.axis_station)
            rim = c + 0.2159 * np.c_[np.zeros(50), np.cos(t[:50]), np.sin(t[:50])]
            rec.log_wheel(w, rim, c, ax, d.rim_radius_m)
        rec.log_car_frame([0, 0, 0.33], np.eye(3))
        rec.log_result(result)
        for w in result.warnings:  # as a cycle's own events: not repeated in the log
            rec.log_event(w, level="WARN")
        rec.log_event("cycle done", level="INFO")
    return rec


def column(path, entity, name):
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        if str(chunk.entity_path) == entity:
            batch = chunk.to_record_batch()
            if name in batch.schema.names:
                return batch.column(batch.schema.names.index(name)).to_pylist()
    raise KeyError(f"{entity} {name}")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec")
    result = make_result(11, cycle=7, verdicts={"overall": False, "FL.toe": False}, warnings=["pair FR drift?"])
    path = d / f"{result.cycle_id}.rrd"
    rec = record_cycle(path, result, recording_id="job-42")
    return path, result, rec


def test_entities_images_and_scalars(recorded):
    path, result, rec = recorded
    s = read_recording_summary(path)
    assert s["recording_id"] == "job-42" and s["application_id"] == "station"
    ents = s["entities"]
    for cam_id in CAM_WHEEL:
        for sub in ("", "/image", "/image/ellipse", "/image/edges"):
            assert f"/station/{cam_id}{sub}" in ents
    for w in WHEELS:
        for sub in ("rim", "center", "axis", "plane"):
            assert f"/vehicle/{w}/{sub}" in ents
    assert "/vehicle/car_frame" in ents and "/result" in ents
    assert s["images"] == 8
    assert {"cycle", "time"} <= set(s["timelines"])
    assert s["scalars"]["FL.toe"] == [pytest.approx(result.wheels["FL"].toe_deg)]
    assert s["scalars"]["RR.camber"] == [pytest.approx(result.wheels["RR"].camber_deg)]
    assert s["scalars"]["thrust"] == [pytest.approx(result.thrust_deg)]
    assert s["scalars"]["front.total_toe"] == [pytest.approx(result.axles["front"].total_toe_deg)]
    texts = [t for _, t in s["events"]]
    assert texts[0] == "cycle start" and texts[-1] == "cycle done"
    assert "FAIL: FL.toe" in texts and texts.count("pair FR drift?") == 1
    assert rec.bytes_written == path.stat().st_size
    assert not list(path.parent.glob(".*part"))  # no temp file left


def test_cycle_timeline_and_poses(recorded):
    path, result, _ = recorded
    assert column(path, "/angles/FL.toe", "cycle") == [7]  # the counter ending the cycle id
    cams = station_cameras()
    trans = column(path, "/station/cam3", "Transform3D:translation")[0][0]
    assert np.allclose(trans, cams["cam3"].center_station, atol=1e-6)
    mat = np.array(column(path, "/station/cam3", "Transform3D:mat3x3")[0][0]).reshape(3, 3)
    # Rerun stores 3x3 matrices column-major; the transform maps camera axes into the station
    # (child to parent), so it must be R_cam_station.T
    R = cams["cam3"].R_cam_station
    assert np.allclose(mat.T, R.T, atol=1e-6)
    K = np.array(column(path, "/station/cam3", "Pinhole:image_from_camera")[0][0]).reshape(3, 3).T
    assert K[0, 0] == pytest.approx(1802.0) and K[0, 2] == pytest.approx(640.0) and K[2, 2] == 1.0
    doc = column(path, "/result", "TextDocument:text")[0][0]
    assert json.loads(doc)["cycle_id"] == result.cycle_id


def test_rerun_cli_verifies_the_file(recorded):
    path, _, _ = recorded
    exe = Path(sys.executable).with_name("rerun")
    if not exe.exists():
        pytest.skip("the rerun CLI is not in this environment")
    out = subprocess.run([str(exe), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr


def test_images_round_trip(recorded, tmp_path):
    import cv2
    path, _, _ = recorded
    blob = column(path, "/station/cam5/image", "EncodedImage:blob")[0][0]
    assert column(path, "/station/cam5/image", "EncodedImage:media_type")[0][0] == "image/jpeg"
    back = cv2.imdecode(np.frombuffer(bytes(blob), np.uint8), cv2.IMREAD_UNCHANGED)
    original = images()["cam5"]
    assert back.shape == original.shape
    assert np.abs(back.astype(int) - original).mean() < 2.0  # JPEG q90 of a smooth noisy frame
    # colour frames keep their channel order (RGB in, RGB out), 16-bit frames keep their top byte
    rgb = np.zeros((64, 64, 3), np.uint8)
    rgb[..., 0] = 200
    mono16 = np.full((64, 64), 40000, np.uint16)
    with CycleRecorder(tmp_path / "c.rrd") as rec:
        rec.log_images({"camR": rgb, "camW": mono16})
    b = cv2.imdecode(np.frombuffer(bytes(column(tmp_path / "c.rrd", "/station/camR/image", "EncodedImage:blob")[0][0]),
                                   np.uint8), cv2.IMREAD_COLOR)  # BGR
    assert b[..., 2].mean() > 190 and b[..., 0].mean() < 10
    w = cv2.imdecode(np.frombuffer(bytes(column(tmp_path / "c.rrd", "/station/camW/image", "EncodedImage:blob")[0][0]),
                                   np.uint8), cv2.IMREAD_UNCHANGED)
    assert abs(w.mean() - (40000 >> 8)) < 2


def test_job_recording_ids_are_stable():
    from station.records.recording import recording_id_for
    assert recording_id_for("VIN 1") == recording_id_for("VIN 1") != recording_id_for("VIN 2")
    assert recording_id_for(None) is None


def test_invalid_cycle_logs_failure_not_angles(tmp_path):
    r = make_result(0, cycle=3, valid=False)
    path = tmp_path / "c.rrd"
    with CycleRecorder(path) as rec:
        rec.log_result(r)
    s = read_recording_summary(path)
    assert s["scalars"] == {}
    assert any(lv == "ERROR" and "no closed rim contour" in t for lv, t in s["events"])


def test_failed_cycle_keeps_its_recording(tmp_path):
    path = tmp_path / "c.rrd"
    with pytest.raises(RuntimeError):
        with CycleRecorder(path) as rec:
            rec.log_event("capturing")
            raise RuntimeError("camera fell off")
    assert read_recording_summary(path)["events"] == [("INFO", "capturing")]


def test_bad_shapes_are_refused(tmp_path):
    rec = CycleRecorder(tmp_path / "c.rrd")
    with pytest.raises(ValueError, match=r"\(N,2\)"):
        rec.log_detection("cam1", np.zeros((5, 3)), np.zeros((5, 2)))
    with pytest.raises(ValueError, match="3-vector"):
        rec.log_wheel("FL", np.zeros((5, 3)), [0, 0], [1, 0, 0], 0.2)
    rec.abort()
    assert list(tmp_path.iterdir()) == []


def test_missing_and_truncated_recordings(tmp_path, recorded):
    with pytest.raises(StorageError, match="no such recording"):
        read_recording_summary(tmp_path / "nope.rrd")
    src, _, _ = recorded
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    with pytest.raises(StorageError, match="not a readable Rerun recording"):
        read_recording_summary(cut)


def test_unwritable_folder_in_process(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    rec = CycleRecorder(blocker / "recordings" / "c.rrd")  # the folder cannot be made
    rec.log_images({"cam1": np.zeros((64, 64), np.uint8)})  # never raises mid-cycle
    assert not rec.ok
    with pytest.raises(StorageError, match="the measurement is kept") as e:
        rec.close()
    assert e.value.code == 600
    assert rec.close() is None  # raised once


FAULT = textwrap.dedent("""
    import json, os, sys
    sys.path.insert(0, {tests!r})
    from result_builder import make_result
    from test_recording import record_cycle
    from station.errors import StorageError
    d = sys.argv[1]
    result = make_result(0, cycle=1)
    out = {{"result_kept": False}}
    try:
        record_cycle(os.path.join(d, "recordings", "c-0001.rrd"), result)
        out["error"] = None
    except StorageError as e:
        out["error"] = str(e)
    out["result_kept"] = result.wheels["FL"].toe_deg is not None
    out["left"] = sorted(os.path.relpath(os.path.join(r, f), d) for r, _, fs in os.walk(d) for f in fs)
    print(json.dumps(out))
""")


def _in_mount_ns(tmp_path, setup: str) -> dict:
    if shutil.which("unshare") is None:
        pytest.skip("unshare is not installed")
    script = tmp_path / "fault.py"
    script.write_text(FAULT.format(tests=str(TESTS)))
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    cmd = f"{setup.format(mnt=mnt)} && {sys.executable} {script} {mnt}"
    p = subprocess.run(["unshare", "-m", "sh", "-c", cmd], capture_output=True, text=True, timeout=120)
    if p.returncode != 0 and ("mount" in p.stderr or "unshare" in p.stderr):
        pytest.skip(f"cannot make a private mount here: {p.stderr.strip()[:200]}")
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_full_disk_leaves_no_file_and_keeps_the_result(tmp_path):
    # a real 1 MB filesystem: eight JPEG frames do not fit
    out = _in_mount_ns(tmp_path, "mount -t tmpfs -o size=1m tmpfs {mnt} && mkdir {mnt}/recordings")
    assert out["result_kept"]
    assert out["error"] and "No space left on device" in out["error"] and "measurement is kept" in out["error"]
    assert out["left"] == []


def test_read_only_folder_leaves_no_file_and_keeps_the_result(tmp_path):
    out = _in_mount_ns(tmp_path, "mount -t tmpfs -o size=8m tmpfs {mnt} && mkdir {mnt}/recordings "
                                 "&& mount -o remount,ro {mnt}")
    assert out["result_kept"]
    assert out["error"] and "Read-only file system" in out["error"]
    assert out["left"] == []


# --- the `station review` command -----------------------------------------------------------------
def test_review_without_display_prints_contents_and_how(tmp_path, monkeypatch, capsys, recorded):
    from station.cli import main
    from station.records.history import History
    src, result, _ = recorded
    rec_dir = tmp_path / "recordings"
    rec_dir.mkdir()
    path = rec_dir / src.name
    path.write_bytes(src.read_bytes())
    with History(tmp_path / "history.sqlite") as h:
        h.store(replace(result, recording=str(path)))
    monkeypatch.setenv("STATION_DATA_DIR", str(tmp_path))
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["review", result.cycle_id]) == 0
    out = capsys.readouterr().out
    assert "8 image(s)" in out and "no display here" in out and f"rerun {path}" in out
    assert f"{result.wheels['FL'].toe_deg:+.3f}" in out
    assert main(["review"]) == 0  # the newest recording
    assert str(path) in capsys.readouterr().out
    assert main(["review", "--job", result.job_id, "--summary"]) == 0
    assert "no display" not in capsys.readouterr().out
    assert main(["review", "no-such-cycle"]) == 2
    assert "no recording found" in capsys.readouterr().err


# --- streaming to a viewer ------------------------------------------------------------------------
def test_streams_to_a_running_viewer_too(tmp_path):
    import signal
    import socket
    import time
    rerun_cli = pytest.importorskip("rerun_cli", reason="the rerun CLI is not in this environment")
    # the CLI's own binary, not the venv's Python wrapper round it: the SIGINT below goes to the
    # server itself
    exe = Path(rerun_cli.__file__).with_name("rerun")
    if not exe.exists():
        pytest.skip("the rerun CLI's binary is not in this environment")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    received = tmp_path / "viewer.rrd"
    # a headless Rerun server that saves what it receives stands in for the viewer
    server = subprocess.Popen([str(exe), "--bind", "127.0.0.1", "--port", str(port), "--save", str(received)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                break
            except OSError:
                time.sleep(0.1)
        rec = CycleRecorder(tmp_path / "c.rrd", viewer_url=f"rerun+http://127.0.0.1:{port}/proxy")
        rec.log_images({"cam1": np.zeros((64, 64), np.uint8)})
        rec.log_event("seen live")
        rec.close()
        assert rec.warnings == []
        for _ in range(50):
            time.sleep(0.1)
            if received.exists() and received.stat().st_size > 1000:
                break
    finally:
        server.send_signal(signal.SIGINT)  # the server saves what it received and ends
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:  # a server that outlives its SIGINT is ended; what it saved
            server.kill()                   # is judged below (the recorder's stream is what is tested)
            server.wait()
    assert read_recording_summary(tmp_path / "c.rrd")["events"] == [("INFO", "seen live")]
    live = read_recording_summary(received)
    assert live["images"] == 1 and ("INFO", "seen live") in live["events"]


def test_unreachable_viewer_is_only_a_warning(tmp_path):
    import socket
    import time
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nobody listens here
    t0 = time.monotonic()
    rec = CycleRecorder(tmp_path / "c.rrd", viewer_url=f"rerun+http://127.0.0.1:{port}/proxy")
    rec.log_event("x")
    assert rec.close() == tmp_path / "c.rrd"
    assert time.monotonic() - t0 < 2 and "viewer not available" in rec.warnings[0]


KILLED_RECORDER = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {tests!r})
    from station.records.recording import CycleRecorder
    rec = CycleRecorder(sys.argv[1])
    print("recording", flush=True)
    time.sleep(600)  # killed mid-cycle: its .part file stays
""")


def test_the_next_recorder_removes_what_a_killed_one_left_and_no_live_ones(tmp_path):
    import os
    folder = tmp_path / "recordings"
    script = tmp_path / "killed.py"
    script.write_text(KILLED_RECORDER.format(tests=str(TESTS)))
    proc = subprocess.Popen([sys.executable, str(script), str(folder / "c-0001.rrd")], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "recording"
    finally:
        proc.kill()
        proc.wait()
    left = [p.name for p in folder.iterdir()]
    assert left == [f".c-0001.rrd.{proc.pid}.part"]  # what the killed recorder left behind
    running = folder / f".c-0002.rrd.{os.getppid()}.part"  # another process's recording in progress
    running.write_bytes(b"")
    with CycleRecorder(folder / "c-0003.rrd") as rec:
        rec.log_result(make_result(3, cycle=3))
    assert sorted(p.name for p in folder.iterdir()) == sorted([running.name, "c-0003.rrd"])
