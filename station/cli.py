"""The `station` command line: a thin dispatcher over station/commands/<name>.py.

Each command module provides ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int``. Errors the station knows (station.errors.CODED_ERRORS: the station's,
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
import importlib.util  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

from station.errors import CODED_ERRORS, user_message  # noqa: E402

# command name -> module under station.commands (listed only when the module exists)
COMMANDS = {
    "measure": "measure",
    "calibrate": "calibrate",
    "simulate": "simulate",
    "detect": "detect",
    "box-print": "box_print",
    "cameras": "cameras",
    "capture": "capture",
    "serve": "serve",
    "live": "live",
    "review": "review",
    "history": "history",
    "report": "report",
    "odometry": "odometry",
    "errors": "errors",
}

EXIT_ERROR = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130


def _available() -> dict[str, str]:
    return {name: mod for name, mod in COMMANDS.items()
            if importlib.util.find_spec(f"station.commands.{mod}") is not None}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="station", description="Wheel alignment station.")
    parser.add_argument("--config", metavar="PATH", help="station configuration (default: config/station.yaml, or $STATION_CONFIG)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod in _available().items():
        module = importlib.import_module(f"station.commands.{mod}")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def _crash_log(exc: BaseException) -> Path:
    log_dir = Path.home() / ".cache" / "station"
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except OSError:
        log_dir = Path("/tmp")
    path = log_dir / f"crash-{time.strftime('%Y%m%dT%H%M%S')}.log"
    path.write_text("".join(traceback.format_exception(exc)))
    return path


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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
