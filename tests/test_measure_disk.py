"""`station measure` on a full or read-only data disk: the result is printed, written to --json
where it can be (or a clear message says why not), and returned with a warning per part of the
cycle's record the disk refused (images, recording, history row); exit status 4 (or 2 when the
--json file could not be written). Nothing half-written stays behind."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.station_fixtures import small_station_config, truth_calibration

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def station_yaml(tmp_path_factory):
    base = tmp_path_factory.mktemp("disk")
    config = small_station_config(base, capture__frames_averaged=1)
    truth_calibration(config)
    return config.path, config.calibration_file


def _measure_on(tmp_path, station_yaml, disk: str, json_path: str) -> tuple[subprocess.CompletedProcess, list[str]]:
    """`station measure --json json_path` with its data folder on a private mount: ``full`` (a
    tmpfs filled up once the calibration is on it) or ``read-only``. (the run, the files left on
    the mount)."""
    if shutil.which("unshare") is None:
        pytest.skip("unshare is not installed")
    config_path, calibration = station_yaml
    mnt = tmp_path / "data"
    mnt.mkdir()
    setup = {"full": f"mount -t tmpfs -o size=256k tmpfs {mnt} && mkdir {mnt}/calibration && "
                     f"cp {calibration} {mnt}/calibration/ && (dd if=/dev/zero of={mnt}/filler bs=4k 2>/dev/null; true)",
             "read-only": f"mount -t tmpfs -o size=1m tmpfs {mnt} && mkdir {mnt}/calibration && "
                          f"cp {calibration} {mnt}/calibration/ && mount -o remount,ro {mnt}"}[disk]
    listing = f"find {mnt} -mindepth 1 > {tmp_path}/left.txt"
    cmd = (f"{setup} && {{ {sys.executable} -m station.cli --config {config_path} measure --seed 3 "
           f"--json {json_path.format(mnt=mnt)}; status=$?; {listing}; exit $status; }}")
    p = subprocess.run(["unshare", "-m", "sh", "-c", cmd], capture_output=True, text=True, timeout=300, cwd=ROOT,
                       env={**os.environ, "STATION_DATA_DIR": str(mnt), "HOME": str(tmp_path)})
    if p.returncode != 0 and ("mount" in p.stderr or "unshare" in p.stderr):
        pytest.skip(f"cannot make a private mount here: {p.stderr.strip()[:200]}")
    left = (tmp_path / "left.txt").read_text().split()
    return p, sorted(os.path.relpath(f, mnt) for f in left)


def _printed_a_result(out: str) -> bool:
    return all(line in out for line in ("FL ", "FR ", "RL ", "RR ", "thrust angle"))


@pytest.mark.slow
def test_full_disk_prints_and_writes_the_result_with_warnings(tmp_path, station_yaml):
    p, left = _measure_on(tmp_path, station_yaml, "full", str(tmp_path / "result.json"))
    assert p.returncode == 4, p.stderr
    assert _printed_a_result(p.stdout) and "Traceback" not in p.stderr and "internal error" not in p.stderr
    assert "cannot save the images: No space left on device; the measurement is kept" in p.stdout
    assert "cannot write the recording: No space left on device" in p.stdout
    assert "the data disk is full); the measurement is kept, this cycle is not in the history" in p.stdout
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["valid"] and not result.get("captures_dir") and not result.get("recording")
    assert any(f["kind"] == "not_kept" for f in result["warning_flags"])
    assert not [f for f in left if Path(f).name.startswith(".")]  # no half-written images or recording


@pytest.mark.slow
def test_full_disk_and_json_on_it_says_so_after_printing_the_result(tmp_path, station_yaml):
    p, left = _measure_on(tmp_path, station_yaml, "full", "{mnt}/result.json")
    assert p.returncode == 2
    assert _printed_a_result(p.stdout) and "Traceback" not in p.stderr
    assert "cannot write the result JSON: No space left on device" in p.stderr
    assert "the result is printed above" in p.stderr
    assert "result.json" not in left and not [f for f in left if Path(f).name.startswith(".")]


@pytest.mark.slow
def test_read_only_disk_prints_and_writes_the_result_with_warnings(tmp_path, station_yaml):
    p, left = _measure_on(tmp_path, station_yaml, "read-only", str(tmp_path / "result.json"))
    assert p.returncode == 4, p.stderr
    assert _printed_a_result(p.stdout) and "Traceback" not in p.stderr
    for part in ("cannot save the images: Read-only file system", "cannot create the recording: Read-only file system",
                 "this cycle is not in the history"):
        assert part in p.stdout
    assert json.loads((tmp_path / "result.json").read_text())["valid"]
    assert left == ["calibration", "calibration/station.calib.json"]
