"""The Adjust page's live stream: updates per second that reach a client while all four wheels are
tracked, and the station's CPU use with and without the page open (issue 35).

    .venv/bin/python bench/ui_live.py                       # the 1.3-Mpx station (scale 1), 20 s
    .venv/bin/python bench/ui_live.py --scale 0.5 --browser # the tests' 0.33-Mpx station, + Chromium

A `station ui` subprocess serves the simulated station (vehicle --seed, its true cameras as the
calibration, in a temporary data folder; the simulated technician turns the FL tie rod through
--adjust-steps steps, rendered once before the loop starts). The station's CPU use is the
user + system time of the server and all its child processes (the measurement workers), from
/proc, over each window, as a share of one core; beside it the rest of the machine's busy time
(/proc/stat: this client, Chromium, and whatever else runs on the shared cores), which the
station's rate depends on. Windows:

1. no page open (the server idle);
2. one client on ``/api/live/stream?axle=all``: an SSE client in this process counting the
   messages (or with --browser the Adjust page in headless Chromium counting what it drew);
3. the page closed again (after the live loop's linger).

Prints a markdown table; docs/ui.md keeps it.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
TICK = os.sysconf("SC_CLK_TCK")


def tree_cpu_s(pid: int) -> float:
    """User + system CPU seconds of ``pid`` and its descendants alive now (and their reaped children)."""
    children: dict[int, list[int]] = {}
    stats: dict[int, list[str]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            text = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2:].split()
        stats[int(entry)] = fields
        children.setdefault(int(fields[1]), []).append(int(entry))
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        f = stats.get(p)
        if f is None:
            continue
        total += sum(int(x) for x in f[11:15]) / TICK  # utime stime cutime cstime
        todo += children.get(p, [])
    return total


def machine_busy_s() -> float:
    """CPU seconds all cores spent busy since boot (/proc/stat: everything but idle and iowait)."""
    fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(fields[:8]) - fields[3] - fields[4]) / TICK


def cpu_share(pid: int, seconds: float) -> tuple[float, float]:
    """(the station's, everything else's) CPU over ``seconds``, each as a share of one core."""
    c0, m0, t0 = tree_cpu_s(pid), machine_busy_s(), time.monotonic()
    time.sleep(seconds)
    dt = time.monotonic() - t0
    station = (tree_cpu_s(pid) - c0) / dt
    return station, max(0.0, (machine_busy_s() - m0) / dt - station)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class SseClient(threading.Thread):
    """Reads the live stream; counts reading messages (after the loop is live)."""

    def __init__(self, url: str):
        super().__init__(daemon=True)
        self.url = url
        self.state = None
        self.times: list[float] = []
        self.stop = False
        self.response = None

    def run(self):
        self.response = urllib.request.urlopen(self.url, timeout=600)
        try:
            self._read()
        except (OSError, AttributeError, ValueError):  # the stream closed under the reader (close())
            if not self.stop:
                raise

    def _read(self):
        event = None
        for raw in self.response:
            if self.stop:
                break
            line = raw.decode().rstrip("\n")
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                if event == "status":
                    self.state = json.loads(line[6:])["state"]
                else:
                    self.times.append(time.monotonic())
                event = None

    def close(self):
        self.stop = True
        try:
            self.response.close()
        except Exception:  # noqa: BLE001 - closing a stream the server may have closed
            pass


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=1.0, help="camera resolution and focal length x this (default 1)")
    ap.add_argument("--seconds", type=float, default=20.0, help="each window's length (default 20)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--adjust-steps", type=int, default=7)
    ap.add_argument("--browser", action="store_true", help="count in headless Chromium's Adjust page too")
    args = ap.parse_args()

    from tests.station_fixtures import small_station_config, truth_calibration

    tmp = Path(tempfile.mkdtemp(prefix="bench-ui-"))
    config = small_station_config(tmp, scale=args.scale)
    env = {**os.environ, "STATION_DATA_DIR": str(config.data_dir), "XDG_CACHE_HOME": str(tmp / "cache")}
    os.environ["STATION_DATA_DIR"] = str(config.data_dir)
    truth_calibration(config)
    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-m", "station.cli", "--config", str(config.path), "ui", "--port",
                             str(port), "--seed", str(args.seed), "--adjust-steps", str(args.adjust_steps)],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rows = []
    try:
        for _ in range(300):
            try:
                urllib.request.urlopen(base + "/api/session", timeout=2)
                break
            except OSError:
                time.sleep(0.2)
        time.sleep(2.0)
        rows.append(("no page open", None, cpu_share(proc.pid, args.seconds)))

        client = SseClient(base + "/api/live/stream?axle=all")
        client.start()
        while client.state != "live":  # the adjustment's frames rendered once, then the car frame
            if not client.is_alive():
                raise RuntimeError("the live stream ended before it was live")
            time.sleep(0.2)
        time.sleep(2.0)
        n0, t0 = len(client.times), time.monotonic()
        share = cpu_share(proc.pid, args.seconds)
        rate = (len(client.times) - n0) / (time.monotonic() - t0)
        rows.append(("Adjust stream open, all four wheels (SSE client)", rate, share))
        client.close()

        if args.browser:
            from tests.cdp import Browser

            b = Browser()
            try:
                page = b.page()
                page.goto(base + "/adjust")
                page.js("(() => { const s = document.querySelector('#axle'); s.value = 'all'; "
                        "s.dispatchEvent(new Event('change')); })()")
                page.wait("document.querySelector('#status').dataset.state === 'live'", timeout=300)
                time.sleep(2.0)
                n0, t0 = int(page.js("document.querySelector('#rate').dataset.updates || 0")), time.monotonic()
                share = cpu_share(proc.pid, args.seconds)
                n1 = int(page.js("document.querySelector('#rate').dataset.updates || 0"))
                rows.append(("Adjust page open in headless Chromium, all four wheels", (n1 - n0) / (time.monotonic() - t0),
                             share))
            finally:
                b.close()
        time.sleep(6.0)  # the live loop lingers 4 s after the last page, then closes the cameras
        rows.append(("page closed again", None, cpu_share(proc.pid, args.seconds)))
    finally:
        proc.terminate()
        proc.wait(60)
        shutil.rmtree(tmp, ignore_errors=True)
    w, h = config.cameras["cam1"].width, config.cameras["cam1"].height
    print(f"station ui on the simulated station at {w}x{h}, vehicle seed {args.seed}, {args.seconds:g} s per window, "
          f"{os.cpu_count()} cores; CPU = the server and its workers, share of one core\n")
    print("| window | updates/s received | station CPU | rest of the machine |")
    print("|---|---|---|---|")
    for name, rate, (share, rest) in rows:
        print(f"| {name} | {'-' if rate is None else f'{rate:.1f}'} | {share * 100:.0f} % | {rest * 100:.0f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
