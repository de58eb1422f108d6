"""Running visual odometry over a sequence: one or both methods, step by step.

A step ``i`` (1..n) is the motion from image i-1 to image i. Any problem (an unreadable,
blank or repeated frame, mismatched sizes, too few common keypoints) stops the method(s)
concerned with an :class:`OdometryError` naming the step; the trajectory up to the last good
step is kept in the run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from station.errors import OdometryError
from station.odometry.features import (PAPER_MATCHING, MatchSettings, StereoFrame,
                                       common_keypoints, detect, ratio_matches,
                                       stereo_match)
from station.odometry.paper_vo import StepEstimate, paper_step
from station.odometry.robust_vo import RobustSettings, robust_step
from station.odometry.sequence_io import StereoSequence
from station.odometry.trajectory import Trajectory

METHODS = ("paper", "robust")
MIN_COMMON_PAPER = 6   # M = P Q^+ needs >= 4 non-coplanar points; a margin against degeneracy


@dataclass(frozen=True)
class Variant:
    """A named estimator set-up: ``estimator`` 'paper' or 'robust', with its matching and
    robust settings (for comparisons such as the paper's estimator on filtered matches)."""

    name: str
    estimator: str
    matching: MatchSettings
    robust: RobustSettings = RobustSettings()


def variant(method: str | Variant) -> Variant:
    """'paper' (the paper's matching and estimator), 'robust', or a Variant as it is."""
    if isinstance(method, Variant):
        return method
    if method == "paper":
        return Variant("paper", "paper", PAPER_MATCHING)
    if method == "robust":
        return Variant("robust", "robust", MatchSettings())
    raise ValueError(f"unknown method {method!r}; use one of {METHODS}")


@dataclass
class StepInfo:
    """What one step used: keypoints in the left image, common to the four images, kept."""

    step: int
    n_keypoints: int
    n_common: int
    n_used: int
    points_world: np.ndarray          # (k,3) the step's points, world frame (for display)


@dataclass
class MethodRun:
    method: str
    trajectory: Trajectory = field(default_factory=Trajectory)
    steps: list[StepInfo] = field(default_factory=list)
    error: OdometryError | None = None


def _estimate(v: Variant, prev: StereoFrame, cur: StereoFrame, a: np.ndarray, b: np.ndarray,
              seq: StereoSequence, step: int) -> StepEstimate:
    R, t = seq.paper_pair
    robust = v.robust
    if v.estimator == "paper":
        if len(a) < MIN_COMMON_PAPER:
            raise OdometryError(f"step {step}: only {len(a)} keypoints common to the four images "
                                f"(the paper's method needs {MIN_COMMON_PAPER})",
                                hint="more texture in view, or smaller steps between images")
        return paper_step(prev.p_l[a], prev.p_r[a], cur.p_l[b], cur.p_r[b], R, t)
    f = 0.5 * (seq.left.K[0, 0] + seq.left.K[1, 1])
    est = robust_step(prev.p_l[a], prev.p_r[a], cur.p_l[b], cur.p_r[b], R, t, f, robust)
    if est is None:
        raise OdometryError(f"step {step}: too few keypoints agree on a motion ({len(a)} common to "
                            f"the four images, fewer than {robust.min_inliers} consistent)",
                            hint="more texture in view, or smaller steps between images")
    return est


def run_odometry(seq: StereoSequence, methods: tuple[str | Variant, ...] = ("robust",),
                 max_steps: int | None = None,
                 on_step: Callable[[str, int, MethodRun], None] | None = None) -> dict[str, MethodRun]:
    """Estimate the trajectory of ``seq`` with each method ('paper', 'robust' or a Variant),
    sharing the SIFT detection; never raises for bad input: a method that fails keeps its
    trajectory so far and records the error. Returns runs keyed by method name."""
    variants = {v.name: v for v in map(variant, methods)}
    methods = tuple(variants)
    runs = {m: MethodRun(m) for m in methods}
    n = len(seq) if max_steps is None else min(len(seq), max_steps + 1)
    frames: dict[str, StereoFrame] = {}
    last = None
    for i in range(n):
        active = [m for m in methods if runs[m].error is None]
        if not active:
            break
        try:
            left_img, right_img = seq.load(i)
            if last is not None:
                for side, img, before in (("left", left_img, last[0]), ("right", right_img, last[1])):
                    if np.array_equal(img, before):
                        raise OdometryError(f"step {i}: the {side} image {i} repeats image {i - 1} "
                                            "exactly (a stalled camera or a duplicated file)",
                                            hint="remove the duplicate or re-record the sequence")
        except OdometryError as e:
            msg = str(e) if str(e).startswith("step") else f"step {i}: {e}"
            for m in active:
                runs[m].error = OdometryError(msg, hint=e.hint)
            break
        last = (left_img, right_img)
        max_features = max(variants[m].matching.max_features for m in active)
        det_l = detect(left_img, max_features)
        det_r = detect(right_img, max_features)
        pairs: dict[float, tuple] = {}             # left-right matches, shared by the methods
        for m in active:
            v = variants[m]
            ratio = v.matching.ratio
            if ratio not in pairs:
                pairs[ratio] = ratio_matches(det_l[1], det_r[1], ratio)
            cur = stereo_match(det_l, det_r, seq.left, seq.right, v.matching, pairs[ratio])
            if i > 0:
                prev = frames[m]
                a, b = common_keypoints(prev, cur, v.matching)
                try:
                    est = _estimate(v, prev, cur, a, b, seq, i)
                except OdometryError as e:
                    runs[m].error = e
                    continue
                T_prev = runs[m].trajectory.poses[-1]
                pts_w = est.points_prev @ T_prev[:3, :3].T + T_prev[:3, 3]
                runs[m].trajectory.append(est.R_bar, est.t_bar)
                runs[m].steps.append(StepInfo(i, len(det_l[0]), len(a), int(est.inliers.sum()), pts_w))
                if on_step:
                    on_step(m, i, runs[m])
            frames[m] = cur
    return runs
