"""The tests never read or write a real station's data, whatever the environment names
(tests/conftest.py): a few tests that save a calibration, captures, a history and run `station`
in a subprocess are run with STATION_DATA_DIR, STATION_CONFIG and XDG_CACHE_HOME pointing at a
sentinel station; they pass and the sentinel, and the repository's var/, are left as they were."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
REPRESENTATIVE = (
    # a module fixture saves a truth calibration, the cycle keeps captures and a history row
    "tests/test_cycle.py::test_an_unknown_vehicle_spec_is_raised_after_the_cycle_is_kept",
    # captures saved under the data directory, in-process
    "tests/test_capture.py::test_station_cycle_saves_under_data_dir_unless_told_not_to",
    # `station measure` in a subprocess on a station without a calibration
    "tests/test_measure.py::test_measure_without_calibration_names_the_file_and_what_to_do",
)


def _snapshot(folder: Path) -> dict[str, str]:
    """{relative path: SHA-1 of the content} of every file under ``folder`` ("" for a folder)."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else ""
            for p in sorted(folder.rglob("*"))}


@pytest.mark.slow
def test_tests_leave_the_station_the_environment_names_untouched(tmp_path):
    sentinel = tmp_path / "station"
    (sentinel / "data" / "calibration").mkdir(parents=True)
    (sentinel / "data" / "calibration" / "station.calib.json").write_text('{"a real station": "calibration"}\n')
    (sentinel / "cache").mkdir()
    config = yaml.safe_load((ROOT / "config" / "station.yaml").read_text())
    config["data_dir"] = str(sentinel / "data")
    config["vehicle_specs"] = str(ROOT / "config" / "vehicles.yaml")
    config["calibration"]["box"] = str(ROOT / "config" / "box.yaml")
    (sentinel / "station.yaml").write_text(yaml.safe_dump(config))
    before, var_before = _snapshot(sentinel), _snapshot(ROOT / "var")
    env = {**os.environ, "STATION_DATA_DIR": str(sentinel / "data"), "STATION_CONFIG": str(sentinel / "station.yaml"),
           "XDG_CACHE_HOME": str(sentinel / "cache")}
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          f"--basetemp={tmp_path / 'inner'}", *REPRESENTATIVE],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert f"{len(REPRESENTATIVE)} passed" in run.stdout
    assert _snapshot(sentinel) == before
    assert _snapshot(ROOT / "var") == var_before
