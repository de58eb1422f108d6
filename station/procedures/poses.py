"""A wheel's pose at one capture of a procedure, as the procedures read it from a result."""

from __future__ import annotations

import numpy as np

from station.config import StationConfig
from station.result import Measurement
from station.stated_uncertainty import unseen_axis_covariance
from station.wheel.rim_pattern import FacePose


def face_pose(result: Measurement, wheel: str) -> FacePose:
    """The wheel's 3-D circle in ``result`` (valid, with its observations)."""
    c = result.observations[wheel].circle
    return FacePose(np.asarray(c.center_station, float), np.asarray(c.axis_station, float), float(c.radius_m))


def normal_covariance(result: Measurement, wheel: str, config: StationConfig) -> np.ndarray:
    """(3,3) the rim normal's covariance at one capture: the circle fit's and the unseen share."""
    o = result.observations[wheel]
    cov = np.asarray(o.circle.cov_axis, float)
    cov = cov if np.all(np.isfinite(cov)) else np.eye(3) * 1e-8
    return cov + unseen_axis_covariance(o, o.circle.axis_station, config)
