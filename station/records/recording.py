"""Rerun recordings of measurement cycles: the one module that talks to Rerun.

One ``.rrd`` file per cycle, written by :class:`CycleRecorder`. Entity paths mirror the station
(frames and signs: docs/conventions.md; the full list: docs/recordings.md)::

    /                          station frame, right-handed, z up (ViewCoordinates, static)
    /station/<cam_id>          Transform3D (camera pose in the station frame) + Pinhole (OpenCV RDF)
    /station/<cam_id>/image    the camera's image, JPEG
    /station/<cam_id>/image/ellipse   detected rim ellipse (closed 2-D line strip, px)
    /station/<cam_id>/image/edges     edge points used by the fit (2-D points, px)
    /vehicle/<wheel>/rim       3-D rim points (m, station frame)
    /vehicle/<wheel>/center    wheel centre
    /vehicle/<wheel>/axis      outward spin axis (arrow from the centre)
    /vehicle/<wheel>/plane     the rim plane, drawn as the rim circle
    /vehicle/car_frame         the car frame's axes (arrows x', y', z')
    /angles/<name>             every angle (deg) as a scalar on the ``cycle`` timeline
    /events                    the sequencer's events (text log)
    /result                    the full result JSON (text document)

Writing never interrupts a measurement: a failure to write (read-only folder, full disk) is
latched, later calls become no-ops, the partial file is removed, and :meth:`CycleRecorder.close`
raises :class:`~station.errors.StorageError` once, after the caller has its result. The data
goes to a ``.<name>.<writer's PID>.part`` file beside the target and is renamed into place only
when complete; the first recorder of a process in a folder removes the ``.part`` files there
whose writer was killed (:func:`remove_unfinished_recordings`).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import socket
import threading
import time
import uuid
import warnings
from pathlib import Path
from urllib.parse import urlparse

import cv2
import numpy as np
import rerun as rr

from calibration.station_frame import AXLES, WHEELS
from station.compute.orphans import remove_orphans
from station.errors import StorageError
from station.records.history import finite_number, jsonable
from station.result import Measurement

_LEVELS = {"TRACE", "DEBUG", "INFO", "WARN", "ERROR", "CRITICAL"}
UNFINISHED = re.compile(r"\.(?P<name>.+\.rrd)\.(?P<pid>\d+)\.part")  # a recording being written
_swept_folders: set[Path] = set()  # folders this process has cleared of killed writers' .part files
_WHEEL_COLORS = {"FL": (230, 160, 40), "FR": (60, 170, 230), "RL": (200, 90, 200), "RR": (90, 200, 110)}
CONE_MAGNIFIED = 50.0  # the runout cone is a few tenths of a degree: drawn with its tilt magnified


def angle_values(result: Measurement) -> dict[str, float]:
    """The named angles of a result (deg), ``{"FL.toe": ..., "thrust": ...}``; missing ones left out.

    Also ``FL.toe_thrust`` / ``FR.toe_thrust`` (front toe against the thrust line) and the
    axles' ``setback_deg`` when present.
    """
    out: dict[str, float] = {}
    for w in WHEELS:
        r = result.wheels.get(w)
        for key in ("toe", "camber", "toe_thrust"):
            v = finite_number(getattr(r, f"{key}_deg", None))
            if v is not None:
                out[f"{w}.{key}"] = v
    for axle in AXLES:
        r = result.axles.get(axle)
        for key in ("total_toe", "setback"):
            v = finite_number(getattr(r, f"{key}_deg", None))
            if v is not None:
                out[f"{axle}.{key}"] = v
    v = finite_number(result.thrust_deg)
    if v is not None:
        out["thrust"] = v
    return out


def remove_unfinished_recordings(folder: str | os.PathLike) -> int:
    """Remove the ``.part`` files in ``folder`` whose writer was killed (its PID no longer runs);
    returns how many. A running process's recording is left alone."""
    return remove_orphans(Path(folder), UNFINISHED)


