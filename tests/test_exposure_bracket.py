"""A camera whose lip is at the sensor's white is taken again at a shorter exposure
(station/capture/exposure_bracket.py): the loop's rules, a simulated cycle, its replay."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from station.capture.exposure_bracket import measure_bracketed
from station.config import load_config
from station.errors import ConfigError
from station.result import CameraDetection, Measurement, WarningFlag
from tests.station_fixtures import small_station_config, truth_calibration


def _measure_by_brightness(white_above: float, lost_below: float = -1.0):
    """A fake measurement: a camera whose image's value is above ``white_above`` is flagged at
    the white; one below ``lost_below`` finds no rim."""
    calls = []

    def measure(images):
        calls.append(dict(images))
        r = Measurement(station="test")
        r.detections = {c: CameraDetection(ok=float(im.mean()) >= lost_below) for c, im in images.items()}
        r.warning_flags = [WarningFlag("exposure", "FL", camera=c) for c, im in images.items()
                           if float(im.mean()) > white_above]
        return r
    return measure, calls


def _recapture(levels: dict, taken: list):
    def recapture(ids, factor):
        taken.append((list(ids), factor))
        return {c: np.full((2, 2), levels[c] * factor) for c in ids}
    return recapture


def test_a_white_camera_is_taken_again_until_it_is_not_white():
    levels = {"cam1": 300.0, "cam2": 100.0, "cam3": 180.0}
    images = {c: np.full((2, 2), v) for c, v in levels.items()}
    measure, calls = _measure_by_brightness(white_above=120.0)
    taken = []
    result, used, exposures = measure_bracketed(images, measure, _recapture(levels, taken), (0.5, 0.25))
    # cam1 300 -> 150 (still white) -> 75; cam3 180 -> 90
    assert taken == [(["cam1", "cam3"], 0.5), (["cam1"], 0.25)]
    assert exposures == {"cam1": 0.25, "cam3": 0.5} == result.exposures
    assert used["cam1"].mean() == 75.0 and used["cam3"].mean() == 90.0 and used["cam2"] is images["cam2"]
    assert len(calls) == 3 and not result.warning_flags
    assert "cam1 at 0.25x" in result.warnings[-1] and "cam3 at 0.5x" in result.warnings[-1]


def test_nothing_is_taken_again_without_a_white_camera_or_without_steps():
    images = {"cam1": np.full((2, 2), 300.0), "cam2": np.full((2, 2), 100.0)}
    measure, calls = _measure_by_brightness(white_above=400.0)
    taken = []
    result, used, exposures = measure_bracketed(images, measure, _recapture({}, taken), (0.5, 0.25))
    assert taken == [] and exposures == {} and result.exposures is None and used is images and len(calls) == 1
    measure, calls = _measure_by_brightness(white_above=120.0)
    result, _, exposures = measure_bracketed(images, measure, _recapture({}, taken), ())
    assert taken == [] and exposures == {} and [f.camera for f in result.warning_flags] == ["cam1"]


def test_a_second_take_that_fails_ends_the_steps_without_measuring_again():
    images = {"cam1": np.full((2, 2), 300.0)}
    measure, calls = _measure_by_brightness(white_above=120.0)
    tries = []
    result, used, exposures = measure_bracketed(images, measure, lambda ids, f: tries.append(f) or {}, (0.5, 0.25))
    assert tries == [0.5] and len(calls) == 1 and exposures == {} and used is images
    assert [f.camera for f in result.warning_flags] == ["cam1"]


def test_a_camera_that_loses_its_rim_at_the_shorter_exposure_keeps_the_longer_frame():
    levels = {"cam1": 300.0, "cam2": 130.0}
    images = {c: np.full((2, 2), v) for c, v in levels.items()}
    measure, calls = _measure_by_brightness(white_above=120.0, lost_below=100.0)  # cam2 at 65: no rim
    taken = []
    result, used, exposures = measure_bracketed(images, measure, _recapture(levels, taken), (0.5,))
    assert exposures == {"cam1": 0.5}
    assert used["cam2"] is images["cam2"] and used["cam1"].mean() == 150.0
    assert all(d.ok for d in result.detections.values())
    assert [f.camera for f in result.warning_flags] == ["cam1", "cam2"]  # still flagged: said, not hidden


@pytest.mark.parametrize("steps, message", [([0.5, 0.7], "falling"), ([1.5], r"\[0.01, 0.99\]"),
                                            ("0.5", "list of up to 4"), ([0.5, "x"], "a number")])
def test_bad_exposure_steps_name_the_key(tmp_path, steps, message):
    config = small_station_config(tmp_path)
    data = yaml.safe_load(Path(config.path).read_text())
    data["capture"]["exposure_steps"] = steps
    Path(config.path).write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=f"capture.exposure_steps: .*{message}"):
        load_config(config.path)


@pytest.mark.slow
def test_an_overexposed_camera_is_measured_on_a_shorter_take_and_a_replay_repeats_it(tmp_path):
    from station.cycle import Station

    (tmp_path / "sim").mkdir()
    config = small_station_config(tmp_path / "sim", capture__frames_averaged=1, recording__enabled=False)
    truth_calibration(config)
    with Station(config, seed=3, progress=lambda msg: None, workers=0) as station:
        cam = station.cameras["cam1"]
        cam.configure(exposure_us=3 * cam.settings.exposure_us)  # its lip at the white
        result = station.measure(job_id="SUN")
        assert cam.settings.exposure_us == 3 * config.cameras["cam1"].exposure_us  # set back after the second take
    assert result.valid, result.failure
    assert result.exposures == {"cam1": 0.5}
    assert not [f for f in result.warning_flags if f.kind == "exposure"]
    limit = config.measurement.white_edge_limit
    assert result.detections["cam1"].white_share <= limit < 1.0
    kept = Path(result.captures_dir) / "exposure-0.5"
    assert sorted(p.name for p in kept.glob("*.png")) == ["cam1.png"]
    assert result.to_json()["exposures"] == {"cam1": 0.5}
    assert Measurement.from_json(result.to_json()).exposures == {"cam1": 0.5}

    # the same camera without the second take: flagged at the white, measured on the white frame
    data = yaml.safe_load(Path(config.path).read_text())
    plain = _config_variant(tmp_path / "plain", data, exposure_steps=[])
    with Station(plain, seed=3, progress=lambda msg: None, workers=0) as station:
        cam = station.cameras["cam1"]
        cam.configure(exposure_us=3 * cam.settings.exposure_us)
        unbracketed = station.measure(job_id="SUN")
    assert unbracketed.exposures is None
    assert [f.camera for f in unbracketed.warning_flags if f.kind == "exposure"] == ["cam1"]
    assert unbracketed.detections["cam1"].white_share > limit

    # the replay of the kept cycle takes cam1's second take from its folder: the same result
    uris = {cid: f"replay://{result.captures_dir}?camera={cid}" for cid in data["cameras"]}
    replay = _config_variant(tmp_path / "replay", data, uris=uris)
    with Station(replay, progress=lambda msg: None, workers=0) as station:
        replayed = station.measure()
    assert replayed.exposures == {"cam1": 0.5}
    for w in ("FL", "FR", "RL", "RR"):
        assert replayed.wheels[w].toe_deg == result.wheels[w].toe_deg
        assert replayed.wheels[w].camber_deg == result.wheels[w].camber_deg

    # a kept cycle without its second take (kept before there was one): measured as kept, and said
    shutil.rmtree(kept)
    with Station(replay, progress=lambda msg: None, workers=0) as station:
        old = station.measure()
    assert old.exposures is None
    assert [f.camera for f in old.warning_flags if f.kind == "exposure"] == ["cam1"]
    assert any("cam1 could not be taken again at 0.5x" in w and "measured on the frames taken before" in w
               for w in old.warnings)


def _config_variant(folder: Path, data: dict, uris: dict | None = None, **capture):
    """The configuration ``data`` with ``capture`` keys and camera URIs changed, loaded from
    ``folder`` (the test's STATION_DATA_DIR, and so the calibration, stay the same)."""
    data = yaml.safe_load(yaml.safe_dump(data))
    data["capture"].update(capture)
    for cid, uri in (uris or {}).items():
        data["cameras"][cid]["uri"] = uri
    folder.mkdir(parents=True)
    (folder / "station.yaml").write_text(yaml.safe_dump(data))
    return load_config(folder / "station.yaml")


@pytest.mark.slow
def test_a_board_fired_station_takes_every_hardware_camera_again_and_the_next_cycle_runs(tmp_path):
    from station.cycle import Station

    config = small_station_config(tmp_path, capture__frames_averaged=1, recording__enabled=False)
    truth_calibration(config)
    data = yaml.safe_load(Path(config.path).read_text())
    data["trigger_board"]["port"] = "sim"
    data["camera_defaults"]["trigger"] = "hardware"
    board = _config_variant(tmp_path / "board", data)
    with Station(board, seed=3, progress=lambda msg: None, workers=0) as station:
        assert station.trigger_board is not None
        cam = station.cameras["cam5"]
        cam.configure(exposure_us=3 * cam.settings.exposure_us)
        first = station.measure()
        second = station.measure()  # the other cameras' frames of the second take left no stale frame
    for result in (first, second):
        assert result.valid, result.failure
        assert result.exposures == {"cam5": 0.5}
