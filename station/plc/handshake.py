"""The PLC handshake as a declared transition table ``(state, event) -> state``.

Like the trigger/busy/done/acknowledge handshake of common vision sensors:

1. the PLC writes a trigger command (measure or calibration check): ``idle -> busy``;
2. the station runs the cycle, writes every result register in one step, then ``busy -> done``
   (or ``busy -> fault`` with a fault code and a readable reason);
3. the PLC reads the results and writes acknowledge: ``done -> idle`` (``fault -> idle``, or
   reset fault).

Every pair that is not in :data:`TRANSITIONS` is refused with the error in :data:`REFUSALS`:
the command is not queued, the state does not change, the PLC gets a Modbus exception and the
error's code in ``reject_code``. A trigger while busy is refused (501); a trigger before the
previous cycle was acknowledged is refused (502), so no result is ever overwritten unread.
"""

from __future__ import annotations

from enum import Enum

from station.errors import PlcError


class State(Enum):
    IDLE = 0
    BUSY = 1
    DONE = 2
    FAULT = 3


class Event(Enum):
    # from the PLC (values of the command register)
    MEASURE = 1
    CALIBRATION_CHECK = 2
    RESET_FAULT = 3
    ACKNOWLEDGE = 4
    # from the station's own cycle
    CYCLE_OK = 101
    CYCLE_FAILED = 102


PLC_EVENTS = (Event.MEASURE, Event.CALIBRATION_CHECK, Event.RESET_FAULT, Event.ACKNOWLEDGE)


# --- refusals: stable codes in the PLC area (5xx), defined in station/errors.py ---------------
from station.errors import (PlcBadJobId, PlcBusy, PlcCycleTimeout, PlcInternal,  # noqa: E402
                            PlcNothingToAcknowledge, PlcNotAcknowledged, PlcUnknownCommand)


_B = State.BUSY
TRANSITIONS: dict[tuple[State, Event], State] = {
    (State.IDLE, Event.MEASURE): _B,
    (State.IDLE, Event.CALIBRATION_CHECK): _B,
    (State.IDLE, Event.RESET_FAULT): State.IDLE,  # harmless: PLCs often pulse reset at start-up
    (State.BUSY, Event.CYCLE_OK): State.DONE,
    (State.BUSY, Event.CYCLE_FAILED): State.FAULT,
    (State.DONE, Event.ACKNOWLEDGE): State.IDLE,
    (State.FAULT, Event.ACKNOWLEDGE): State.IDLE,
    (State.FAULT, Event.RESET_FAULT): State.IDLE,
}

REFUSALS: dict[tuple[State, Event], tuple[type[PlcError], str]] = {
    (State.IDLE, Event.ACKNOWLEDGE): (PlcNothingToAcknowledge, "acknowledge refused: no finished cycle to acknowledge"),
    (State.BUSY, Event.MEASURE): (PlcBusy, "trigger refused: a cycle is running (not queued); wait for done or fault"),
    (State.BUSY, Event.CALIBRATION_CHECK): (PlcBusy, "trigger refused: a cycle is running (not queued); wait for done or fault"),
    (State.BUSY, Event.RESET_FAULT): (PlcBusy, "reset refused: a cycle is running; wait for done or fault"),
    (State.BUSY, Event.ACKNOWLEDGE): (PlcBusy, "acknowledge refused: the cycle is still running"),
    (State.DONE, Event.MEASURE): (PlcNotAcknowledged, "trigger refused: acknowledge the previous result first"),
    (State.DONE, Event.CALIBRATION_CHECK): (PlcNotAcknowledged, "trigger refused: acknowledge the previous result first"),
    (State.DONE, Event.RESET_FAULT): (PlcNothingToAcknowledge, "reset refused: no fault; acknowledge the result instead"),
    (State.FAULT, Event.MEASURE): (PlcNotAcknowledged, "trigger refused: acknowledge or reset the fault first"),
    (State.FAULT, Event.CALIBRATION_CHECK): (PlcNotAcknowledged, "trigger refused: acknowledge or reset the fault first"),
}
for _s in State:  # the cycle's own events outside busy: a late cycle after a timeout
    for _e in (Event.CYCLE_OK, Event.CYCLE_FAILED):
        if _s is not State.BUSY:
            REFUSALS[(_s, _e)] = (PlcInternal, f"cycle end ignored: the station is {_s.name.lower()}, not busy")


def modbus_exception(error: PlcError) -> int:
    """The Modbus exception code that answers a refused write: 6 (server device busy) while a
    cycle runs, 3 (illegal data value) for a command not allowed now or not a command."""
    return 6 if isinstance(error, PlcBusy) else 3


def next_state(state: State, event: Event) -> State:
    """The state after ``event`` in ``state``; raises the refusal's PlcError for an illegal move."""
    try:
        return TRANSITIONS[(state, event)]
    except KeyError:
        pass
    cls, message = REFUSALS[(state, event)]
    raise cls(message)


def event_for_command(value: int) -> Event:
    """Command register value -> PLC event; raises PlcUnknownCommand."""
    try:
        event = Event(value)
    except ValueError:
        event = None
    if event not in PLC_EVENTS:
        raise PlcUnknownCommand(f"command {value} is not a command (1 measure, 2 calibration check, "
                                "3 reset fault, 4 acknowledge)")
    return event


def markdown_table() -> str:
    """The transition table for docs/plc.md."""
    rows = ["| state | command / event | result | Modbus answer |", "|---|---|---|---|"]
    for s in State:
        for e in Event:
            if (s, e) in TRANSITIONS:
                res, answer = f"-> **{TRANSITIONS[(s, e)].name.lower()}**", "ok" if e in PLC_EVENTS else "-"
            else:
                cls, msg = REFUSALS[(s, e)]
                if e not in PLC_EVENTS:
                    continue
                res, answer = f"refused, reject_code {cls.code}: {msg}", f"exception {modbus_exception(cls(msg))}"
            rows.append(f"| {s.name.lower()} | {e.name.lower()} | {res} | {answer} |")
    return "\n".join(rows) + "\n"


_missing = [(s, e) for s in State for e in Event if (s, e) not in TRANSITIONS and (s, e) not in REFUSALS]
assert not _missing, f"handshake table incomplete: {_missing}"
assert not set(TRANSITIONS) & set(REFUSALS)
