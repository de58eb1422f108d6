"""KITTI pose files: one line per image, the 3x4 ``[R|t]`` of the left camera at that image in
the left camera frame of image 0, row-major, 12 numbers (docs/odometry.md). The truth we read
and the trajectories we write.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from station.errors import OdometryError

POSE_HINT = "a KITTI pose file: one line per image, 12 numbers (the 3x4 [R|t], row-major)"
ROTATION_TOL = 1e-2   # |R^T R - I|: KITTI's files print 6-7 significant digits


def parse_rows(text: str, what: str, n_values: int = 12) -> tuple[np.ndarray, list[int]]:
    """Lines of ``n_values`` numbers -> (N, n_values) array and each row's line number (1-based).

    Blank lines are skipped; a line with another count or a word that is not a number raises
    OdometryError naming ``what`` and the line."""
    rows, line_nos = [], []
    for no, line in enumerate(text.splitlines(), 1):
        words = line.split()
        if not words:
            continue
        if len(words) != n_values:
            raise OdometryError(f"{what} line {no}: {len(words)} numbers, expected {n_values}",
                                hint=POSE_HINT)
        try:
            rows.append([float(w) for w in words])
        except ValueError:
            bad = next(w for w in words if not _is_number(w))
            raise OdometryError(f"{what} line {no}: {bad!r} is not a number", hint=POSE_HINT) from None
        line_nos.append(no)
    return np.array(rows, float).reshape(-1, n_values), line_nos


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _read(path: Path) -> tuple[np.ndarray, list[int]]:
    """(N,4,4) transforms of a KITTI pose file and each one's line number."""
    path = Path(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise OdometryError(f"{path}: not a text file", hint=POSE_HINT) from None
    except OSError as e:
        raise OdometryError(f"{path}: cannot read the poses ({e.strerror or e})", hint=POSE_HINT) from e
    rows, line_nos = parse_rows(text, str(path))
    if not len(rows):
        raise OdometryError(f"{path}: no poses in the file", hint=POSE_HINT)
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :] = rows.reshape(-1, 3, 4)
    return T, line_nos


def read_poses(path: str | Path) -> np.ndarray:
    """KITTI pose file -> (N,4,4) camera-to-first-camera transforms (12 numbers per line, checked;
    the 3x3 blocks as they are: the paper's trajectories are not exactly rotations)."""
    return _read(Path(path))[0]


def read_truth(path: str | Path) -> np.ndarray:
    """A ground-truth pose file: :func:`read_poses`, and a rotation in every 3x3 block.
    Raises OdometryError naming the file and line."""
    T, line_nos = _read(Path(path))
    R = T[:, :3, :3]
    off = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero(~(off <= ROTATION_TOL))
    if len(bad):
        raise OdometryError(f"{path} line {line_nos[bad[0]]}: the first 3 columns are not a rotation "
                            f"(|R^T R - I| = {off[bad[0]]:.3g}); {len(bad)} such line(s)", hint=POSE_HINT)
    return T


def write_poses(path: str | Path, T: np.ndarray) -> None:
    """(N,4,4) transforms -> KITTI pose file (12 numbers per line)."""
    lines = [" ".join(f"{v:.9e}" for v in M[:3].ravel()) for M in np.asarray(T)]
    Path(path).write_text("\n".join(lines) + ("\n" if lines else ""))


def rebase(T: np.ndarray, T_truth_cam: np.ndarray | None = None) -> np.ndarray:
    """Poses (N,4,4) re-expressed from the first one: ``T_0^-1 T_i``; with ``T_truth_cam``
    (4,4: maps the camera's coordinates into those of the camera the poses describe), the
    poses of the camera instead: ``X^-1 T_0^-1 T_i X``."""
    T = np.asarray(T, float)
    out = np.linalg.solve(T[0], T)          # T_0^-1 @ T_i, batched
    if T_truth_cam is not None:
        out = np.linalg.inv(T_truth_cam) @ out @ T_truth_cam
    return out
