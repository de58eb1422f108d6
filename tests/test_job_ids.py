"""Job ids with control characters: refused where they come in (`station measure --job`), and
shown escaped where one already stored goes out (the history listing, the CSV, the HTML report);
seeds are whole numbers, 0 or more, for every command that takes one."""

from __future__ import annotations

import csv
import re

import pytest

from result_builder import make_result
from station.cli import main
from station.records.history import History, export_csv
from station.records.printable import visible
from station.records.report import build_report

HOSTILE = ["JOB\n2026-11-22T10:00:00      forged-cycle", "JOB\x1b[2J\x1b[31mRED", "JOB\r", "VIN\u202eLIVE",
           "JOB\x00NUL", "JOB\x7f", "JOB\x9b1m", "A\u2028B", "JOB\udcff"]
STORED = [j for j in HOSTILE if "\udcff" not in j]  # a lone surrogate cannot be stored at all
CONTROL = re.compile("[\x00-\x09\x0b-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069\ud800-\udfff]")


@pytest.mark.parametrize("job", HOSTILE, ids=[ascii(j) for j in HOSTILE])
def test_measure_refuses_a_job_id_with_control_characters(job, capsys):
    with pytest.raises(SystemExit) as e:
        main(["measure", "--job", job, "--no-record"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "argument --job" in err and "without them" in err
    assert not CONTROL.search(err.replace("\n", " ")), ascii(err)  # the message itself is safe to print


@pytest.mark.parametrize("job", ["WVWZZZ1KZAW000001", "Müller 4711", "ΑΒΓ-12", "x" * 200])
def test_printable_job_ids_pass_the_argument_check(job):
    from station.commands.arguments import job_id

    assert job_id(job) == job


@pytest.mark.parametrize("command", ["measure", "calibrate", "capture", "live"])
@pytest.mark.parametrize("value", ["-1", "x", "1.5", "9" * 5000])
def test_a_seed_that_is_not_a_whole_number_from_0_is_a_usage_error(command, value, capsys):
    with pytest.raises(SystemExit) as e:
        main([command, "--seed", value])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "argument --seed" in err and "expected a whole number, 0 or more" in err


@pytest.fixture
def stored(tmp_path, monkeypatch):
    """A history holding a cycle of every hostile job id (as an older station could store them)."""
    monkeypatch.setenv("STATION_DATA_DIR", str(tmp_path))
    with History(tmp_path / "history.sqlite") as h:
        for i, job in enumerate(STORED, start=1):
            h.store(make_result(i, cycle=i, job_id=job, vehicle_spec=None))
    return tmp_path


def test_the_job_listing_escapes_stored_control_characters(stored, capsys):
    assert main(["history", "--jobs"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert len(lines) == 1 + len(STORED)  # the header and one line per job: no forged line
    assert not CONTROL.search(out.replace("\n", " ")), ascii(out)
    assert any(line.startswith("JOB\\n2026-11-22T10:00:00") for line in lines)
    assert main(["history"]) == 0
    out = capsys.readouterr().out
    assert len(out.splitlines()) == 1 + len(STORED) + 1 and not CONTROL.search(out.replace("\n", " "))
    assert "JOB\\x1b[2J" in out


def test_the_csv_export_escapes_stored_control_characters(stored):
    with History(stored / "history.sqlite") as h:
        rows = h.query()
    path = stored / "h.csv"
    assert export_csv(rows, path) == len(STORED)
    text = path.read_text()
    assert not CONTROL.search(text.replace("\n", " ")), ascii(text)
    assert len(text.splitlines()) == 1 + len(STORED)
    assert sorted(r["job_id"] for r in csv.DictReader(path.open())) == sorted(visible(j) for j in STORED)


@pytest.mark.parametrize("job", HOSTILE, ids=[ascii(j) for j in HOSTILE])
def test_the_html_report_escapes_stored_control_characters(job):
    html = build_report(job, [make_result(1, job_id=job, vehicle_spec=None, warnings=[f"odd {job}"])])
    assert not CONTROL.search(html.replace("\n", " ")), ascii(html[:300])
    assert visible(job).replace("<", "&lt;") in html


def test_the_report_command_lists_known_jobs_escaped(stored, capsys):
    assert main(["report", "no-such-job"]) == 2
    err = capsys.readouterr().err
    assert "the newest jobs are" in err and not CONTROL.search(err.replace("\n", " ")), ascii(err)
