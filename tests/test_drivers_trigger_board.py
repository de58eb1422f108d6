"""The trigger board's line protocol against the board simulated on a pseudo-terminal."""

from __future__ import annotations

import os
import time

import pytest

from drivers.trigger_board import TriggerBoard, TriggerBoardError
from simulators.trigger_board_sim import TriggerBoardSim


@pytest.fixture
def sim():
    with TriggerBoardSim() as s:
        yield s


def test_identify_ping_fire_status(sim):
    with TriggerBoard(sim.port, 115200, timeout_s=0.5, n_lines=8) as b:
        assert (b.model, b.firmware, b.n_lines) == ("TB8-SIM", "1.0", 8)
        assert b.ping() < 0.5
        b.set_strobe_us(2500)
        r1, r2 = b.fire(), b.fire(mask=0x05)
        assert r2.seq == r1.seq + 1 and r2.board_time_us >= r1.board_time_us
        assert (r1.fired_mask, r2.fired_mask) == (0xFF, 0x05)
        assert [sim.lines.count(i) for i in range(8)] == [2, 1, 2, 1, 1, 1, 1, 1]
        assert b.status() == {"fired": 2, "strobe": 2500, "pulse": 100, "fault": 0}
        assert sim.received[0] == "ID?" and sim.received[-2] == f"FIRE {r2.seq} 05"


def test_refusals_and_faults_are_clear_errors(sim):
    with TriggerBoard(sim.port, timeout_s=0.3) as b:
        with pytest.raises(TriggerBoardError, match="refused 'STROBE 0'.*out of range"):
            b.set_strobe_us(0)
        with pytest.raises(TriggerBoardError, match="FIRE mask 100"):
            b.fire(mask=0x100)
        sim.fault_mask = 0b1000_0001
        with pytest.raises(TriggerBoardError, match=r"line\(s\) 0, 7 did not fire") as e:
            b.fire()
        assert e.value.code == 204 and "trigger cable" in e.value.hint
        sim.fault_mask = 0
        sim.mute = True
        t = time.monotonic()
        with pytest.raises(TriggerBoardError, match="no answer to FIRE within 0.3 s"):
            b.fire()
        assert 0.29 < time.monotonic() - t < 1.5  # the deadline, not pyserial's own timeout
        sim.mute = False
        assert b.fire().fired_mask == 0xFF  # back to work


def test_a_late_reply_is_not_taken_for_the_next_one(sim):
    with TriggerBoard(sim.port, timeout_s=0.15) as b:
        sim.reply_delay_s = 0.3
        with pytest.raises(TriggerBoardError, match="no answer"):
            b.fire()
        sim.reply_delay_s = 0.0
        time.sleep(0.3)  # the stale FIRED <seq-1> is now waiting in the input buffer
        r = b.fire()
        assert r.seq == int(sim.received[-1].split()[1])


def test_missing_port_and_wrong_device(tmp_path):
    with pytest.raises(TriggerBoardError, match="cannot open /nonexistent/ttyUSB9") as e:
        TriggerBoard("/nonexistent/ttyUSB9").open()
    assert "trigger_board.port" in e.value.hint
    # a pty where nothing answers: the identity query times out with the port named
    master, slave = os.openpty()
    try:
        with pytest.raises(TriggerBoardError, match=f"{os.ttyname(slave)}: no answer to ID\\?"):
            TriggerBoard(os.ttyname(slave), timeout_s=0.2).open()
    finally:
        os.close(master)
        os.close(slave)
