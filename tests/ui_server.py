"""A `station ui` subprocess for the browser tests: its own data folder, a free loopback port."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

from tests.serve_process import free_port

ROOT = Path(__file__).resolve().parents[1]


class UiServer:
    """`station ui --seed SEED --adjust-steps N` on ``config`` (its data folder as
    STATION_DATA_DIR, crash logs under ``tmp``/cache, output in ``tmp``/server.log). Close it."""

    def __init__(self, config, tmp: Path, seed: int, adjust_steps: int = 3, timeout_s: float = 60.0):
        port = free_port()
        env = {**os.environ, "STATION_DATA_DIR": str(config.data_dir), "XDG_CACHE_HOME": str(tmp / "cache")}
        self.log_path = tmp / "server.log"
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", "station.cli", "--config", str(config.path), "ui",
                                      "--port", str(port), "--seed", str(seed), "--adjust-steps", str(adjust_steps)],
                                     cwd=ROOT, env=env, stdout=self._log, stderr=subprocess.STDOUT)
        self.base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                urllib.request.urlopen(self.base + "/api/session", timeout=2)
                return
            except urllib.error.HTTPError:  # it answers (401: a login is needed)
                return
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    self.close()
                    raise RuntimeError(self.log_path.read_text())
                time.sleep(0.2)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._log.close()
