"""A measurement cycle on the assembled station: capture, keep, measure, record, store.

:class:`Station` is assembled once from the configuration (cameras through the driver
registry, the calibration file); nothing below asks whether it is simulated: the sim://
driver brings its simulated station through ``drivers.registry.build_context``, and the
truth it adds reaches the cycle through ``drivers.context.Simulation``. Everything a cycle
produces is kept: the frames (even of a failed cycle), the result JSON, the Rerun
recording and the history row; a failure to keep the frames, record or store (a full or
read-only disk) becomes a warning on the result (flag ``not_kept``), never a lost
measurement.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from calibration.calib_file import StationCalibration, load_calibration, software_version
from calibration.errors import CalibrationMismatch
from drivers.context import DriverContext
from drivers.registry import build_context
from station.capture.cameras import close_cameras, open_station_cameras, open_trigger_board
from station.capture.exposure_bracket import measure_bracketed
from station.capture.linearity import response_warnings
from station.capture.saving import capture_and_keep, keep_capture, new_cycle_id, remove_unfinished_captures
from station.capture.sync import capture_averaged
from station.compute.workers import WorkerPool, default_workers
from station.config import StationConfig
from station.errors import CODED_ERRORS, ProcedureError, StationError, StorageError, WheelLeftView
from station.measure import measure_frames
from station.operator import AlignmentOperator
from station.procedures.runout import MIN_POSITIONS, ROLL_DISTANCE_M, ROLL_PLAN, compensated, wheel_rolls
from station.procedures.runout_store import apply_kept_runout_to, keep_runout
from station.procedures.steering import DEFAULT_SWEEP_DEG, STEER_PLAN, steering_geometry, sweep_poses
from station.records.atomic_file import write_text_atomic
from station.result import Failure, Measurement, WarningFlag
from station.sequencer import Sequencer


def _say(msg: str) -> None:
    print(msg, flush=True)


def open_capture(config: StationConfig, context: DriverContext):
    """Open the cameras and the trigger board: (cameras, board or None, capture deadline s).
    The simulated cameras may ask for a longer deadline than the configured one."""
    cameras = open_station_cameras(config, context)
    try:
        board = open_trigger_board(config, context)
    except CODED_ERRORS:
        close_cameras(cameras)
        raise
    return cameras, board, max(config.capture.timeout_s, context.capture_timeout_s)


def close_capture(workers: WorkerPool | None, cameras: dict, board, context: DriverContext) -> None:
    """Release what a station or a live session holds: its worker processes (or None), the
    cameras and trigger board of ``open_capture`` and the driver context."""
    if workers is not None:
        workers.close()
    close_cameras(cameras)
    if board is not None:
        board.close()
    context.close()


class Station:
    """Cameras + calibration of one configured station. Use as a context manager."""

    def __init__(self, config: StationConfig, *, seed: int | None = None,
                 calibration: StationCalibration | None = None, progress: Callable[[str], None] = _say,
                 workers: int | None = None):
        """workers: measurement worker processes (station/compute/workers.py); None: one per
        core, 0 or 1: none (the four wheels run in two threads of this process)."""
        self.config = config
        self.progress = progress
        remove_unfinished_captures(config.data_path("captures"))  # of a station process killed mid-save
        self.calibration = calibration or load_calibration(config.calibration_file, config)
        self.models = {cid: self.calibration.model(cid) for cid in config.cameras}
        uris = [c.uri for c in config.cameras.values()]
        self.context = build_context(uris, config, seed=seed)
        self.cameras, self.trigger_board, self.timeout_s = open_capture(config, self.context)
        self.cycle_count = 0
        self.sequencer = Sequencer()  # the cycle's states: idle, capturing, measuring, reporting, done, fault
        n = default_workers() if workers is None else workers
        self.workers = WorkerPool(n) if n > 1 else None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        close_capture(self.workers, self.cameras, self.trigger_board, self.context)

    # --- one cycle --------------------------------------------------------------------------
    def measure(self, *, job_id: str | None = None, vehicle_spec: str | None = None,
                method: str = "circle", record: bool = True, store: bool = True,
                compensate: AlignmentOperator | None = None, roll_distance_m: float = ROLL_DISTANCE_M) -> Measurement:
        """Run one cycle through the sequencer's states (station/sequencer.py) and return its
        result. A capture that fails gives an invalid result, kept in the history, and leaves
        the sequencer in fault. A vehicle spec that cannot be applied is raised after the cycle
        is kept (with a warning saying so).

        ``compensate``: measure with runout compensation (station/procedures/runout.py): this
        operator rolls the car ``roll_distance_m`` back and forward between the captures, and the
        runout found is kept with the job (station/procedures/runout_store.py). Without it, a
        runout kept for ``job_id`` is applied when the wheels can still be followed."""
        cycle = _Cycle(new_cycle_id(), job_id, vehicle_spec, record and self.config.recording.enabled, store,
                       time.perf_counter())
        if compensate is None:
            return self._run(cycle, lambda: self._capture(cycle), lambda frames: self._measure(cycle, frames, method))
        return self._run(cycle, lambda: self._capture_positions(cycle, self._roll_moves(compensate, roll_distance_m)),
                         lambda captures: self._measure_rolled(cycle, captures, method))

    def caster(self, operator: AlignmentOperator, *, sweep_deg: float = DEFAULT_SWEEP_DEG, job_id: str | None = None,
               vehicle_spec: str | None = None, method: str = "circle", record: bool = True,
               store: bool = True) -> Measurement:
        """A steering sweep (station/procedures/steering.py): the operator steers the front wheels
        ``sweep_deg`` left, right and back to straight ahead; the result is the last capture's
        measurement (a runout kept for ``job_id`` applied) with caster, SAI and included angle
        (``steering``). A refused sweep is an invalid result with its code, kept."""
        cycle = _Cycle(new_cycle_id(), job_id, vehicle_spec, record and self.config.recording.enabled, store,
                       time.perf_counter())
        return self._run(cycle, lambda: self._capture_positions(cycle, self._steer_moves(operator, sweep_deg)),
                         lambda captures: self._measure_steered(cycle, captures, method, sweep_deg))

    def _run(self, cycle: _Cycle, capture: Callable, measure: Callable) -> Measurement:
        try:
            result = self.sequencer.run_cycle(capture=capture, measure=measure,
                                              report=lambda measured: self._report(cycle, measured))
        except CODED_ERRORS:
            if cycle.failed is None:
                raise
            return cycle.failed
        if cycle.spec_error is not None:
            raise cycle.spec_error
        return result

    def _capture(self, cycle: _Cycle, part: str | None = None) -> dict:
        """The cycle's frames (of one ``part`` of a procedure: a folder of the cycle's captures).
        A failed capture's result is kept (``cycle.failed``) and its error raised."""
        cfg = self.config
        cycle.truth = self.context.simulation.truth() if self.context.simulation else None
        captures_dir = cfg.data_path("captures", cycle.cycle_id, *([part] if part else []))
        n = cfg.capture.frames_averaged
        self.progress(f"cycle {cycle.cycle_id}: capturing {len(self.cameras)} cameras"
                      + (f", {n} frames each (averaged)" if n > 1 else "") + (f" ({part})" if part else ""))
        try:
            if cfg.capture.keep_captures:
                frames, kept = capture_and_keep(self.cameras, self.timeout_s, captures_dir, truth=cycle.truth,
                                                trigger_board=self.trigger_board, extra={"job_id": cycle.job_id},
                                                frames_averaged=n)
            else:
                frames, kept = capture_averaged(self.cameras, self.timeout_s, self.trigger_board, frames=n), None
        except CODED_ERRORS as e:
            self._keep_failure(cycle, e, getattr(e, "kept", None))
            raise
        if kept is not None:
            cycle.captures_dir = str(kept.path.parent if part and kept.path else kept.path) if kept.path else None
            cycle.not_kept = cycle.not_kept or kept.warning
        return frames

    def _retake(self, cycle: _Cycle, ids: list[str], factor: float, failed: list[str]) -> dict:
        """The cameras ``ids`` taken again at ``factor`` times their configured exposure (with
        the hardware-triggered others where a trigger board fires them all; their frames left):
        {camera id: image} of ``ids``, kept in the cycle's ``exposure-<factor>`` folder. A
        capture or camera that fails leaves {} and a sentence in ``failed``: the cycle goes on
        with the frames it has."""
        cfg = self.config
        n = cfg.capture.frames_averaged
        self.progress(f"cycle {cycle.cycle_id}: the rim's lip is at the sensor's white in {', '.join(ids)}: "
                      f"taking {'them' if len(ids) > 1 else 'it'} again at {factor:g}x the exposure")
        configured = {c: self.cameras[c].settings.exposure_us for c in ids}
        frames = {}
        try:
            for c in ids:
                self.cameras[c].configure(exposure_us=configured[c] * factor)
            cameras = {c: cam for c, cam in self.cameras.items()  # and those the board's pulse reaches
                       if c in ids or (self.trigger_board is not None and cam.settings.trigger == "hardware")}
            frames = capture_averaged(cameras, self.timeout_s, self.trigger_board, frames=n)
        except CODED_ERRORS as e:
            failed.append(f"{', '.join(ids)} could not be taken again at {factor:g}x the exposure ({e}); measured "
                          "on the frames taken before")
        finally:
            for c in ids:
                try:
                    self.cameras[c].configure(exposure_us=configured[c])
                except CODED_ERRORS as e:
                    failed.append(f"{c}: its exposure could not be set back to {configured[c]:g} us ({e}): "
                                  f"restart the station before the next cycle")
        frames = {c: frames[c] for c in ids if c in frames}
        if frames and cfg.capture.keep_captures and cycle.captures_dir:
            kept = keep_capture(frames, Path(cycle.captures_dir) / f"exposure-{factor:g}", truth=cycle.truth,
                                extra={"job_id": cycle.job_id, "exposure_factor": factor})
            cycle.not_kept = cycle.not_kept or kept.warning
        return {c: f.image for c, f in frames.items()}

    def _keep_failure(self, cycle: _Cycle, error, kept=None) -> None:
        """A cycle that ends before it is measured (a capture, a roll not confirmed): its invalid
        result is kept in the history (``cycle.failed``), with where its frames are."""
        result = Measurement(station=self.config.name, failure=Failure(error.code, str(error), error.hint))
        self._stamp(result, cycle)
        result.captures_dir = str(kept.path) if kept and kept.path else cycle.captures_dir
        if kept and kept.error:
            _not_kept(result, kept.warning)
        self._finish(result, record=False, store=cycle.store)
        cycle.failed = result

    def _capture_positions(self, cycle: _Cycle, moves: list[tuple[str, Callable[[], None]]]) -> list[dict]:
        """The frames where the car stands, then after each of ``moves`` ((what the operator is
        asked, the operator's action)): one set per position, each in its own folder."""
        captures = []
        for k in range(len(moves) + 1):
            if k:
                text, move = moves[k - 1]
                self.progress(f"cycle {cycle.cycle_id}: step {k} of {len(moves)}: {text}")
                try:
                    move()
                except CODED_ERRORS as e:  # a move not confirmed (the PLC's timeout): kept like a failed capture
                    self._keep_failure(cycle, e)
                    raise
            captures.append(self._capture(cycle, f"position-{k + 1}"))
            cycle.truths.append(cycle.truth)
        return captures

    def _roll_moves(self, operator: AlignmentOperator, distance_m: float) -> list[tuple[str, Callable[[], None]]]:
        """The roll plan's moves (runout compensation)."""
        steps = [(b - a) * distance_m for a, b in zip(ROLL_PLAN, ROLL_PLAN[1:])]
        return [(f"roll the car {'forward' if d > 0 else 'back'} {abs(d) * 100:.3g} cm",
                 lambda d=d: operator.roll_car(d)) for d in steps]

    def _steer_moves(self, operator: AlignmentOperator, sweep_deg: float) -> list[tuple[str, Callable[[], None]]]:
        """The steering plan's moves (station caster)."""
        targets = [p * sweep_deg for p in STEER_PLAN[1:]]
        return [(f"steer {'straight ahead' if t == 0 else f'{abs(t):g} deg ' + ('left' if t > 0 else 'right')}",
                 lambda t=t: operator.steer(t)) for t in targets]

    def _measure_rolled(self, cycle: _Cycle, captures: list[dict], method: str) -> Measurement:
        """Each position measured, then the spin axes (station/procedures/runout.py): the last
        position's result with toe and camber of the spin axes. A position other than the last
        that fails is left out with a warning while ``MIN_POSITIONS`` remain; the last (the
        result's) failing, fewer remaining, or a procedure the checks refuse, gives an invalid
        result naming why."""
        results = []
        for frames, truth in zip(captures, cycle.truths):
            cycle.truth = truth  # each position's result against the car as it stood then
            results.append(self._measure(cycle, frames, method, apply_kept_runout=False, refuse_uncertain=False))
        bad = [k for k, r in enumerate(results) if not r.valid]
        if bad and (bad[-1] == len(results) - 1 or len(results) - len(bad) < MIN_POSITIONS):
            failed = results[bad[-1]]
            failed.warnings.insert(0, f"runout compensation: position {bad[-1] + 1} of {len(results)} failed")
            return failed
        left_out = [f"runout compensation: position {k + 1} of {len(results)} left out ({results[k].failure.message})"
                    for k in bad]
        results = [r for k, r in enumerate(results) if k not in bad]
        captures = [c for k, c in enumerate(captures) if k not in bad]
        cycle.positions = results
        result = results[-1]
        result.warnings[:0] = left_out
        t0 = time.perf_counter()
        images = [{cid: f.image for cid, f in frames.items()} for frames in captures]
        try:
            rolls = wheel_rolls(results, images, self.models, self.config)
        except ProcedureError as e:
            failed = self._failed_result(cycle, e)
            failed.warnings.append("runout compensation refused; the rim-plane values of the last position are "
                                   "not reported")
            return failed
        result = compensated(result, rolls, self.config)
        result.timing_s["runout"] = time.perf_counter() - t0
        result.timing_s["capture"] = results[-1].timing_s["capture"]
        cycle.rolls = rolls
        if result.valid:  # a spin axis less certain than the limit leaves nothing to keep for the job
            try:
                keep_runout(self.config, result, rolls, images[-1], self.models)
            except StorageError as e:
                _not_kept(result, f"{e}; later measurements of this job cannot apply the runout")
        if cycle.truth is not None:
            result.add_truth(cycle.truth)
        return result

    def _measure_steered(self, cycle: _Cycle, captures: list[dict], method: str, sweep_deg: float) -> Measurement:
        """Each steer position measured, then the steering axes: the last (straight-ahead)
        position's result, a runout kept for the job applied, with ``steering``. A position that
        fails (a rim the cameras lost), or a sweep the checks refuse, gives an invalid result."""
        results = []
        for k, (frames, truth) in enumerate(zip(captures, cycle.truths)):
            cycle.truth = truth
            last = k == len(captures) - 1  # the straight-ahead capture, whose toe and camber are reported
            results.append(self._measure(cycle, frames, method, apply_kept_runout=last, refuse_uncertain=last))
        cycle.positions = results
        bad = next((k for k, r in enumerate(results) if not r.valid), None)
        if bad is not None:
            target = STEER_PLAN[bad] * sweep_deg
            e = WheelLeftView(f"capture {bad + 1} of {len(results)} (steered {target:+g} deg) failed: "
                              f"{results[bad].failure.message}",
                              hint="steer less far (--sweep), or check that the cameras see both front rims, and "
                                   "measure again")
            return self._failed_result(cycle, e)
        t0 = time.perf_counter()
        images = [{cid: f.image for cid, f in frames.items()} for frames in captures]
        try:
            sweep = sweep_poses(results, images, self.models, self.config)
        except ProcedureError as e:
            return self._failed_result(cycle, e)
        result = results[-1]
        result.steering = steering_geometry(result, sweep, results, sweep_deg)
        result.timing_s["steering"] = time.perf_counter() - t0
        cycle.sweep = sweep
        if cycle.truth is not None:
            result.add_truth(cycle.truth)
        return result

    def _failed_result(self, cycle: _Cycle, error) -> Measurement:
        """A procedure's invalid result: its code, sentence and hint."""
        failed = Measurement(station=self.config.name, failure=Failure(error.code, str(error), error.hint))
        self._stamp(failed, cycle)
        failed.captures_dir = cycle.captures_dir
        return failed

    def _measure(self, cycle: _Cycle, frames: dict, method: str, apply_kept_runout: bool = True,
                 refuse_uncertain: bool = True) -> Measurement:
        t_capture = time.perf_counter() - cycle.t0
        self.progress(f"cycle {cycle.cycle_id}: detecting rims and rebuilding the wheels")

        def measure(images: dict) -> Measurement:
            return measure_frames(images, self.models, self.config, method=method, workers=self.workers,
                                  calibration_cov=self.calibration.pair_covariance, refuse_uncertain=refuse_uncertain)

        # a procedure's positions are measured as taken: its captures are compared with each other
        steps = self.config.capture.exposure_steps if refuse_uncertain else ()
        retake_failed: list[str] = []
        result, cycle.images, _ = measure_bracketed({cid: f.image for cid, f in frames.items()}, measure,
                                                    lambda ids, factor: self._retake(cycle, ids, factor, retake_failed),
                                                    steps)
        result.warnings += retake_failed
        for cid, text in response_warnings(frames, self.config):  # a camera's grey not proportional to light
            result.warn(text, WarningFlag("response", self.config.cameras[cid].wheel, camera=cid))
        self._stamp(result, cycle)
        result.timing_s["capture"] = t_capture
        result.captures_dir = cycle.captures_dir
        if apply_kept_runout and result.valid and cycle.job_id:
            result = apply_kept_runout_to(self.config, result, cycle.images, self.models)
        if cycle.not_kept:
            _not_kept(result, cycle.not_kept)
        if cycle.truth is not None:
            result.add_truth(cycle.truth)
        return result

    def _report(self, cycle: _Cycle, result: Measurement) -> Measurement:
        """Pass/fail against the vehicle spec, then the recording and the history. A spec that
        cannot be applied becomes a warning on the kept cycle (``cycle.spec_error``)."""
        if cycle.vehicle_spec and result.valid:
            try:
                _apply_spec(self.config, result, cycle.vehicle_spec)
            except StationError as e:
                cycle.spec_error = e
                result.warnings.append(f"vehicle spec {cycle.vehicle_spec!r}: {e}")
        self._finish(result, record=cycle.record, store=cycle.store, images=cycle.images, cycle=cycle)
        result.timing_s["total"] = time.perf_counter() - cycle.t0
        self.cycle_count += 1
        return result

    def calibration_check(self) -> Measurement:
        """A PLC's calibration check: one cycle whose verdict is whether every pair still fits
        its calibration (the epipolar residual of the rim points within the configured limit)."""
        result = self.measure(job_id="calibration-check", record=True, store=True)
        drift = [f.text or f"pair {f.wheel}: a camera may have moved" for f in result.warning_flags if f.kind == "drift"]
        if result.valid and drift:
            raise CalibrationMismatch("; ".join(drift), hint="recalibrate with `station calibrate`")
        return result

    def _stamp(self, result: Measurement, cycle: _Cycle) -> None:
        """The cycle's identity on its result."""
        result.cycle_id = cycle.cycle_id
        result.time_utc = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        result.software_version = software_version()
        result.calibration_id = self.calibration.calibration_id
        result.job_id, result.vehicle_spec = cycle.job_id, cycle.vehicle_spec

    def _finish(self, result: Measurement, *, record: bool, store: bool, images: dict | None = None,
                cycle: _Cycle | None = None) -> None:
        t0 = time.perf_counter()
        if record:
            path = self.config.data_path("recordings", f"{result.cycle_id}.rrd")
            try:
                _record(path, self, result, images or {}, cycle)
                result.recording = str(path)
            except StorageError as e:
                _not_kept(result, str(e))
        if store:
            try:
                from station.records.history import open_history
                with open_history(self.config) as history:
                    history.store(result)
                    if history.last_queued:  # kept on this PC; sent when the server answers again
                        result.warn(f"the history server did not take this cycle now ({history.where}); it waits "
                                    f"in the station's outbox ({history.queued()} cycle(s)) and is sent once it answers")
            except StorageError as e:
                _not_kept(result, f"{e}; the measurement is kept, this cycle is not in the history")
        result.timing_s["record_and_store"] = time.perf_counter() - t0


