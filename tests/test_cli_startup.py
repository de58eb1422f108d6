"""`station --help` and a command's --help import none of the heavy libraries: commands import
what they need when they run (the time itself is bench/cli_startup.py's)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from station.cli import COMMANDS

HEAVY = ("numpy", "cv2", "rerun", "numba", "scipy", "pymodbus", "station.measure", "station.rim.detector")


def _imported_after(args: list[str]) -> set[str]:
    code = ("import sys, contextlib, io\n"
            "from station.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n"
            f"        main({args!r})\n"
            "    except SystemExit:\n"
            "        pass\n"
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    return set(out.stdout.split())


def test_station_help_imports_no_command_and_no_heavy_library():
    assert _imported_after(["--help"]) == set()


@pytest.mark.parametrize("command", ["measure", "calibrate", "calibration", "live", "review", "history", "serve", "simulate"])
def test_a_commands_help_imports_no_pipeline(command):
    assert command in COMMANDS
    heavy = _imported_after([command, "--help"]) - {"numpy"}  # numpy alone is cheap enough to allow
    assert heavy == set(), heavy


def test_an_unknown_command_is_an_error_naming_the_choices(capsys):
    from station.cli import main

    with pytest.raises(SystemExit) as e:
        main(["mesure"])
    assert e.value.code == 2
    assert "invalid choice: 'mesure'" in capsys.readouterr().err
