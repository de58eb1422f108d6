"""A Rerun recording (.rrd) of an odometry run: paths, the camera, the points of each step.

Entities (world = the left camera at step 0, OpenCV axes: x right, y down, z forward)::

    /world                       ViewCoordinates RDF (static)
    /world/truth/path            the true path (static), when known
    /world/<method>/path         the estimated path up to the step (line strip)
    /world/<method>/camera       the left camera's pose at the step (Transform3D + Pinhole)
    /world/<method>/points       the 3-D points the step used (world frame)
    /error/<method>              eq. 49 error per step (m, scalar)

Time line: ``step``. The file is written beside the target as ``.part`` and renamed at the end.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import rerun as rr

from station.errors import StorageError
from station.odometry.pipeline import MethodRun
from station.odometry.sequence_io import StereoSequence

COLORS = {"paper": (230, 120, 40), "robust": (40, 160, 230), "truth": (90, 200, 90)}


def write_recording(path: str | Path, seq: StereoSequence, runs: dict[str, MethodRun]) -> Path:
    """Write the runs (and the truth, if any) to ``path``. Raises StorageError if it cannot."""
    path = Path(path)
    part = path.with_name(path.name + ".part")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        rec = rr.RecordingStream("station-odometry")
        rec.save(str(part))
        rec.log("/world", rr.ViewCoordinates.RDF, static=True)
        B_true = None if seq.truth is None else seq.truth[:, :3, 3]
        if B_true is not None:
            rec.log("/world/truth/path", rr.LineStrips3D([B_true], colors=[COLORS["truth"]]), static=True)
        K = seq.left.K
        for m, run in runs.items():
            rec.log(f"/world/{m}/camera", rr.Pinhole(image_from_camera=K,
                                                      resolution=[seq.left.width, seq.left.height],
                                                      camera_xyz=rr.ViewCoordinates.RDF,
                                                      image_plane_distance=0.2), static=True)
            poses = run.trajectory.poses
            B = run.trajectory.positions
            for k, T in enumerate(poses):
                rec.set_time("step", sequence=k)
                rec.log(f"/world/{m}/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
                rec.log(f"/world/{m}/path", rr.LineStrips3D([B[:k + 1]], colors=[COLORS.get(m, (200, 200, 200))]))
                if k >= 1 and k - 1 < len(run.steps):
                    rec.log(f"/world/{m}/points", rr.Points3D(run.steps[k - 1].points_world, radii=0.01,
                                                              colors=[COLORS.get(m, (200, 200, 200))]))
                if B_true is not None and k < len(B_true):
                    rec.log(f"/error/{m}", rr.Scalars(float(np.linalg.norm(B[k] - B_true[k]))))
        rec.flush()
        rec.disconnect()
        os.replace(part, path)
    except (OSError, RuntimeError, ValueError) as e:
        try:
            part.unlink()
        except OSError:
            pass
        raise StorageError(f"{path}: cannot write the Rerun recording ({e})",
                           hint="check the folder exists and is writable") from e
    return path
