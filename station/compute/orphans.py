"""What a killed station process leaves behind, and how its successors recognise it.

A process killed with SIGKILL (a watchdog, the OOM killer, a power button held down) runs no
cleanup: its unfinished files stay where they were being written. Every such file or folder
carries its owner's PID in its name, so the next process that owns the folder can tell a dead
owner's leftovers (removed) from a running process's work in progress (left alone).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path


def owner_alive(pid: int) -> bool:
    """Whether a process with this PID runs (another user's process counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_orphans(folder: Path, pattern: re.Pattern) -> int:
    """Remove the entries of ``folder`` whose name matches ``pattern`` (its ``pid`` group the
    owner's PID) and whose owner no longer runs; returns how many. A folder that cannot be read
    or written (missing, read-only) removes nothing and raises nothing."""
    removed = 0
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return 0
    for entry in entries:
        m = pattern.fullmatch(entry.name)
        if m is None or owner_alive(int(m.group("pid"))):
            continue
        try:
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            removed += 1
        except OSError:
            pass
    return removed
