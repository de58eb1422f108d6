"""`station review [CYCLE]`: open a cycle's Rerun recording in the viewer (or say how)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from station.config import load_config
from station.errors import StorageError
from station.records.history import History


def add_arguments(parser):
    parser.add_argument("cycle", metavar="CYCLE", nargs="?",
                        help="a cycle id, or an .rrd file (default: the newest recording)")
    parser.add_argument("--job", metavar="J", help="open every recording of this job together")
    parser.add_argument("--summary", action="store_true",
                        help="print what the recording holds instead of opening the viewer")


def _rerun_exe() -> str | None:
    local = Path(sys.executable).with_name("rerun")
    return str(local) if local.exists() else shutil.which("rerun")


def _find(config, args) -> list[Path]:
    folder = config.data_path("recordings")
    history_path = config.data_path("history.sqlite")
    if args.job:
        with History(history_path, read_only=True) as h:
            paths = [Path(r["recording"]) for r in h.query(job=args.job) if r.get("recording")]
        if not paths:
            raise StorageError(f"job {args.job!r}: no recordings in the history",
                               hint="`station history --jobs` lists the jobs")
        return paths
    if args.cycle:
        p = Path(args.cycle)
        if p.suffix == ".rrd" or p.exists():
            return [p]
        if history_path.exists():
            with History(history_path, read_only=True) as h:
                row = h.get(args.cycle)
            if row and row.get("recording"):
                return [Path(row["recording"])]
        candidate = folder / f"{args.cycle}.rrd"
        if candidate.exists():
            return [candidate]
        raise StorageError(f"cycle {args.cycle!r}: no recording found (looked in the history and {folder})",
                           hint="`station history` lists the cycles; recording may be off in config")
    files = sorted(folder.glob("*.rrd"), key=lambda p: p.stat().st_mtime) if folder.is_dir() else []
    if not files:
        raise StorageError(f"no recordings in {folder}", hint="run `station measure` first")
    return [files[-1]]


def _print_summary(path: Path) -> None:
    from station.records.recording import read_recording_summary  # (Rerun: imported when used)

    s = read_recording_summary(path)
    print(f"{path}  ({s['bytes'] / 1e6:.2f} MB, recording id {s['recording_id']})")
    print(f"  {s['images']} image(s), {len(s['entities'])} entities, timelines: {', '.join(s['timelines'])}")
    for name, values in sorted(s["scalars"].items()):
        print(f"  {name:<18} " + " ".join(f"{v:+.3f}" for v in values) + " deg")
    for level, text in s["events"]:
        print(f"  [{level}] {text}")


def run(args) -> int:
    config = load_config(args.config)
    paths = _find(config, args)
    missing = [p for p in paths if not p.exists()]
    if missing:
        raise StorageError(f"{missing[0]}: the recording is gone (moved or deleted)")
    exe = _rerun_exe()
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if args.summary or not has_display or exe is None:
        for p in paths:
            _print_summary(p)
        if not args.summary:
            files = " ".join(str(p) for p in paths)
            why = "no display here" if exe else "the rerun viewer is not installed"
            print(f"\n{why}. To look at it:\n"
                  f"  on a machine with a display:  rerun {files}\n"
                  f"  in a browser on this machine:  rerun --web-viewer --bind 127.0.0.1 {files}")
        return 0
    subprocess.Popen([exe, *map(str, paths)], start_new_session=True,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    print("opened in the Rerun viewer: " + ", ".join(str(p) for p in paths))
    return 0
