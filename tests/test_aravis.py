"""The Aravis driver against Aravis' own GigE Vision emulator, for real.

Every scenario runs in tests/aravis_probe.py INSIDE a loopback-only network namespace
(``unshare -n``): Aravis must never reach a real network. Skipped, with the reason, where
unshare, the emulator or the Aravis typelib is missing.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from aravis_probe import netns_available, run_in_netns

PROBE = str(Path(__file__).with_name("aravis_probe.py"))
REASON = netns_available()
pytestmark = pytest.mark.skipif(REASON is not None, reason=str(REASON))


def probe(scenario: str, n_addresses: int = 1, *args: str) -> dict:
    return run_in_netns(PROBE, [scenario, *args], n_addresses)


def test_open_configure_snap_and_deadline():
    r = probe("basic")
    assert r["identity"] == ["Aravis", "Fake", "FAKE2", 1280, 1024]
    assert r["exposure"] == 5000.0 and r["gain"] == 2.0
    assert r["trigger"] == ["On", "Software"]
    assert r["shape"] == [1024, 1280] and r["dtype"] == "uint8"
    assert r["ramp"], "buffer unpacked with the wrong stride/size"
    ids = r["frame_ids"]
    assert ids[1] == ids[0] + 1 and ids[2] == ids[1] + 1  # one frame per software trigger
    # armed, no trigger: CameraTimeout (201) after the deadline, not before, not much after
    assert r["no_trigger"]["type"] == "CameraTimeout" and r["no_trigger"]["code"] == 201
    assert 0.29 <= r["no_trigger"]["s"] < 1.5
    assert "NoSuchFeature" in r["bad_feature"]["msg"] and "cam1" in r["bad_feature"]["msg"]
    assert "outside the camera's range" in r["exposure_range"]["msg"]
    assert r["after_error"]
    assert r["half"] == [2500.0, True] and r["restored"] == [5000.0, True]  # re-exposed between frames


def test_pixel_formats_roi_and_trigger_modes():
    r = probe("formats")
    assert r["Mono16"][:2] == ["uint16", [48, 64]] and r["Mono16"][2] > 255
    for fmt in ("BayerRG8", "BayerBG8", "Mono8"):
        assert r[fmt][:2] == ["uint8", [48, 64]]
    assert "Mono12" in r["Mono12"]["msg"] and r["Mono12"]["type"] == "DriverError"
    assert "does not fit" in r["too_big"]["msg"]
    assert r["roi"] == [16, 32]
    assert r["hw_source"] == "Line0"
    assert r["hw_no_pulse"]["type"] == "CameraTimeout"
    assert "Line9" in r["bad_line"]["msg"] and "Line0, Software" in r["bad_line"]["msg"]
    assert r["free_run"] == [True, True]


def test_camera_drops_off_and_comes_back():
    r = probe("drop")
    assert r["before"]
    assert r["gone"]["type"] == "CameraMissing" and "cam1" in r["gone"]["msg"]
    assert r["gone"]["s"] < 5.0  # Aravis' own GVCP timeout, bounded
    assert r["still_gone"]["type"] == "CameraMissing" and r["still_gone"]["s"] < 2.0  # GVCP ping, not Aravis' 2.5 s
    assert r["back"]["type"] is None and r["back_ramp"]
    assert r["reconnects"] == 1


def test_corrupt_buffers_are_errors_not_hangs():
    r = probe("corrupt")
    kinds = {x["type"] for x in r["results"]}
    assert kinds <= {None, "FrameError"}
    assert "FrameError" in kinds, "30 % packet loss without resend must give a corrupt buffer"
    bad = [x for x in r["results"] if x["type"] == "FrameError"]
    assert all("corrupt buffer" in x["msg"] and "cam1" in x["msg"] for x in bad)
    assert all(x["s"] < 3.0 for x in r["results"])


def test_opening_eight_reports_every_missing_camera_once():
    r = probe("open_missing", 8)["open"]
    assert r["type"] == "CameraMissing" and r["code"] == 202
    assert "(cam6, cam8)" in r["msg"] and "127.0.0.7" in r["msg"] and "127.0.0.9" in r["msg"]
    assert "cam1" not in r["msg"]
    assert r["s"] < 8  # opened concurrently, not 2 x 2.5 s one after the other plus the rest


@pytest.mark.slow
def test_synchronised_capture_of_eight_emulated_cameras():
    r = probe("sync8", 8, "10")
    assert r["serials"] == [f"FAKE{i}" for i in range(2, 10)]
    assert r["lost"] == [] and len(r["times"]) == 10 and r["ramps"]
    assert max(r["times"]) < 3.0
    assert r["replay_identical"]
    drop = r["drop"]
    assert drop["type"] in ("CameraTimeout", "CameraMissing") and "(cam4)" in drop["msg"]
    assert r["drop_s"] < 2.5  # the 1.5 s deadline held (not 2.5 s of GVCP retries)
    assert r["back"]["type"] is None, r["back"]
    assert r["open_missing"]["type"] == "CameraMissing" and "(cam6)" in r["open_missing"]["msg"]


def test_station_commands_on_eight_gige_cameras():
    r = probe("cli", 8)
    assert r["cameras_rc"] == 0
    rows = r["cameras"]
    assert [row["serial"] for row in rows] == [f"FAKE{i}" for i in range(2, 10)]
    assert all(row["open"] and row["vendor"] == "Aravis" and row["resolution"] == "640x480" for row in rows)
    assert r["capture_rc"] == 0 and "captured 8 frames" in r["capture_out"]
    assert r["saved"] == [f"cam{i}" for i in range(1, 9)] and r["complete"]
    assert r["address"] == "127.0.0.4"
