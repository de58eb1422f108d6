"""A trajectory built step by step (eq. 47), its position error against truth (eq. 49) and
drift (orientation and KITTI's segment errors: truth_errors.py).

World frame: the left camera at step 0 (the paper's choice). ``poses[i]`` is the 4x4 transform
from the left camera frame of step i to the world; its translation is the paper's ``B_i``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from station.errors import StorageError
from station.odometry.poses_io import write_poses


@dataclass
class Trajectory:
    """Poses (n+1, 4, 4), starting at the identity; one appended per step."""

    poses: list[np.ndarray] = field(default_factory=lambda: [np.eye(4)])

    def append(self, R_bar: np.ndarray, t_bar: np.ndarray) -> None:
        """Add step i with ``P_{i-1} = R_bar^T Q_i + t_bar``: eq. 47,
        ``B_i = B_{i-1} + (prod R_bar^T) t_bar``, and the orientation ``(prod R_bar^T) R_bar^T``."""
        prev = self.poses[-1]
        step = np.eye(4)
        step[:3, :3] = R_bar.T
        step[:3, 3] = t_bar
        self.poses.append(prev @ step)

    @property
    def positions(self) -> np.ndarray:
        """(n+1, 3) the paper's B_0..B_n, metres, world frame."""
        return np.array([T[:3, 3] for T in self.poses])

    def __len__(self) -> int:
        return len(self.poses)

    def write(self, path: str | Path) -> Path:
        """KITTI pose file (12 numbers per line), or CSV (step,x_m,y_m,z_m) for a .csv name."""
        path = Path(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            if path.suffix.lower() == ".csv":
                B = self.positions
                rows = "\n".join(f"{i},{x:.6f},{y:.6f},{z:.6f}" for i, (x, y, z) in enumerate(B))
                path.write_text("step,x_m,y_m,z_m\n" + rows + "\n")
            else:
                write_poses(path, np.array(self.poses))
        except OSError as e:
            raise StorageError(f"{path}: cannot write the trajectory ({e.strerror or e})",
                               hint="choose a writable file with --out") from e
        return path


def step_errors(B_est: np.ndarray, B_true: np.ndarray) -> np.ndarray:
    """Eq. 49: e_i = |B~_i - B_i| for every step both have, (n+1,) metres."""
    n = min(len(B_est), len(B_true))
    return np.linalg.norm(np.asarray(B_est)[:n] - np.asarray(B_true)[:n], axis=1)


def distance_travelled(B_true: np.ndarray) -> np.ndarray:
    """(n+1,) cumulative path length along the true positions, metres."""
    seg = np.linalg.norm(np.diff(np.asarray(B_true), axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


@dataclass(frozen=True)
class ErrorSummary:
    """mean_m, std_m, max_m: eq. 49 over steps 1..n (std with ddof=0); final_m: at step n;
    drift_pct: the final error in % of the distance travelled; max_drift_pct: the largest e_i / d_i over steps with
    d_i >= 1 m (NaN if none)."""

    n_steps: int
    mean_m: float
    std_m: float
    max_m: float
    final_m: float
    distance_m: float
    drift_pct: float
    max_drift_pct: float


def summarize(B_est: np.ndarray, B_true: np.ndarray) -> ErrorSummary:
    e = step_errors(B_est, B_true)
    d = distance_travelled(np.asarray(B_true)[:len(e)])
    steps = e[1:]
    far = d >= 1.0
    return ErrorSummary(
        n_steps=len(steps),
        mean_m=float(steps.mean()) if len(steps) else float("nan"),
        std_m=float(steps.std()) if len(steps) else float("nan"),
        max_m=float(steps.max()) if len(steps) else float("nan"),
        final_m=float(steps[-1]) if len(steps) else float("nan"),
        distance_m=float(d[-1]),
        drift_pct=float(100 * e[-1] / d[-1]) if d[-1] > 0 else float("nan"),
        max_drift_pct=float(np.max(100 * e[far] / d[far])) if far.any() else float("nan"))
