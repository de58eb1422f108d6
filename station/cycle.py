"""A measurement cycle on the assembled station: capture, keep, measure, record, store.

:class:`Station` is assembled once from the configuration (cameras through the driver
registry, the calibration file); nothing below asks whether it is simulated: the sim://
driver brings its world through ``drivers.registry.build_context``. Everything a cycle
produces is kept: the frames (even of a failed cycle), the result JSON, the Rerun
recording and the history row; a failure to record or store becomes a warning on the
result, never a lost measurement.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

from calibration.calib_file import StationCalibration, load_calibration
from calibration.errors import CalibrationMismatch
from drivers.registry import build_context
from station.capture.cameras import close_cameras, open_station_cameras, open_trigger_board
from station.capture.saving import capture_and_save, new_cycle_id
from station.capture.sync import capture_averaged
from station.config import StationConfig
from station.records.atomic_file import write_text_atomic
from station.errors import CODED_ERRORS, StationError, StorageError
from station.measure import add_truth, measure_frames
from station.compute.workers import WorkerPool, default_workers

SOFTWARE_NAME = "wheel-alignment-station"


def _say(msg: str) -> None:
    print(msg, flush=True)


def open_capture(config: StationConfig, context: dict):
    """Open the cameras and the trigger board: (cameras, board or None, capture deadline s).
    The simulated cameras may ask for a longer deadline than the configured one."""
    cameras = open_station_cameras(config, context)
    try:
        board = open_trigger_board(config, context)
    except CODED_ERRORS:
        close_cameras(cameras)
        raise
    return cameras, board, max(config.capture.timeout_s, float(context.get("capture_timeout_s", 0)))


class Station:
    """Cameras + calibration of one configured station. Use as a context manager."""

    def __init__(self, config: StationConfig, *, seed: int | None = None,
                 calibration: StationCalibration | None = None, progress: Callable[[str], None] = _say,
                 workers: int | None = None):
        """workers: measurement worker processes (station/compute/workers.py); None: one per
        core, 0 or 1: none (the four wheels run in two threads of this process)."""
        self.config = config
        self.progress = progress
        self.calibration = calibration or load_calibration(config.calibration_file, config)
        self.models = {cid: self.calibration.model(cid) for cid in config.cameras}
        uris = [c.uri for c in config.cameras.values()]
        self.context = build_context(uris, config, seed=seed)
        self.cameras, self.trigger_board, self.timeout_s = open_capture(config, self.context)
        self.cycle_count = 0
        n = default_workers() if workers is None else workers
        self.workers = WorkerPool(n) if n > 1 else None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self.workers is not None:
            self.workers.close()
        close_cameras(self.cameras)
        if self.trigger_board is not None:
            self.trigger_board.close()
        self.context.get("close", lambda: None)()

    # --- one cycle --------------------------------------------------------------------------
    def measure(self, *, job_id: str | None = None, vehicle_spec: str | None = None,
                method: str = "circle", record: bool = True, store: bool = True) -> dict:
        """Run one cycle and return the result dict (docs/result-schema.md)."""
        cfg = self.config
        cycle_id = new_cycle_id()
        t0 = time.perf_counter()
        truth_fn = self.context.get("truth")
        truth = truth_fn() if truth_fn else None
        captures_dir = cfg.data_path("captures", cycle_id)
        n = cfg.capture.frames_averaged
        self.progress(f"cycle {cycle_id}: capturing {len(self.cameras)} cameras"
                      + (f", {n} frames each (averaged)" if n > 1 else ""))
        try:
            if cfg.capture.keep_captures:
                frames, _ = capture_and_save(self.cameras, self.timeout_s, captures_dir, truth=truth,
                                                     trigger_board=self.trigger_board, extra={"job_id": job_id},
                                                     frames_averaged=n)
            else:
                frames = capture_averaged(self.cameras, self.timeout_s, self.trigger_board, frames=n)
        except CODED_ERRORS as e:
            saved = getattr(e, "saved_to", None)
            result = self._base(cycle_id, job_id, vehicle_spec)
            result["failure"] = {"code": e.code, "message": str(e), "hint": e.hint}
            result["captures_dir"] = str(saved) if saved else None
            self._finish(result, record=False, store=store)
            return result
        t_capture = time.perf_counter() - t0
        self.progress(f"cycle {cycle_id}: detecting rims and rebuilding the wheels")
        images = {cid: f.image for cid, f in frames.items()}
        result = measure_frames(images, self.models, cfg, method=method, workers=self.workers,
                                calibration_cov=self.calibration.pair_covariance)
        result.update(self._base(cycle_id, job_id, vehicle_spec))
        result["timing_s"]["capture"] = t_capture
        result["captures_dir"] = str(captures_dir) if cfg.capture.keep_captures else None
        if truth is not None:
            add_truth(result, truth)
        spec_error = None
        if vehicle_spec and result["valid"]:
            try:
                _apply_spec(cfg, result, vehicle_spec)
            except StationError as e:  # the measurement is still kept; the caller gets the error
                spec_error = e
                result["warnings"].append(f"vehicle spec {vehicle_spec!r}: {e}")
        self._finish(result, record=record and cfg.recording.enabled, store=store, images=images)
        result["timing_s"]["total"] = time.perf_counter() - t0
        self.cycle_count += 1
        if spec_error is not None:
            raise spec_error
        return result

    def calibration_check(self) -> dict:
        """A PLC's calibration check: one cycle whose verdict is whether every pair still fits
        its calibration (the epipolar residual of the rim points within the configured limit)."""
        result = self.measure(job_id="calibration-check", record=True, store=True)
        drift = [w for w in result.get("warnings", []) if "epipolar residual" in w]
        if result["valid"] and drift:
            raise CalibrationMismatch("; ".join(drift), hint="recalibrate with `station calibrate`")
        return result

    def _base(self, cycle_id, job_id, vehicle_spec) -> dict:
        from calibration.calib_file import software_version
        return {"cycle_id": cycle_id,
                "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "station": self.config.name, "software_version": software_version(),
                "calibration_id": self.calibration.calibration_id,
                "job_id": job_id, "vehicle_spec": vehicle_spec}

    def _finish(self, result: dict, *, record: bool, store: bool, images: dict | None = None) -> None:
        observations = result.pop("_observations", None)
        t0 = time.perf_counter()
        if record:
            path = self.config.data_path("recordings", f"{result['cycle_id']}.rrd")
            try:
                _record(path, self, result, images or {}, observations or {})
                result["recording"] = str(path)
            except StorageError as e:
                result.setdefault("warnings", []).append(str(e))
        if store:
            try:
                from station.records.history import History
                with History(self.config.data_path("history.sqlite")) as history:
                    history.store(result)
            except StorageError as e:
                result.setdefault("warnings", []).append(str(e))
        result.setdefault("timing_s", {})["record_and_store"] = time.perf_counter() - t0


def _apply_spec(cfg: StationConfig, result: dict, key: str) -> None:
    from station.records.vehicle_specs import apply_spec, get_spec, load_vehicle_specs

    specs = load_vehicle_specs(cfg.vehicle_specs_path)
    apply_spec(result, get_spec(specs, key, cfg.vehicle_specs_path))


def _record(path: Path, station: Station, result: dict, images: dict, observations: dict) -> None:
    from station.records.recording import CycleRecorder, recording_id_for

    rec = CycleRecorder(path, jpeg_quality=station.config.recording.jpeg_quality,
                        recording_id=recording_id_for(result.get("job_id")))
    with rec:
        rec.log_cameras(station.models)
        if images:
            rec.log_images(images)
        for wheel, o in observations.items():
            for cam_id, det in zip(o.cams, o.detections):
                rec.log_detection(cam_id, det.ellipse.points(180), det.points_px)
            rec.log_wheel(wheel, o.paper.points_station, o.circle.center_station, o.circle.axis_station,
                          o.circle.radius_m)
        frame = result.get("alignment_frame")
        if frame:
            rec.log_car_frame(frame["origin_station_m"], frame["R_station_align"])
        rec.log_result(result)


def write_json(result: dict, path: str | Path) -> Path:
    """Write a result as JSON atomically (temp file + rename). OSError -> StorageError."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return write_text_atomic(path, json.dumps(result, indent=1, default=_json_default))
    except OSError as e:
        raise StorageError(f"{path}: cannot write the result JSON: {e.strerror or e}; the cycle is "
                           "kept in the history", hint="choose a writable folder for --json") from e


def _json_default(o):
    import numpy as np
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
