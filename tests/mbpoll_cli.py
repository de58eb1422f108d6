"""mbpoll, the third-party Modbus client the PLC tests drive the station with: one call, its
printed registers read back, and a register's value as a signed 16-bit integer."""

from __future__ import annotations

import re
import subprocess


def mbpoll(args: list[str], *values: int) -> subprocess.CompletedProcess:
    """mbpoll with 0-based addresses, one poll, a 2 s timeout, then ``args`` and ``values``."""
    return subprocess.run(["mbpoll", "-0", "-1", "-o", "2", *args, *map(str, values)],
                          capture_output=True, text=True, timeout=20)


def parse(out: str) -> dict[int, str]:
    """mbpoll's '[120]: \t0.243700' lines -> {120: '0.243700'}."""
    return {int(a): v.strip() for a, v in re.findall(r"^\[(\d+)\]:\s+(\S+)", out, re.M)}


def signed(v: str) -> int:
    n = int(v)
    return n - 65536 if n > 32767 else n
