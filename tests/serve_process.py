"""Servers the tests start as processes: a free loopback port for them, and `station serve
--dry-run` running while a test drives it (the PLC simulator, mbpoll, a Modbus client)."""

from __future__ import annotations

import socket
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def dry_run_serve(port: int, *args: str):
    """`station serve --dry-run --port PORT ARGS...` (text pipes), yielded once it says it
    listens there; killed on the way out if it has not ended by then."""
    serve = subprocess.Popen([sys.executable, "-m", "station.cli", "serve", "--dry-run", "--port", str(port), *args],
                             cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = serve.stdout.readline()
        assert f"Modbus TCP 127.0.0.1:{port}" in line, line + serve.stderr.read()
        yield serve
    finally:
        if serve.poll() is None:
            serve.kill()
