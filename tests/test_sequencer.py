"""The cycle sequencer: every (state, command) pair either follows the table or is refused."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from drivers.errors import CameraTimeout
from station.errors import StationError
from station.sequencer import (EVENTS, STATES, TRANSITIONS, IllegalCommand, Sequencer,
                               transition_table_markdown)


def _at(state: str) -> Sequencer:
    """A sequencer driven (legally) into ``state``."""
    path = {"idle": [], "capturing": ["start"], "measuring": ["start", "captured"],
            "reporting": ["start", "captured", "measured"],
            "done": ["start", "captured", "measured", "reported"], "fault": ["start", "fail"]}[state]
    s = Sequencer()
    for e in path:
        s.fire(e)
    assert s.state == state
    return s


@pytest.mark.parametrize("state,event", list(itertools.product(STATES, EVENTS)))
def test_every_pair(state, event):
    s = _at(state)
    if (state, event) in TRANSITIONS:
        assert s.fire(event) == TRANSITIONS[(state, event)] == s.state
    else:
        with pytest.raises(IllegalCommand, match=f"cannot {event} while {state}; allowed now: "):
            s.fire(event)
        assert s.state == state  # an illegal command changes nothing


def test_table_is_complete_and_reachable():
    assert {s for s, _ in TRANSITIONS} | set(TRANSITIONS.values()) == set(STATES)
    assert sorted(_at("idle").allowed()) == ["start"]
    assert sorted(_at("capturing").allowed()) == ["abort", "captured", "fail"]
    with pytest.raises(IllegalCommand, match="unknown command 'go'"):
        Sequencer().fire("go")


def test_run_cycle_ok_and_listeners():
    seen = []
    s = Sequencer(listeners=[lambda *t: seen.append(t)])
    out = s.run_cycle(lambda: "frames", lambda f: f + "+result", lambda r: r + "+report")
    assert out == "frames+result+report" and s.state == "done" and s.cycle == 1
    assert [t[1] for t in seen] == ["start", "captured", "measured", "reported"]


def test_a_fault_keeps_the_error_and_leaves_the_station_ready():
    s = Sequencer()

    def capture():
        raise CameraTimeout("cam3: no frame within 3 s", hint="check the cable")

    with pytest.raises(CameraTimeout):
        s.run_cycle(capture, lambda f: f, lambda r: r)
    assert s.state == "fault" and s.fault.code == 201 and s.fault.state == "capturing"
    assert "cam3" in s.fault.message and s.fault.hint == "check the cable"
    assert s.run_cycle(lambda: 1, lambda f: f + 1, lambda r: r + 1) == 3  # the next command works
    assert s.state == "done" and s.fault is None and s.cycle == 2

    with pytest.raises(ZeroDivisionError):
        s.run_cycle(lambda: 1, lambda f: f / 0, lambda r: r)
    assert s.state == "fault" and "internal error: ZeroDivisionError" in s.fault.message
    assert s.fault.state == "measuring"
    s.fire("reset")
    assert s.state == "idle" and s.fault is None


def test_a_second_start_while_busy_is_refused():
    s = Sequencer()

    def capture():
        with pytest.raises(IllegalCommand, match="cannot start while capturing"):
            s.fire("start")
        return "frames"

    s.run_cycle(capture, lambda f: f, lambda r: r)
    assert s.state == "done"


def test_illegal_command_is_a_station_error_with_a_code():
    with pytest.raises(StationError) as e:
        _at("done").fire("captured")
    assert e.value.code == 2 and "abort" in e.value.hint


def test_docs_show_the_table():
    doc = (Path(__file__).resolve().parent.parent / "docs" / "cameras.md").read_text()
    assert transition_table_markdown() in doc