@dataclass
class _Cycle:
    """What one cycle knows as it goes: its ids and options, the truth (simulation), its
    images, and how it ended early (a failed capture's result, a vehicle spec's error)."""

    cycle_id: str
    job_id: str | None
    vehicle_spec: str | None
    record: bool
    store: bool
    t0: float
    truth: dict | None = None
    truths: list = field(default_factory=list)  # runout compensation: the truth at each position
    captures_dir: str | None = None
    not_kept: str | None = None  # why the frames could not be kept (a full or read-only disk)
    images: dict | None = None
    positions: list[Measurement] | None = None  # a procedure: each position's result
    rolls: dict | None = None               # and each wheel's WheelRoll (station/procedures/runout.py)
    sweep: dict | None = None               # a steering sweep: each front wheel's WheelSweep
    failed: Measurement | None = None
    spec_error: StationError | None = None


def _not_kept(result: Measurement, sentence: str) -> None:
    """A part of the cycle's record (images, recording, history row) that the data disk refused."""
    result.warn(sentence, WarningFlag("not_kept"))


def _apply_spec(cfg: StationConfig, result: Measurement, key: str) -> None:
    from station.records.vehicle_specs import apply_spec, get_spec, load_vehicle_specs

    specs = load_vehicle_specs(cfg.vehicle_specs_path)
    apply_spec(result, get_spec(specs, key, cfg.vehicle_specs_path))


