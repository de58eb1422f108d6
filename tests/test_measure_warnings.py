"""The wording of the per-camera warnings, from detections alone (the rendered cycles that raise
them are in tests/test_measure.py)."""

from types import SimpleNamespace

from station.config import load_config
from station.measure import _small_rim_warnings


def test_a_rim_much_smaller_than_the_other_cameras_is_named_as_another_contour():
    """A camera whose "rim" is a third of the other cameras' took the hub or an inner ring (a
    black rim): its warning says so and does not ask for a longer lens; one only a little
    smaller than the others is a rim too small in its image."""
    cfg = load_config(None)
    cams = list(cfg.cameras)
    detections = {c: SimpleNamespace(ellipse=SimpleNamespace(axes_px=(280.0, 270.0))) for c in cams}
    detections[cams[0]] = SimpleNamespace(ellipse=SimpleNamespace(axes_px=(85.0, 80.0)))
    detections[cams[1]] = SimpleNamespace(ellipse=SimpleNamespace(axes_px=(175.0, 170.0)))
    warned = dict(_small_rim_warnings(detections, cfg))
    assert set(warned) == {cams[0], cams[1]}
    assert "hub" in warned[cams[0]] and "black" in warned[cams[0]] and "longer lens" not in warned[cams[0]]
    assert "280 px" in warned[cams[0]]
    assert "longer lens" in warned[cams[1]] and "hub" not in warned[cams[1]]
