"""The simulated toe adjustment behind `station live` (simulators/adjustment.py)."""

from __future__ import annotations

import numpy as np

from simulators.adjustment import AdjustmentWorld


class _World:
    """The few SimWorld parts AdjustmentWorld uses; truth() names the scene it was given."""

    def __init__(self, cams):
        self.config = None
        self.cameras = {c: None for c in cams}
        self.noise_sigma = 1.0

    def truth(self, scene):
        return {"scene": scene}


def _adjustment(hold=1):
    cams = ["cam1", "cam2", "cam3", "cam4"]
    clean = np.full((4, 6), 100, np.uint8)
    steps = [{c: clean for c in cams}] + [{"cam3": clean, "cam4": clean} for _ in range(2)]
    return AdjustmentWorld(_World(cams), ["step0", "step1", "step2"], steps, hold=hold, seed=0)


def test_frames_step_forwards_then_backwards():
    adj = _adjustment(hold=2)
    assert [adj.step_of(n) for n in range(10)] == [0, 0, 1, 1, 2, 2, 1, 1, 0, 0]


def test_truth_follows_the_live_cameras_whatever_camera_was_served_first():
    adj = _adjustment()
    for cam in ("cam1", "cam2", "cam4", "cam3"):  # the baseline: every camera, a non-live one first
        adj.render(cam)
    assert adj.truth()["scene"] == "step0"
    for _ in range(2):  # two live updates: the adjusted wheel's cameras only
        for cam in ("cam3", "cam4"):
            img = adj.render(cam)
    assert img.shape == (4, 6) and img.dtype == np.uint8
    assert adj.truth()["scene"] == "step2"
