"""bench/layers.py: the repository's layers point down and its modules import no cycle; and the
check does find an upward import and a cycle when there is one."""

from __future__ import annotations

from pathlib import Path

from bench.layers import check, print_report

REPO = Path(__file__).resolve().parent.parent


def _tree(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_the_repository_has_no_upward_import_and_no_cycle():
    report = check(REPO)
    assert len(report.modules) > 100 and len(report.imports) > 300  # it did read the packages
    assert [f"{imp.where()}: {why}" for imp, why in report.violations] == []
    assert [" -> ".join(i.source for i in cycle) for cycle in report.cycles] == []


def test_finds_an_upward_import_and_a_two_module_cycle(tmp_path, capsys):
    root = _tree(tmp_path, {
        "calibration/__init__.py": "",
        "calibration/geometry.py": "import numpy as np\n\nfrom station.errors import ConfigError\n",
        "station/__init__.py": "",
        "station/errors.py": "def late():\n    from station import config\n",
        "station/config.py": "import station.errors\n",
    })
    report = check(root)
    assert [(imp.source, imp.target, imp.where()) for imp, _ in report.violations] == [
        ("calibration.geometry", "station.errors", "calibration/geometry.py:3")]
    assert len(report.cycles) == 1
    cycle = report.cycles[0]
    assert [(i.source, i.target, i.where()) for i in cycle] == [
        ("station.config", "station.errors", "station/config.py:1"),
        ("station.errors", "station.config", "station/errors.py:2")]
    print_report(report)
    out = capsys.readouterr().out
    assert "calibration/geometry.py:3: layer violation" in out and "station/errors.py:2" in out
    assert "1 layer violation(s), 1 import cycle(s)" in out


def test_reads_every_kind_of_import(tmp_path):
    """Relative, inside a function, under TYPE_CHECKING, a submodule by ``from pkg import``, a
    test helper by its plain name, and a module the table does not place."""
    root = _tree(tmp_path, {
        "station/__init__.py": "",
        "station/rim/__init__.py": "",
        "station/rim/edges.py": ("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n"
                                 "    from ..wheel import fit\n"),
        "station/rim/hough.py": "def vote():\n    from . import edges\n    import synthetic_wheel\n",
        "station/wheel/__init__.py": "",
        "station/wheel/fit.py": "from station.rim import hough\n",
        "station/gadget.py": "",
        "tests/synthetic_wheel.py": "",
    })
    report = check(root)
    found = {(imp.source, imp.target, imp.line) for imp, _ in report.violations}
    assert found == {("station.rim.edges", "station.wheel.fit", 4),
                     ("station.rim.hough", "tests.synthetic_wheel", 3),
                     ("station.gadget", "station.gadget", 1)}
    assert ("station.rim.hough", "station.rim.edges", 2) in {(i.source, i.target, i.line) for i in report.imports}
    assert [sorted(i.source for i in c) for c in report.cycles] == [
        ["station.rim.edges", "station.rim.hough", "station.wheel.fit"]]
