"""Every test reads and writes only its own temporary folders, whatever the environment says.

A real station's ``STATION_DATA_DIR`` and ``STATION_CONFIG`` must not reach the tests (a test
would save its calibration over the station's, or measure with the station's configuration), and
the tests that use the default configuration (``data_dir: ../var``) must not write into the
repository. So ``STATION_DATA_DIR`` names a temporary folder, ``STATION_CONFIG`` is removed
(the default is the repository's config/station.yaml) and ``XDG_CACHE_HOME`` (where
``station`` writes its crash logs) is a temporary folder too: first for the whole session,
before any test module is imported (module and session fixtures build their stations then),
then a fresh one for each test. ``os.environ`` is changed, so subprocesses inherit it.
``tests/test_isolation.py`` runs tests with the variables pointing at a sentinel and checks it.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

_SESSION_ROOT: Path | None = None


def _isolate(root: Path, setenv) -> None:
    setenv("STATION_DATA_DIR", str(root / "data"))
    setenv("XDG_CACHE_HOME", str(root / "cache"))


def pytest_configure(config):
    global _SESSION_ROOT
    _SESSION_ROOT = Path(tempfile.mkdtemp(prefix="station-tests-"))
    os.environ.pop("STATION_CONFIG", None)
    _isolate(_SESSION_ROOT, os.environ.__setitem__)


def pytest_unconfigure(config):
    if _SESSION_ROOT is not None:
        shutil.rmtree(_SESSION_ROOT, ignore_errors=True)


@pytest.fixture(autouse=True)
def station_data_dir(tmp_path_factory, monkeypatch) -> Path:
    """This test's own STATION_DATA_DIR (created on first use, like a station's)."""
    root = tmp_path_factory.mktemp("station")
    monkeypatch.delenv("STATION_CONFIG", raising=False)
    _isolate(root, monkeypatch.setenv)
    return root / "data"
