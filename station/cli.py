"""The `station` command line: a thin dispatcher over station/commands/<name>.py.

Each command module provides ``add_arguments(parser)`` and ``run(args) -> int``; its one-line
help is in :data:`COMMANDS`, and only the command that runs is imported. Errors the station knows (station.errors.CODED_ERRORS: the station's,
the drivers', the calibration's) print one clear message and exit non-zero; anything
unexpected is logged with its traceback to a file, never to the terminal.
"""

from __future__ import annotations

import os

# Small (N,3) @ (3,3) products dominate our geometry; BLAS threads only contend with our own
# worker threads on a 2-core station PC (measured ~30x slower under load). Set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

from station.errors import CODED_ERRORS, user_message  # noqa: E402

# command name -> (module under station.commands, what it does in one line). Only the command
# that runs is imported: `station --help` needs none of them.
COMMANDS = {
    "measure": ("measure", "measure toe and camber of all four wheels (one cycle on the configured station)"),
    "calibrate": ("calibrate", "calibrate the eight cameras and four pairs with the calibration box"),
    "calibration": ("calibration_files", "import the calibration from OpenCV files, or export it to them"),
    "simulate": ("simulate", "render the simulated station with a random vehicle and save it as a replay set (+ truth)"),
    "detect": ("detect", "find the rim ellipse in a photograph of a wheel, or in each of several or a folder (PNG, JPEG, ...)"),
    "box-print": ("box_print", "write the calibration box's faces as PNG images at true scale for manufacturing"),
    "cameras": ("cameras", "list the configured cameras and their state (open, model, serial, resolution, last frame)"),
    "capture": ("capture", "capture one synchronised set from all cameras and save it (lossless PNG + metadata)"),
    "serve": ("serve", "serve the station to the shop PLC over Modbus TCP or RTU (register map: docs/plc.md)"),
    "live": ("live", "live toe and camber of one axle while a wheel is adjusted (Ctrl-C to stop)"),
    "caster": ("caster", "caster, SAI and included angle of the front wheels from a steering sweep"),
    "review": ("review", "open a cycle's recording in the Rerun viewer (default: the newest cycle)"),
    "history": ("history", "list the stored measurement cycles (filter by job, date, vehicle, pass/fail; export CSV)"),
    "report": ("report", "write the printable before/after report (HTML, optionally PDF) of a job"),
    "odometry": ("odometry", "stereo visual odometry of an image sequence (paper section 3.3)"),
    "ui": ("ui", "the technician's screen: a local web application for the whole job (docs/ui.md)"),
    "errors": ("errors", "list the station's error codes (the PLC's fault codes)"),
}

EXIT_ERROR = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command's name and help line; ``command``'s arguments too (its
    module imported, its ``run`` the parsed arguments' ``_run``)."""
    parser = argparse.ArgumentParser(prog="station", description="Wheel alignment station.")
    parser.add_argument("--config", metavar="PATH", help="station configuration (default: config/station.yaml, or $STATION_CONFIG)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (mod, text) in COMMANDS.items():
        p = sub.add_parser(name, help=text, description=text, add_help=name == command)
        if name == command:
            module = importlib.import_module(f"station.commands.{mod}")
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    return parser


def _command_of(argv: list[str]) -> str | None:
    """The command named in ``argv`` (the first argument that is one), else None."""
    probe = argparse.ArgumentParser(add_help=False)
    probe.add_argument("--config")
    probe.add_argument("command", nargs="?")
    known, _ = probe.parse_known_args(argv)
    return known.command if known.command in COMMANDS else None


def _crash_log(exc: BaseException) -> Path:
    log_dir = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "station"
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except OSError:
        log_dir = Path("/tmp")
    path = log_dir / f"crash-{time.strftime('%Y%m%dT%H%M%S')}.log"
    path.write_text("".join(traceback.format_exception(exc)))
    return path


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(_command_of(argv))
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return EXIT_ERROR
    try:
        return int(args._run(args) or 0)
    except CODED_ERRORS as e:
        print(user_message(e), file=sys.stderr)
        return EXIT_ERROR
    except BrokenPipeError:  # output piped into `head` and closed early: not an error
        return 0
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:  # noqa: BLE001 - the last line of defence: no traceback for users
        path = _crash_log(e)
        print(f"internal error: {type(e).__name__}: {e}\n  the details are in {path}; "
              "please send that file with the cycle's images", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
