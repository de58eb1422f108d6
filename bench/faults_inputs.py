"""Fault bench section ``inputs``: corrupt calibrations, configurations and images, hostile job
ids and seeds (bench/faults.py --only inputs).

Every try runs ``station`` on a simulated station in a temporary folder: the named calibration
faults as real processes (``python -m station.cli``), the seeded random mutations in this
process (``station.cli.main``, the same code without the interpreter's start-up). A row counts

* ``correct``: refused with exit 2, a message naming the file or option and the field, no
  traceback; for a stored job id, every output (listing, CSV, report) free of control
  characters with the job shown;
* ``wrong``: a traceback, an internal error (exit 3), another exit code, a message that does not
  name what is wrong, an impossible value accepted, or a control character in an output;
* ``lost``: a stored job missing from an output;
* ``procs left`` / ``MiB left``: processes this section started (marked in their environment)
  still running afterwards, and their resident memory.

The random mutations set one field of a good file to a value no such field can hold (NaN,
infinity, 1e308, an integer of 400 digits, text for a number, a number for text, ...) or delete
a required key; the message must name that field.

    .venv/bin/python bench/faults.py --only inputs               # default tries (about 2 min)
    .venv/bin/python bench/faults.py --only inputs --tries 50
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import os
import random
import re
import subprocess
import sys
import tempfile
import uuid
from dataclasses import dataclass
from html import escape as html_escape
from pathlib import Path

import numpy as np
import yaml

from bench.faults import FaultRow

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "config" / "station.yaml"
MARK = "STATION_FAULTS_INPUTS"  # in the environment of every process this section starts
# what an output line must not carry (besides its own newline), and with the newline
_CONTROLS = "\x00-\x09\x0b-\x1f\x7f-\x9f\u200b-\u200f\u2028-\u202e\u2060-\u206f\ufeff\ud800-\udfff"
CONTROL = re.compile(f"[{_CONTROLS}]")
CONTROL_OR_NEWLINE = re.compile(f"[{_CONTROLS}\n]")
HOSTILE_NUMBERS = [float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 10**400, "1", None, [], {}, True]
HOSTILE_TEXT = [7, 1.5, None, [], {}, True]
HOSTILE_BOOL = [1, "true", None, []]
HOSTILE_MAPPING = ["text", 7, []]
CALIBRATION_REQUIRED = {"format", "format_version", "cameras", "pairs", "width", "height", "K", "dist",
                        "R_cam_station", "t_cam_station_m", "left", "right"}


@dataclass
class Outcome:
    code: int | str
    out: str
    err: str

    def refused(self, *needles: str) -> bool:
        """Exit 2, every needle in the message, no traceback, no internal error."""
        return (self.code == 2 and "Traceback" not in self.err and "internal error" not in self.err
                and all(n in self.err for n in needles))


class Bench:
    """A simulated station in a temporary folder and the two ways to run ``station`` on it."""

    def __init__(self, root: Path):
        self.root = root
        self.data = root / "data"
        self.env = {**os.environ, "STATION_DATA_DIR": str(self.data), "XDG_CACHE_HOME": str(root / "cache"),
                    MARK: uuid.uuid4().hex, "PYTHONPATH": str(ROOT)}
        self.env.pop("STATION_CONFIG", None)
        doc = yaml.safe_load(CONFIG.read_text())
        doc["vehicle_specs"] = str(CONFIG.parent / doc["vehicle_specs"])
        doc["calibration"]["box"] = str(CONFIG.parent / doc["calibration"]["box"])
        self.config_doc = doc
        self.config = root / "station.yaml"  # the shipped file's text, its neighbours' paths made absolute
        self.config.write_text(CONFIG.read_text()
                               .replace("vehicle_specs: vehicles.yaml", f"vehicle_specs: {doc['vehicle_specs']}")
                               .replace("box: box.yaml", f"box: {doc['calibration']['box']}"))
        self.calibration_doc = self._good_calibration()
        self.calibration = self.data / "calibration" / "station.calib.json"

    def _good_calibration(self) -> dict:
        """The simulated station's true cameras, with standard deviations and every pair's
        covariance (so that every field of the format is there to be damaged)."""
        from calibration.calib_file import CameraCalibration, StationCalibration
        from simulators.world import SimWorld
        from station.config import load_config

        with self.environment():
            config = load_config(self.config)
        world = SimWorld.from_config(config)
        std = {"fx": 0.1, "fy": 0.1, "cx": 0.2, "cy": 0.2, "k1": 1e-3, "k2": 1e-3, "p1": 1e-5, "p2": 1e-5,
               "k3": 1e-3, "position_m": [1e-4] * 3, "rotation_deg": [1e-3] * 3}
        cams = {c: CameraCalibration(m, 0.1, 1000, dict(std)) for c, m in world.cameras.items()}
        rng = np.random.default_rng(0)
        covs = {}
        for wheel in config.pairs:
            A = rng.normal(size=(30, 30)) * 1e-4
            covs[wheel] = A @ A.T
        calib = StationCalibration(cams, {w: (p.precision, p.reference) for w, p in config.pairs.items()},
                                   station_name=config.name, pair_covariance=covs)
        return json.loads(json.dumps(calib.to_dict()))

    @contextlib.contextmanager
    def environment(self):
        saved = dict(os.environ)
        os.environ.clear()
        os.environ.update(self.env)
        try:
            yield
        finally:
            os.environ.clear()
            os.environ.update(saved)

    def process(self, *argv: str) -> Outcome:
        run = subprocess.run([sys.executable, "-m", "station.cli", *argv], env=self.env, cwd=self.root,
                             capture_output=True, timeout=600)
        return Outcome(run.returncode, run.stdout.decode(errors="replace"), run.stderr.decode(errors="replace"))

    def inprocess(self, *argv: str) -> Outcome:
        from station.cli import main

        out, err = io.StringIO(), io.StringIO()
        with self.environment(), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(list(argv))
            except SystemExit as e:  # argparse's usage errors
                code = e.code
        return Outcome(code, out.getvalue(), err.getvalue())

    def write_calibration(self, content) -> None:
        self.calibration.parent.mkdir(parents=True, exist_ok=True)
        self.calibration.write_bytes(content if isinstance(content, bytes) else json.dumps(content).encode())

    def measure(self, run) -> Outcome:
        return run("--config", str(self.config), "measure", "--seed", "1", "--no-record")

    def left_behind(self) -> tuple[int, float]:
        """(processes carrying this section's mark, their resident MiB). This process is not
        counted, nor the forkserver and resource tracker an in-process measurement starts for
        it (multiprocessing keeps one of each per process; they end with it): the workers they
        start are."""
        mark = f"{MARK}={self.env[MARK]}".encode()
        n, kib = 0, 0
        for pid in filter(str.isdigit, os.listdir("/proc")):
            if int(pid) == os.getpid():
                continue
            try:
                if mark not in Path(f"/proc/{pid}/environ").read_bytes().split(b"\0"):
                    continue
                status = Path(f"/proc/{pid}/status").read_text()
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue
            ppid = next((int(line.split()[1]) for line in status.splitlines() if line.startswith("PPid:")), 0)
            if ppid == os.getpid() and (b"forkserver" in cmdline or b"resource_tracker" in cmdline):
                continue
            n += 1
            kib += next((int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:")), 0)
        return n, kib / 1024


def _row(bench: Bench, fault: str, outcomes) -> FaultRow:
    """A row from (correct, lost) per try; a try that is neither correct nor lost is wrong."""
    row = FaultRow(fault, 0)
    for correct, lost in outcomes:
        row.tries += 1
        row.correct += bool(correct)
        row.lost += bool(lost and not correct)
        row.wrong += not correct and not lost
    row.procs_left, row.mib_left = bench.left_behind()
    return row


# --- calibration files --------------------------------------------------------------------------
def _leaves(doc, path=()):
    """(path, value) of every leaf and container of a parsed JSON/YAML document."""
    yield path, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _leaves(v, path + (i,))


def _set(doc, path, value):
    doc = copy.deepcopy(doc)
    target = doc
    for k in path[:-1]:
        target = target[k]
    if value is KeyError:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return doc


def _field(path) -> str:
    """The dotted name a message gives a field: the path up to its first list index."""
    names = []
    for k in path:
        if isinstance(k, int):
            break
        names.append(str(k))
    return ".".join(names)


def _hostile(path, value, rng: random.Random, nullable=()):
    """A value no field like ``value`` (at ``path``) can hold, or KeyError (delete it) for a
    required key; None where the field is not one to damage this way."""
    name = path[-1] if path else None
    if isinstance(value, bool):
        return rng.choice(HOSTILE_BOOL)
    if isinstance(value, (int, float)):
        return rng.choice([v for v in HOSTILE_NUMBERS if not (v is None and name in nullable)])
    if isinstance(value, str):
        return rng.choice(HOSTILE_TEXT)
    if isinstance(value, (dict, list)) and path:
        return rng.choice(HOSTILE_MAPPING if isinstance(value, dict) else ["text", 7, {}])
    return None


def _random_mutations(doc: dict, n: int, seed: int, required: set, nullable=()):
    """n (path, mutated document) pairs, seeded: a hostile value in a random field, or a
    required key deleted."""
    rng = random.Random(seed)
    fields = [(p, v) for p, v in _leaves(doc) if p]
    out = []
    while len(out) < n:
        path, value = rng.choice(fields)
        if rng.random() < 0.15 and isinstance(path[-1], str) and path[-1] in required:
            out.append((path, _set(doc, path, KeyError)))
            continue
        bad = _hostile(path, value, rng, nullable)
        if bad is not None:
            out.append((path, _set(doc, path, bad)))
    return out


def calibration_rows(bench: Bench, tries: int | None) -> list[FaultRow]:
    good, path, rng = bench.calibration_doc, str(bench.calibration), random.Random(31)
    cams, wheels = list(good["cameras"]), list(good["pairs"])
    rows = []

    def refused(content, *needles):
        bench.write_calibration(content)
        return bench.measure(bench.process).refused("error 30", path, *needles), False

    n = tries or 8
    rows.append(_row(bench, 'calibration: "std": null', (
        refused(_set(good, ("cameras", c, "std"), None), f"cameras.{c}.std") for c in (cams * n)[:n])))
    numeric = [p for p, v in _leaves(good) if isinstance(v, float) and p[0] in ("cameras", "pairs")]
    rows.append(_row(bench, "calibration: NaN in a number", (
        refused(_set(good, p, float("nan")), _field(p)) for p in rng.sample(numeric, n))))
    focal = [("cameras", c, "K", i, i) for c in cams for i in (0, 1)]
    rows.append(_row(bench, "calibration: focal length 1e308", (
        refused(_set(good, p, 1e308), f"cameras.{p[1]}.K") for p in rng.sample(focal, min(n, len(focal))))))
    missing = [(("pairs",), "pairs: missing")] + [(("pairs", w), f"no pair {w}") for w in wheels]
    rows.append(_row(bench, "calibration: pairs missing", (
        refused(_set(good, p, KeyError), needle) for p, needle in (missing * n)[:max(n, len(missing))])))
    binary = [_binary(rng) for _ in range(n - 1)]
    rows.append(_row(bench, "calibration: binary file", (
        refused(b, "not UTF-8") for b in [b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR"] + binary)))
    text = json.dumps(good, indent=2).encode()
    rows.append(_row(bench, "calibration: truncated file", (
        refused(text[:rng.randrange(len(text) - 2)]) for _ in range(n))))
    m = tries or 200
    rows.append(_row(bench, f"calibration: random field mutation ({m} seeds)", (
        _mutation_refused(bench, doc, path, _field(p)) for p, doc in
        _random_mutations(good, m, seed=7, required=CALIBRATION_REQUIRED, nullable=("reprojection_rms_px",)))))
    bench.write_calibration(good)
    return rows


def _binary(rng: random.Random) -> bytes:
    """Random bytes that are not UTF-8 from the first one on (a continuation byte)."""
    return bytes([rng.randrange(0x80, 0xC0)] + [rng.randrange(256) for _ in range(rng.randint(0, 4095))])


def _mutation_refused(bench: Bench, doc: dict, path: str, field: str):
    bench.write_calibration(doc)
    return bench.measure(bench.inprocess).refused("error 30", path, field or "not a station calibration"), False


# --- configuration files ------------------------------------------------------------------------
def config_rows(bench: Bench, tries: int | None) -> list[FaultRow]:
    rng = random.Random(41)
    n, m = tries or 6, tries or 200
    target = bench.root / "bad.yaml"

    def history(content: bytes, *needles):
        target.write_bytes(content)
        return bench.process("--config", str(target), "history").refused("error 100", str(target), *needles), False

    rows = [_row(bench, "config: binary file", (
        history(_binary(rng), "is not text")
        for _ in range(n)))]
    text = bench.config.read_bytes()
    end = text.index(b"RR: {", text.index(b"fixture:")) + len(b"RR: {")  # every required key before here
    rows.append(_row(bench, "config: truncated file", (history(text[:rng.randrange(end)]) for _ in range(n))))

    def mutated(doc, field):
        target.write_text(yaml.safe_dump(doc))
        return bench.inprocess("--config", str(target), "history").refused("error 100", str(target), field), False

    rows.append(_row(bench, f"config: random field mutation ({m} seeds)", (
        mutated(doc, _field(p)) for p, doc in _random_mutations(bench.config_doc, m, seed=9, required=set()))))
    box_doc = yaml.safe_load((CONFIG.parent / "box.yaml").read_text())
    box = bench.root / "box.yaml"

    def box_mutated(doc, field):
        box.write_text(yaml.safe_dump(doc))
        cfg = bench.root / "box-station.yaml"
        cfg.write_text(yaml.safe_dump({**bench.config_doc, "calibration": {**bench.config_doc["calibration"],
                                                                            "box": str(box)}}))
        return bench.inprocess("--config", str(cfg), "box-print", "--out", str(bench.root / "print")).refused(
            "error 100", str(box), field), False

    k = tries or 50
    rows.append(_row(bench, f"box file: random field mutation ({k} seeds)", (
        box_mutated(doc, _field(p)) for p, doc in _random_mutations(box_doc, k, seed=11, required=set()))))
    return rows


# --- images -------------------------------------------------------------------------------------
def image_rows(bench: Bench, tries: int | None) -> list[FaultRow]:
    import cv2

    n, rng = tries or 10, random.Random(51)
    img = np.full((480, 640), 60, np.uint8)
    cv2.ellipse(img, (320, 240), (180, 150), 10, 0, 360, 200, 25)
    rows = []
    for suffix in (".png", ".jpg"):
        data = cv2.imencode(suffix, img)[1].tobytes()
        path = bench.root / f"cut{suffix}"

        def cut(size):
            path.write_bytes(data[:size])
            return bench.inprocess("detect", str(path)).refused("error 402", str(path)), False

        rows.append(_row(bench, f"image: truncated {suffix[1:].upper()}",
                         (cut(rng.randrange(1, len(data) - 4)) for _ in range(n))))
    good = bench.root / "wheel.png"
    cv2.imwrite(str(good), img)
    suffixes = [".xyz", ".exr", "", ".txt", ".json", ".pdf", ".svg", ".doc", ".csv", ".html"]

    def draw(suffix):
        out = bench.root / f"drawing{suffix}"
        ok = bench.inprocess("detect", str(good), "--draw", str(out)).refused("argument --draw", "use .png or .jpg")
        return ok and not out.exists(), False

    rows.append(_row(bench, "image: --draw with an unknown suffix", (draw(s) for s in (suffixes * n)[:max(n, 10)])))
    return rows


# --- job ids and seeds --------------------------------------------------------------------------
FIXED_JOBS = ["JOB\n2026-11-22T10:00:00      forged-line", "JOB\x1b[2J\x1b[31mRED", "JOB\r", "VIN\u202eLIVE",
              "JOB\x00", "JOB\x7f", "JOB\x9b1m", "A\u2028B", "JOB\u200bX"]
CONTROLS = [chr(c) for c in (*range(0, 32), *range(127, 160))] + ["\u2028", "\u2029", "\u202a", "\u202e", "\u2066",
                                                                 "\u200b", "\ufeff"]


def _hostile_jobs(n: int, seed: int) -> list[str]:
    rng = random.Random(seed)
    jobs = list(FIXED_JOBS)
    while len(jobs) < n:
        chars = list("".join(rng.choice("ABCDEFGHJKLMNPRSTUVWXYZ0123456789") for _ in range(17)))
        for _ in range(rng.randint(1, 3)):
            chars.insert(rng.randrange(len(chars) + 1), rng.choice(CONTROLS))
        jobs.append("".join(chars))
    return jobs[:n]


def _runs(job: str) -> list[str]:
    """The printable stretches of a job id: what any safe output must still show of it."""
    return [r for r in CONTROL_OR_NEWLINE.split(job) if r]


def job_rows(bench: Bench, tries: int | None) -> list[FaultRow]:
    n = tries or 30
    jobs = _hostile_jobs(n, seed=61)
    cfg = ("--config", str(bench.config))

    def at_input(job):
        o = bench.inprocess(*cfg, "measure", "--job", job, "--no-record")
        return o.refused("argument --job") and not CONTROL.search(o.err.replace("\n", " ")), False

    rows = [_row(bench, "job id with control characters: measure --job", (at_input(j) for j in jobs)),
            _row(bench, "job id with bytes not UTF-8: measure --job", (
                (bench.process(*cfg, "measure", "--job", os.fsdecode(b"JOB\xff\xfe")).refused("argument --job"), False)
                for _ in range(min(n, 3))))]
    _store_jobs(bench, jobs)
    listing = bench.inprocess(*cfg, "history", "--jobs").out
    cycles = bench.inprocess(*cfg, "history").out
    table = bench.inprocess(*cfg, "history", "--csv", "-").out
    safe = not any(CONTROL.search(o.replace("\n", " ")) for o in (listing, cycles, table))
    one_line_each = len(listing.splitlines()) == len(jobs) + 1 and len(table.splitlines()) == len(jobs) + 1

    def listed(job):
        shown = all(run in table for run in _runs(job))
        return safe and one_line_each and shown, not shown

    rows.append(_row(bench, "stored job id: history, --jobs, --csv", (listed(j) for j in jobs)))

    def report(job):
        out = bench.root / "report.html"
        o = bench.inprocess(*cfg, "report", job, "--out", str(out))
        html = out.read_text(errors="replace") if out.exists() else ""
        out.unlink(missing_ok=True)
        shown = all(html_escape(run) in html for run in _runs(job))
        return o.code == 0 and shown and not CONTROL.search(html.replace("\n", " ")), o.code == 0 and not shown

    rows.append(_row(bench, "stored job id: HTML report", (report(j) for j in jobs)))
    values = ["-1", "x", "1.5", "", "9" * 5000]
    seeds = [(c, v) for c in ("measure", "calibrate", "capture", "live") for v in values]
    rows.append(_row(bench, "--seed not a whole number from 0", (
        (bench.inprocess(*cfg, c, "--seed", v).refused("argument --seed"), False)
        for c, v in (seeds * n)[:max(n, len(seeds))])))
    return rows


def _store_jobs(bench: Bench, jobs: list[str]) -> None:
    """One failed cycle per job id in the history, as an older station could have stored it."""
    from station.records.history import History
    from station.result import Failure, Measurement

    for old in bench.data.glob("history.sqlite*"):  # only these cycles
        old.unlink()
    with bench.environment(), History(bench.data / "history.sqlite") as history:
        for i, job in enumerate(jobs):
            history.store(Measurement(station="bench", valid=False, failure=Failure(401, "no rim"), job_id=job,
                                      cycle_id=f"20261122T1000{i // 60:02d}Z-{i:04d}",
                                      time_utc=f"2026-11-22T10:{i // 60:02d}:{i % 60:02d}.000Z"))


def rows(tries: int | None) -> list[FaultRow]:
    with tempfile.TemporaryDirectory(prefix="station-faults-inputs-") as tmp:
        bench = Bench(Path(tmp))
        out = []
        for part in (calibration_rows, config_rows, image_rows, job_rows):
            print(f"  inputs: {part.__name__.removesuffix('_rows')} ...", file=sys.stderr, flush=True)
            out += part(bench, tries)
        return out


if __name__ == "__main__":
    from bench.faults import main

    sys.argv[1:1] = ["--only", "inputs"]
    sys.exit(main())