def recording_id_for(job_id: str | None) -> str | None:
    """A stable recording id for a job (UUID 5 of the job id), so the viewer merges the job's cycles."""
    return None if not job_id else str(uuid.uuid5(uuid.NAMESPACE_URL, f"station-job:{job_id}"))


def _cycle_number(stem: str) -> int:
    """``20261122T221500Z-0007`` -> 7 (the cycle counter ending a cycle id); 0 when there is none."""
    m = re.search(r"-(\d+)$", stem)
    return int(m.group(1)) if m else 0


def _points(a, ncols: int, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != ncols:
        raise ValueError(f"{what}: expected an (N,{ncols}) array, got shape {a.shape}")
    return a


def _vec3(a, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{what}: expected a 3-vector, got shape {a.shape}")
    return a


def circle_station(center: np.ndarray, axis: np.ndarray, radius_m: float, n: int = 97) -> np.ndarray:
    """(n,3) closed circle of ``radius_m`` about ``center`` in the plane normal to ``axis``."""
    w = axis / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(w[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    t = np.linspace(0.0, 2.0 * np.pi, n)
    return center + radius_m * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)


class CycleRecorder:
    """Log one cycle to ``path`` (an ``.rrd``); usable as a context manager.

    ``cycle`` is the sequence number on the ``cycle`` timeline (default: the counter ending the
    file name, e.g. ``...-0007.rrd`` -> 7). Give the cycles of one job the same ``recording_id``
    and the viewer merges their files into one recording, so the angle plots run over cycles.
    ``spawn_viewer`` or ``viewer_url`` also stream to a Rerun viewer (best effort: a missing
    viewer is a warning in :attr:`warnings`, never an error).
    """

    def __init__(self, path: str | os.PathLike, *, application: str = "station",
                 recording_id: str | None = None, jpeg_quality: int = 90,
                 spawn_viewer: bool = False, viewer_url: str | None = None,
                 cycle: int | None = None):
        self.path = Path(path)
        self.jpeg_quality = int(jpeg_quality)
        self.recording_id = recording_id or str(uuid.uuid4())
        self.error: StorageError | None = None
        self.warnings: list[str] = []
        self.bytes_written = 0
        self._result_events: set[tuple[str, str]] = set()  # (level, text) of the result's warnings
        self._sequencer_events: set[tuple[str, str]] = set()
        self._closed = False
        self._file = None
        self._part = self.path.with_name(f".{self.path.name}.{os.getpid()}.part")
        self._rec = rr.RecordingStream(application, recording_id=self.recording_id)
        self._stream = self._rec.binary_stream()
        self._recs = [self._rec]
        if spawn_viewer or viewer_url:
            self._attach_viewer(application, spawn_viewer, viewer_url)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if self.path.parent not in _swept_folders:
                _swept_folders.add(self.path.parent)
                remove_unfinished_recordings(self.path.parent)
            self._file = open(self._part, "wb")
        except OSError as e:
            self._fail(e, "cannot create the recording")
        self._cycle = _cycle_number(self.path.stem) if cycle is None else int(cycle)
        self._set_time()
        self._log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for rec in self._recs:
            rec.send_recording_name(self.path.stem)

    # -- plumbing ------------------------------------------------------------------------------
    def _attach_viewer(self, application, spawn, url):
        try:
            if url:
                # Rerun connects lazily and, when nobody listens, blocks ~6 s at shutdown: look first
                parsed = urlparse(url)
                with socket.create_connection((parsed.hostname or "127.0.0.1", parsed.port or 9876), timeout=0.3):
                    pass
            viewer = rr.RecordingStream(application, recording_id=self.recording_id)
            if url:
                viewer.connect_grpc(url)
            else:
                viewer.spawn(connect=True)
            self._recs.append(viewer)
        except Exception as e:  # noqa: BLE001 - a viewer is a convenience, never a failure
            self.warnings.append(f"Rerun viewer not available ({type(e).__name__}: {e}); recording to file only")

    def _fail(self, exc: OSError, doing: str) -> None:
        if self.error is None:
            reason = exc.strerror or str(exc)
            self.error = StorageError(
                f"{self.path}: {doing}: {reason}; the measurement is kept, this cycle has no recording",
                hint="check that the recordings folder exists, is writable and has free space")
            self.error.__cause__ = exc
        self._discard()

    def _discard(self) -> None:
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                pass
            self._file = None
        try:
            self._part.unlink()
        except OSError:
            pass

    def _set_time(self, when: float | None = None) -> None:
        when = time.time() if when is None else when
        for rec in self._recs:
            rec.set_time("cycle", sequence=self._cycle)
            rec.set_time("time", timestamp=when)

    def _log(self, entity: str, archetype, static: bool = False) -> None:
        for rec in self._recs:
            rec.log(entity, archetype, static=static)

    def _write_out(self) -> None:
        """Move the encoded recording from Rerun's buffer to the .part file (where a full disk shows).

        Rerun closes an RRD segment (footer, checksums) at every flush, and its reader rejects
        a file of several segments, so the buffer is read once, when the cycle is complete.
        """
        data = self._stream.read(flush=True) or b""
        self._rec.disconnect()
        data += self._stream.read(flush=False) or b""
        if self._file is None:
            return
        try:
            self._file.write(data)
            self.bytes_written += len(data)
        except OSError as e:
            self._fail(e, "cannot write the recording")

    @property
    def ok(self) -> bool:
        return self.error is None

    # -- what a cycle logs ---------------------------------------------------------------------
    def log_cameras(self, cameras: dict) -> None:
        """Each camera (a CameraModel) as a pinhole with its pose in the station frame."""
        for cam_id, cam in cameras.items():
            R = np.asarray(cam.R_cam_station, dtype=np.float64)
            K = np.asarray(cam.K, dtype=np.float64)
            entity = f"/station/{cam_id}"
            # Rerun's transform maps the child (camera) frame into the parent (station):
            # x_station = R_cam_station.T @ x_cam + C_station.
            self._log(entity, rr.Transform3D(translation=cam.center_station, mat3x3=R.T))
            self._log(entity, rr.Pinhole(image_from_camera=K, resolution=[cam.width, cam.height],
                                         camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3))

    def log_images(self, images: dict[str, np.ndarray]) -> None:
        """Camera images (H,W) uint8/uint16 mono or (H,W,3) RGB, JPEG at ``jpeg_quality``.

        Encoded with OpenCV's libjpeg-turbo (about 30 % faster here than Rerun's own
        ``Image.compress``, which goes through Pillow) and logged as an EncodedImage.
        """
        params = [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality]
        for cam_id, img in images.items():
            img = np.asarray(img)
            if img.dtype == np.uint16:
                img = (img >> 8).astype(np.uint8)
            if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
                raise ValueError(f"image {cam_id}: expected (H,W) or (H,W,3) 8/16-bit, got {img.shape} {img.dtype}")
            ok, jpeg = cv2.imencode(".jpg", img if img.ndim == 2 else img[:, :, ::-1], params)
            if not ok:
                raise ValueError(f"image {cam_id}: JPEG encoding failed")
            self._log(f"/station/{cam_id}/image", rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))

    def log_detection(self, cam_id: str, ellipse_points_px, edge_points_px) -> None:
        """Detected rim ellipse (N,2) px (drawn closed) and the edge points (M,2) px behind it."""
        ell = _points(ellipse_points_px, 2, "ellipse_points_px")
        edges = _points(edge_points_px, 2, "edge_points_px")
        if len(ell):
            ell = np.vstack([ell, ell[:1]])
            self._log(f"/station/{cam_id}/image/ellipse", rr.LineStrips2D([ell], colors=[(255, 60, 60)]))
        self._log(f"/station/{cam_id}/image/edges", rr.Points2D(edges, colors=[(255, 220, 0)], radii=0.8))

    def log_wheel(self, wheel: str, rim_points_station, center_station, axis_station, radius_m: float) -> None:
        """A wheel: rim points (N,3) m, centre (3,), outward spin axis (3,), rim radius (m)."""
        rim = _points(rim_points_station, 3, "rim_points_station")
        c = _vec3(center_station, "center_station")
        w = _vec3(axis_station, "axis_station")
        w = w / np.linalg.norm(w)
        color = _WHEEL_COLORS.get(wheel, (200, 200, 200))
        base = f"/vehicle/{wheel}"
        self._log(f"{base}/rim", rr.Points3D(rim, colors=[color], radii=0.002))
        self._log(f"{base}/center", rr.Points3D([c], colors=[color], radii=0.01, labels=[wheel]))
        self._log(f"{base}/axis", rr.Arrows3D(origins=[c], vectors=[w * max(radius_m, 0.1)], colors=[color]))
        self._log(f"{base}/plane", rr.LineStrips3D([circle_station(c, w, float(radius_m))], colors=[color]))

    def log_roll(self, wheel: str, centers_station, normals_station, spin_axis_station, radius_m: float,
                 face_points: int = 0) -> None:
        """Runout compensation of a wheel: its centre (K,3) and rim normal (K,3) at each roll
        position, the fitted spin axis (3,) from the last centre (its label says how many of the
        face's points joined it, station/wheel/face_motion.py), and the cone the rim normal
        sweeps about it, drawn at the last centre with the tilt magnified ``CONE_MAGNIFIED`` times."""
        cs = _points(centers_station, 3, "centers_station")
        ns = _points(normals_station, 3, "normals_station")
        a = _vec3(spin_axis_station, "spin_axis_station")
        a = a / np.linalg.norm(a)
        color = _WHEEL_COLORS.get(wheel, (200, 200, 200))
        base = f"/vehicle/{wheel}/runout"
        length = max(radius_m, 0.1)
        self._log(f"{base}/positions", rr.Points3D(cs, colors=[color], radii=0.006,
                                                   labels=[f"position {k + 1}" for k in range(len(cs))]))
        magnified = a + CONE_MAGNIFIED * (ns - a)
        self._log(f"{base}/rim_normals", rr.Arrows3D(origins=np.repeat(cs[-1:], len(ns), axis=0),
                                                     vectors=length * magnified, colors=[color]))
        self._log(f"{base}/spin_axis", rr.Arrows3D(origins=[cs[-1]], vectors=[a * length * 1.2],
                                                   colors=[(255, 255, 255)],
                                                   labels=[f"{wheel} spin axis (lip and {face_points} face points)"
                                                           if face_points else f"{wheel} spin axis (lip)"]))
        tilt = float(np.mean(np.arccos(np.clip(ns @ a, -1.0, 1.0))))
        tip_circle = circle_station(cs[-1] + length * a, a, length * np.tan(tilt) * CONE_MAGNIFIED)
        self._log(f"{base}/cone", rr.LineStrips3D([tip_circle], colors=[color]))

    def log_steering(self, wheel: str, centers_station, normals_station, axis_station, point_station,
                     radius_m: float) -> None:
        """A steering sweep of a front wheel: its centre (K,3) and rim normal (K,3) at each steer
        position, and the fitted steering axis (unit direction (3,), a point on it (3,)), drawn
        from the runway (z = 0) up past the wheel's top."""
        cs = _points(centers_station, 3, "centers_station")
        ns = _points(normals_station, 3, "normals_station")
        u = _vec3(axis_station, "axis_station")
        u = u / np.linalg.norm(u)
        p = _vec3(point_station, "point_station")
        color = _WHEEL_COLORS.get(wheel, (200, 200, 200))
        base = f"/vehicle/{wheel}/steering"
        self._log(f"{base}/positions", rr.Points3D(cs, colors=[color], radii=0.006,
                                                   labels=[f"position {k + 1}" for k in range(len(cs))]))
        self._log(f"{base}/rim_normals", rr.Arrows3D(origins=cs, vectors=ns * max(radius_m, 0.1), colors=[color]))
        ground = p - u * (p[2] / u[2])
        top = ground + u * (2.2 * float(np.max(cs[:, 2])) / u[2])
        self._log(f"{base}/axis", rr.LineStrips3D([[ground, top]], colors=[(255, 255, 255)],
                                                  labels=[f"{wheel} steering axis"]))

    def log_car_frame(self, origin, R_station_car) -> None:
        """The car frame: origin (3,) and R_station_car (3,3) whose columns are x', y', z'."""
        o = _vec3(origin, "origin")
        R = np.asarray(R_station_car, dtype=np.float64)
        if R.shape != (3, 3):
            raise ValueError(f"R_station_car: expected (3,3), got {R.shape}")
        self._log("/vehicle/car_frame", rr.Arrows3D(
            origins=np.repeat(o[None], 3, axis=0), vectors=R.T * 0.5,
            colors=[(255, 0, 0), (0, 200, 0), (0, 80, 255)], labels=["x'", "y'", "z'"]))

    def log_result(self, result: Measurement) -> None:
        """Every angle (deg) as a scalar on the ``cycle`` timeline, pass/fail and the full JSON."""
        when = _parse_time(result.time_utc)
        if when is not None:
            self._set_time(when)
        if result.valid:
            for name, value in angle_values(result).items():
                self._log(f"/angles/{name}", rr.Scalars(value))
        else:
            failure = result.failure
            code = None if failure is None else failure.code
            self._result_event(str((failure and failure.message) or f"cycle failed (error {code})"), "ERROR")
        passes = result.verdicts or {}
        if passes:
            bad = [k for k, v in passes.items() if k != "overall" and v is False]
            text = "PASS" if passes.get("overall") else "FAIL" + (f": {', '.join(bad)}" if bad else "")
            self._log("/events", rr.TextLog(text, level="INFO" if passes.get("overall") else "WARN"))
        for w in result.warnings:
            self._result_event(str(w), "WARN")
        self._log("/result", rr.TextDocument(json.dumps(jsonable(result.to_json()), indent=1), media_type="text/plain"))

    def _result_event(self, text: str, level: str) -> None:
        """A warning or failure of the result: logged once even if also sent through log_event."""
        if (level, text) not in self._result_events and (level, text) not in self._sequencer_events:
            self._result_events.add((level, text))
            self._log("/events", rr.TextLog(text, level=level))

    def log_event(self, text: str, level: str = "INFO") -> None:
        """One sequencer event, stamped with the current time on the ``time`` timeline.

        A warning or error identical to one the result already logged is not repeated.
        """
        level = level.upper()
        if level == "WARNING":
            level = "WARN"
        if level not in _LEVELS:
            level = "INFO"
        if (level, str(text)) in self._result_events:
            return
        if level in ("WARN", "ERROR"):
            self._sequencer_events.add((level, str(text)))
        for rec in self._recs:
            rec.set_time("time", timestamp=time.time())
        self._log("/events", rr.TextLog(str(text), level=level))

    # -- finishing -----------------------------------------------------------------------------
    def close(self) -> Path | None:
        """Finish the file and move it into place. Returns its path, or raises StorageError once."""
        if self._closed:
            return None if self.error else self.path
        self._closed = True
        if len(self._recs) > 1:  # let the viewer stream drain without holding up the cycle
            threading.Thread(target=_disconnect_all, args=(self._recs[1:],), daemon=True).start()
        if self.error is None:
            self._write_out()
        else:
            self._drop_buffer()
        if self.error is None:
            try:
                self._file.flush()
                os.fsync(self._file.fileno())
                self._file.close()
                self._file = None
                os.replace(self._part, self.path)
            except OSError as e:
                self._fail(e, "cannot finish the recording")
        if self.error is not None:
            raise self.error
        return self.path

    def abort(self) -> None:
        """Drop the recording (no file left)."""
        self._closed = True
        self._drop_buffer()
        self._discard()

    def _drop_buffer(self) -> None:
        self._rec.disconnect()
        self._stream.read(flush=False)

    def __enter__(self) -> "CycleRecorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            # the cycle itself failed: keep what was recorded (it explains the failure)
            try:
                self.close()
            except StorageError:
                pass


def _disconnect_all(recs) -> None:
    for rec in recs:
        try:
            rec.flush(timeout_sec=2.0)
            rec.disconnect()
        except Exception:  # noqa: BLE001 - the viewer is best effort
            pass


def _parse_time(text) -> float | None:
    if not isinstance(text, str):
        return None
    try:
        return _dt.datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()
    except ValueError:
        return None


# --- reading back -------------------------------------------------------------------------------
def read_recording_summary(path: str | os.PathLike) -> dict:
    """What a recording holds, read with Rerun's own reader.

    Returns ``{"path", "bytes", "application_id", "recording_id", "entities": {entity: rows},
    "images": n, "image_bytes": n, "scalars": {angle name: [values]}, "events": [(level, text)],
    "timelines": [...]}``. A missing or unreadable file raises StorageError.
    """
    path = Path(path)
    if not path.is_file():
        raise StorageError(f"{path}: no such recording", hint="`station history` lists the cycles and their recordings")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer": a truncated file, reported below if unreadable
            reader = rr.chunk.RrdReader(str(path))
        stores = list(reader.recordings())
        entities: dict[str, int] = {}
        scalars: dict[str, list[float]] = {}
        events: list[tuple[str, str]] = []
        timelines: set[str] = set()
        images = image_bytes = 0
        for chunk in reader.stream():
            ent = str(chunk.entity_path)
            if ent.startswith("/__"):
                continue
            n = int(chunk.num_rows)
            entities[ent] = entities.get(ent, 0) + n
            timelines.update(chunk.timeline_names)
            batch = chunk.to_record_batch()
            cols = {name: batch.column(i) for i, name in enumerate(batch.schema.names)}
            if "EncodedImage:blob" in cols:
                blobs = cols["EncodedImage:blob"].to_pylist()
                images += sum(1 for b in blobs if b)
                image_bytes += sum(len(x[0]) if x and isinstance(x[0], (bytes, list)) else 0 for x in blobs)
            if ent.startswith("/angles/") and "Scalars:scalars" in cols:
                for row in cols["Scalars:scalars"].to_pylist():
                    if row:
                        scalars.setdefault(ent[len("/angles/"):], []).extend(float(x) for x in row)
            if "TextLog:text" in cols:
                texts = cols["TextLog:text"].to_pylist()
                levels = cols["TextLog:level"].to_pylist() if "TextLog:level" in cols else [None] * len(texts)
                for lv, tx in zip(levels, texts):
                    events.append(((lv or [None])[0], (tx or [""])[0]))
    except StorageError:
        raise
    except Exception as e:  # noqa: BLE001 - Rerun's reader raises plain exceptions on bad files
        raise StorageError(f"{path}: not a readable Rerun recording ({type(e).__name__}: {e})",
                           hint="the file may be truncated; `rerun rrd verify FILE` checks it") from e
    first = stores[0] if stores else None
    return {
        "path": str(path), "bytes": path.stat().st_size,
        "application_id": getattr(first, "application_id", None),
        "recording_id": getattr(first, "recording_id", None),
        "entities": dict(sorted(entities.items())), "images": images, "image_bytes": image_bytes,
        "scalars": scalars, "events": events, "timelines": sorted(timelines),
    }