def _record(path: Path, station: Station, result: Measurement, images: dict, cycle: _Cycle | None = None) -> None:
    """The cycle's Rerun recording; of a procedure (``cycle``'s positions), each wheel's poses
    and the fitted runout cone or steering axis too."""
    from station.records.recording import CycleRecorder, recording_id_for

    rec = CycleRecorder(path, jpeg_quality=station.config.recording.jpeg_quality,
                        recording_id=recording_id_for(result.job_id))
    with rec:
        rec.log_cameras(station.models)
        if images:
            rec.log_images(images)
        for wheel, o in result.observations.items():
            for cam_id, det in zip(o.cams, o.detections):
                rec.log_detection(cam_id, det.ellipse.points(180), det.points_px)
            rec.log_wheel(wheel, o.paper.points_station, o.circle.center_station, o.circle.axis_station,
                          o.circle.radius_m)
        for wheel, r in ((cycle and cycle.rolls) or {}).items():
            circles = [p.observations[wheel].circle for p in cycle.positions]
            rec.log_roll(wheel, [c.center_station for c in circles], [c.axis_station for c in circles],
                         r.spin.axis_station, float(circles[-1].radius_m), r.face_points)
        for wheel, sw in ((cycle and cycle.sweep) or {}).items():
            circles = [p.observations[wheel].circle for p in cycle.positions]
            rec.log_steering(wheel, [c.center_station for c in circles], [c.axis_station for c in circles],
                             sw.axis.direction_station, sw.axis.point_station, float(circles[-1].radius_m))
        if result.alignment_frame:
            rec.log_car_frame(result.alignment_frame["origin_station_m"], result.alignment_frame["R_station_align"])
        rec.log_result(result)


def write_json(result: Measurement, path: str | Path) -> Path:
    """Write a result as JSON atomically (temp file + rename). OSError -> StorageError."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return write_text_atomic(path, json.dumps(result.to_json(), indent=1, default=_json_default))
    except OSError as e:
        raise StorageError(f"{path}: cannot write the result JSON: {e.strerror or e}",
                           hint="choose a folder for --json that is writable and has free space") from e


def _json_default(o):
    import numpy as np
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
