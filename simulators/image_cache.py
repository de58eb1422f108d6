"""Rendered images kept on disk (.npz), stamped with the world that rendered them.

Rendering a vehicle's eight images takes seconds to minutes; the benchmarks and ``station
live`` keep them by seed. A cache is only valid for the station that rendered it: after a
change of the camera layout, a lens or the station seed, the same file name would hold
another station's images, and measuring them with this station's cameras gives errors of
degrees that look like a broken method. So every file holds the world's
:meth:`~simulators.world.SimWorld.fingerprint` and is read only by a world with the same one.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

STAMP = "_world"  # the key of the fingerprint in the .npz


def load(path: Path, world) -> dict[str, np.ndarray] | None:
    """{camera id: image} of every camera of the world from ``path``, or None when the file is
    missing, unreadable, rendered by another world or lacks a camera."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        with np.load(path) as z:
            if STAMP not in z.files or str(z[STAMP]) != world.fingerprint():
                return None
            return {c: z[c] for c in world.cameras}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None


def save(path: Path, images: dict[str, np.ndarray], world) -> None:
    """Write ``images`` to ``path`` with the world's stamp (a temporary file, then renamed:
    an interrupted write never leaves a half file under the real name)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.part.npz")
    np.savez(tmp, **images, **{STAMP: np.array(world.fingerprint())})
    tmp.replace(path)
