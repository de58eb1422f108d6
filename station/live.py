"""Live measurement for adjusting toe: one axle (or all four wheels), many updates a second.

A technician turning a tie rod watches toe move. :class:`LiveSession` assembles the station
like station/cycle.py does (cameras through the driver registry, the calibration file), takes
one full cycle of all eight cameras to fix the car frame (the car does not move while a wheel
is adjusted), then loops over the live axle's cameras only: capture, rim detection with each
camera's previous ellipse as the prior (the detector's fast path; it falls back to the full
search by itself), the 3-D circle of each live wheel, and the angles in the car frame with the
other wheels' last measured centres and axes.

Nothing here asks whether the station is simulated, except one place: on a sim:// station
(``drivers.context.Simulation``) a simulated technician turns the live wheel's tie rod while the
loop runs, and each reading carries the true toe.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from station import alignment
from station.capture.sync import capture_cycle
from calibration.station_frame import WHEELS
from station.config import StationConfig
from station.errors import MeasurementError, StationError
from station.cycle import close_capture, open_capture
from station.compute.workers import WorkerPool, default_workers
from station.rim.camera_response import linear_images
from station.measure import measure_frames
from station.result import Measurement
from station.wheel.pair import WheelObservation, check_same_rim
from station.wheel.other_contour import on_circle
from station.wheel.circle_fit import CircleFitSettings, not_faint, refine_circle
from station.wheel.fit import WheelFit
from station.wheel.paper import reconstruct_paper
from station.wheel.arcs import not_grazing

AXLES = {"front": ("FL", "FR"), "rear": ("RL", "RR"), "all": WHEELS}


@dataclass
class Reading:
    """One live update. wheels[W] = {toe_deg, camber_deg} for the live wheels; errors[W] = why
    a live wheel has no value this time; timing_s per stage; truth_toe_deg in simulation."""

    n: int
    wheels: dict = field(default_factory=dict)
    total_toe_deg: dict = field(default_factory=dict)   # axle -> deg (both wheels measured)
    errors: dict = field(default_factory=dict)
    timing_s: dict = field(default_factory=dict)
    truth_toe_deg: dict | None = None


class LiveSession:
    """Cameras + calibration + the live loop. Use as a context manager."""

    def __init__(self, config: StationConfig, *, axle: str = "front", seed: int = 0, calibration=None,
                 cache_dir: str | Path | None = None, hold: int = 5, toe_span_deg: float = 0.6,
                 n_steps: int = 7, progress: Callable[[str], None] = print, workers: int | None = None,
                 job_id: str | None = None):
        """job_id: a runout kept for this job (``station measure --compensate --job``) is
        applied: the live toe and camber are of the spin axes (:attr:`runout_compensated`)."""
        from calibration.calib_file import load_calibration
        from drivers.registry import build_context

        if axle not in AXLES:
            raise MeasurementError(f"unknown axle {axle!r}; expected one of {', '.join(AXLES)}")
        self.config = config
        self.axle = axle
        self.live_wheels = tuple(AXLES[axle])
        self.calibration = calibration or load_calibration(config.calibration_file, config)
        self.models = {cid: self.calibration.model(cid) for cid in config.cameras}
        self.pairs = {w: (config.pairs[w].precision, config.pairs[w].reference) for w in WHEELS}
        self.live_cams = [c for w in self.live_wheels for c in self.pairs[w]]
        self.context = build_context([c.uri for c in config.cameras.values()], config, seed=seed)
        self.simulation = self.context.simulation
        if self.simulation is not None:  # the simulated station: a simulated tie-rod adjustment
            cache = Path(cache_dir) if cache_dir else config.data_path("live-cache")
            self.simulation.start_toe_adjustment(self.live_wheels[0], toe_span_deg, n_steps, self.live_cams, cache,
                                                 progress, hold)
        self.cameras, self.trigger_board, self.timeout_s = open_capture(config, self.context)
        self.previous: dict = {}  # cam id -> its last RimDetection (tracking)
        self.circles: dict = {}   # wheel -> its last 3-D circle (WheelFit), the next fit's start
        self.centers: dict = {}
        self.axes: dict = {}
        self.n = 0
        self.job_id = job_id
        self.runout_compensated = False
        self.to_spin: dict = {}   # wheel -> (3,3) rotation from its rim normal to its spin axis (kept runout)
        n = default_workers() if workers is None else workers
        self.workers = WorkerPool(n) if n > 1 else None
        self._pool = ThreadPoolExecutor(max_workers=2)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._pool.shutdown(wait=True)
        close_capture(self.workers, self.cameras, self.trigger_board, self.context)

    # --- the car frame: one full cycle --------------------------------------------------------
    def baseline(self) -> Measurement:
        """Measure all four wheels once (every camera); raises MeasurementError if it fails."""
        frames = capture_cycle(self.cameras, self.timeout_s, self.trigger_board)
        result = measure_frames({c: f.image for c, f in frames.items()}, self.models, self.config,
                                workers=self.workers)
        if not result.valid:
            raise MeasurementError(f"the first full measurement failed: {result.failure.message}",
                                   hint=result.failure.hint
                                   or "check the vehicle's position and the cameras' images (station measure)")
        if self.job_id:
            result = self._apply_kept_runout(result, {c: f.image for c, f in frames.items()})
        for w in WHEELS:
            self.centers[w] = np.asarray(result.wheels[w].center_station_m)
            self.axes[w] = np.asarray(result.wheels[w].axis_station)
        self.previous = {c: d for o in result.observations.values() for c, d in zip(o.cams, o.detections)}
        self.circles = {w: o.circle for w, o in result.observations.items()}
        return result

    def _apply_kept_runout(self, result: Measurement, images: dict) -> Measurement:
        """The baseline with the job's kept runout applied; the live wheels then keep the rotation
        from their rim normal to their spin axis (the car stands still while it is adjusted)."""
        from station.procedures.runout_store import apply_kept_runout_to, rotation_onto

        result.job_id, result.calibration_id = self.job_id, self.calibration.calibration_id
        rim = {w: np.asarray(o.circle.axis_station) for w, o in result.observations.items()}
        result = apply_kept_runout_to(self.config, result, images, self.models)
        if result.runout_compensated:
            self.runout_compensated = True
            self.to_spin = {w: rotation_onto(rim[w], np.asarray(result.wheels[w].axis_station)) for w in WHEELS}
        return result

    # --- one live update ----------------------------------------------------------------------
    def update(self) -> Reading:
        """Capture the live cameras, detect, rebuild the live wheels, compute their angles."""
        if not self.centers:
            self.baseline()
        reading = Reading(self.n)
        t0 = time.perf_counter()
        cams = {c: self.cameras[c] for c in self.live_cams}
        frames = capture_cycle(cams, self.timeout_s, self.trigger_board)
        t1 = time.perf_counter()
        images = linear_images({c: frames[c].image for c in cams}, self.config)  # station/rim/camera_response.py
        tasks = [(w, self.pairs[w], {c: images[c] for c in self.pairs[w]},
                  {c: self.models[c] for c in self.pairs[w]}, {c: self.previous.get(c) for c in self.pairs[w]},
                  self.config, self.circles.get(w)) for w in self.live_wheels]
        if self.workers is not None:
            outcomes = self.workers.map(live_wheel, tasks)
        else:
            outcomes = list(self._pool.map(lambda a: live_wheel(*a), tasks))
        t2 = time.perf_counter()
        for o in outcomes:
            for cid, d in o.detections.items():  # a failed camera searches the whole image next time
                if isinstance(d, StationError):
                    self.previous.pop(cid, None)
                else:
                    self.previous[cid] = d
            if o.error is not None:
                reading.errors[o.wheel] = o.error
                continue
            self.centers[o.wheel] = o.observation.circle.center_station
            self.axes[o.wheel] = self.to_spin.get(o.wheel, np.eye(3)) @ o.observation.circle.axis_station
            self.circles[o.wheel] = o.observation.circle
            reading.wheels[o.wheel] = {}
        work = {k: sum(o.timing_s[k] for o in outcomes) for k in ("detect", "reconstruct")}
        t3 = time.perf_counter()
        if reading.wheels:
            angles = alignment.compute_angles(self.centers, self.axes)
            for w in reading.wheels:
                reading.wheels[w] = {k: float(angles["wheels"][w][k]) for k in ("toe_deg", "camber_deg")}
            for axle, (left, right) in (("front", ("FL", "FR")), ("rear", ("RL", "RR"))):
                if left in reading.wheels and right in reading.wheels:
                    reading.total_toe_deg[axle] = float(angles["axles"][axle]["total_toe_deg"])
        t4 = time.perf_counter()
        reading.timing_s = {"capture": t1 - t0, "wheels": t2 - t1, **work, "angles": t4 - t3, "total": t4 - t0}
        if self.simulation is not None:
            truth = self.simulation.truth()
            key = "toe_deg" if self.runout_compensated else "rim_toe_deg"
            reading.truth_toe_deg = {w: truth["wheels"][w].get(key, truth["wheels"][w]["toe_deg"])
                                     for w in self.live_wheels}
        self.n += 1
        return reading

    def run(self, seconds: float | None, show: Callable[[Reading], None], max_updates: int | None = None) -> dict:
        """Update until ``seconds`` pass, ``max_updates`` are done or Ctrl-C; returns the rate.

        Ctrl-C ends the loop cleanly (the KeyboardInterrupt is caught here, the summary still
        returned, with ``interrupted`` True)."""
        times, interrupted = [], False
        t_start = time.perf_counter()
        try:
            while True:
                r = self.update()
                times.append(r.timing_s)
                show(r)
                if seconds is not None and time.perf_counter() - t_start >= seconds:
                    break
                if max_updates is not None and len(times) >= max_updates:
                    break
        except KeyboardInterrupt:
            interrupted = True
        elapsed = time.perf_counter() - t_start
        return rate_summary(times, elapsed, interrupted)


LIVE_MAX_POINTS = 400  # edge points per view for the live 3-D fit (a full cycle uses all)
# the live fit: no covariance's bias term (the display shows no uncertainty) and no second fit
# without the grazing points (the baseline's choice is kept, below)
LIVE_FIT = CircleFitSettings(bias_modes=0, grazing_test=False)


def _thin(points: np.ndarray, n: int) -> np.ndarray:
    """Every k-th of the (N,2) points, at most about ``n``, spread evenly along the rim."""
    return points[:: max(1, int(np.ceil(len(points) / n)))]


@dataclass
class LiveWheel:
    """One live wheel of an update: detections (RimDetection or StationError per camera), the
    observation or why there is none, seconds of work per stage."""

    wheel: str
    detections: dict
    observation: WheelObservation | None
    error: str | None
    timing_s: dict


def live_wheel(wheel: str, cams: tuple[str, str], images: dict, models: dict, previous: dict,
               config: StationConfig, previous_circle: WheelFit | None = None) -> LiveWheel:
    """Track the rim in both cameras of a pair from their previous detections and rebuild the
    wheel (a worker's task). The 3-D fit starts from the wheel's previous circle (it moved by
    a fraction of a degree) and skips the covariance: the live display shows none."""
    from station.rim import detect_rim

    t0 = time.perf_counter()
    detections = {}
    for c in cams:
        try:
            detections[c] = detect_rim(images[c], camera=models[c], previous=previous.get(c), camera_id=c)
        except StationError as e:
            detections[c] = e
    t1 = time.perf_counter()
    obs, error = None, None
    bad = [c for c in cams if isinstance(detections[c], StationError)]
    if bad:
        error = f"{bad[0]}: {detections[bad[0]]}"
    else:
        try:
            cam_l, cam_r = models[cams[0]], models[cams[1]]
            det_l, det_r = detections[cams[0]], detections[cams[1]]
            pl, pr = (_thin(d.points_px, LIVE_MAX_POINTS) for d in (det_l, det_r))
            con_l, con_r = (_thin(d.points_contrast, LIVE_MAX_POINTS) for d in (det_l, det_r))  # (as measure's)
            paper = reconstruct_paper(pl, pr, cam_l, cam_r)
            # the baseline cycle chose, by the covariance, whether this wheel is fitted without
            # the points seen across the lip at a grazing angle; live keeps that choice (no
            # second fit per update: it would halve the all-wheel rate)
            grazing_out = previous_circle is not None and previous_circle.grazing_left_out
            if grazing_out:
                keep_l, keep_r = not_grazing(previous_circle, pl, pr, cam_l, cam_r)
                pl, pr, con_l, con_r = pl[keep_l], pr[keep_r], con_l[keep_l], con_r[keep_r]
            # and whether arcs on another concentric contour are left out (station/wheel/other_contour.py)
            other_out = previous_circle is not None and previous_circle.arcs_left_out
            if other_out:
                views = [(cam, cam.pixels_to_normalized(p)) for cam, p in ((cam_l, pl), (cam_r, pr))]
                keep_l, keep_r = on_circle(views, previous_circle)
                pl, pr, con_l, con_r = pl[keep_l], pr[keep_r], con_l[keep_l], con_r[keep_r]
            # and whether the points of faint edge step are (the same rule, without a second fit)
            faint_out = previous_circle is not None and previous_circle.faint_left_out
            if faint_out:
                keep_l, keep_r = not_faint(con_l), not_faint(con_r)
                pl, pr, con_l, con_r = pl[keep_l], pr[keep_r], con_l[keep_l], con_r[keep_r]
            settings = replace(LIVE_FIT, faint_test=previous_circle is None)
            circle = refine_circle(pl, pr, cam_l, cam_r, previous_circle or paper, contrast=(con_l, con_r),
                                   settings=settings, init_is_fitted=previous_circle is not None)
            circle = replace(circle, grazing_left_out=grazing_out, arcs_left_out=other_out,
                             faint_left_out=faint_out or circle.faint_left_out,
                             other_contour_mm=previous_circle.other_contour_mm if other_out else None)
            obs = WheelObservation(wheel, cams, (det_l, det_r), paper, circle)
            check_same_rim(obs, config)
        except StationError as e:
            obs, error = None, str(e)
    return LiveWheel(wheel, detections, obs, error, {"detect": t1 - t0, "reconstruct": time.perf_counter() - t1})


def rate_summary(times: list[dict], elapsed_s: float, interrupted: bool = False) -> dict:
    """Updates per second and the median time per stage (ms) of a live run."""
    out = {"updates": len(times), "elapsed_s": elapsed_s, "interrupted": interrupted,
           "rate_hz": len(times) / elapsed_s if elapsed_s > 0 and times else 0.0}
    for k in ("capture", "wheels", "detect", "reconstruct", "angles", "total"):
        vals = [t[k] for t in times if k in t]
        out[f"{k}_ms"] = float(np.median(vals) * 1e3) if vals else None
    return out


# --- the terminal display ---------------------------------------------------------------------
def format_reading(reading: Reading, spec=None, live_wheels=WHEELS) -> list[str]:
    """The display's lines: per live wheel toe and camber, the spec range and pass/fail."""
    lines = [f"{'wheel':<6}{'toe (deg)':>10}{'spec':>18}{'':>6}{'camber (deg)':>14}{'spec':>18}{'':>6}"]
    for w in live_wheels:
        if w not in reading.wheels:
            lines.append(f"{w:<6}  no reading: {reading.errors.get(w, 'not measured')}")
            continue
        line = f"{w:<6}"
        for kind in ("toe", "camber"):
            value = reading.wheels[w][f"{kind}_deg"]
            s = _angle_spec(spec, f"{w}.{kind}")
            line += f"{value:>+10.3f}" if kind == "toe" else f"{value:>+14.3f}"
            line += f"{_range(s):>18}{_verdict(s, value):>6}"
        if reading.truth_toe_deg and w in reading.truth_toe_deg:
            line += f"   (sim true toe {reading.truth_toe_deg[w]:+.3f})"
        lines.append(line)
    for axle, value in reading.total_toe_deg.items():
        s = _angle_spec(spec, f"{axle}.total_toe")
        lines.append(f"{axle} total toe {value:+.3f} deg  {_range(s)} {_verdict(s, value)}".rstrip())
    t = reading.timing_s
    if t:
        lines.append(f"update {reading.n}: {t['total'] * 1e3:.0f} ms (capture {t['capture'] * 1e3:.0f}, "
                     f"wheels {t['wheels'] * 1e3:.0f}; work: detect {t['detect'] * 1e3:.0f}, "
                     f"3-D {t['reconstruct'] * 1e3:.0f})")
    return lines


def _angle_spec(spec, name):
    """The AngleSpec of ``name`` ("FL.toe", "front.total_toe"); per-wheel names fall back to the
    axle's ("front.toe") for a spec written per axle."""
    if spec is None:
        return None
    if name in spec.angles:
        return spec.angles[name]
    wheel, _, kind = name.partition(".")
    axle = {"F": "front", "R": "rear"}.get(wheel[:1])
    return spec.angles.get(f"{axle}.{kind}") if axle else None


def _range(s) -> str:
    return "" if s is None else f"[{s.low_deg:+.2f}, {s.high_deg:+.2f}]"


def _verdict(s, value) -> str:
    if s is None:
        return ""
    return "OK" if s.check(value) else "ADJUST"
