"""The PLC handshake as a declared transition table ``(state, event) -> state``.

Like the trigger/busy/done/acknowledge handshake of common vision sensors:

1. the PLC writes a trigger command (measure or calibration check): ``idle -> busy``;
2. the station runs the cycle, writes every result register in one step, then ``busy -> done``
   (or ``busy -> fault`` with a fault code and a readable reason);
3. the PLC reads the results and writes acknowledge: ``done -> idle`` (``fault -> idle``, or
   reset fault).

A cycle with runout compensation (command 5, issue 32) also needs the car rolled between its
captures: the station asks for each roll, ``busy -> roll`` (the roll prompt registers say how
far), the PLC moves its conveyor and writes in position, ``roll -> busy``, and the station
captures. A roll not confirmed within ``plc.roll_timeout_s`` goes ``roll -> busy`` on its own,
and the cycle ends in fault (415). Every other command is refused in roll, as in busy (501).

A steering sweep (command 7, issue 33) needs the front wheels steered to each target of the
sweep: the station asks, ``busy -> steer`` (the steer prompt registers say where to), publishes
the wheels' live steer angle, and goes back to busy by itself once they stand still at the
target (``steer_reached``: the PLC confirms nothing). A steer not reached within
``plc.steer_timeout_s`` (or one the station's guide gave up on) goes ``steer -> busy`` too, and the
cycle ends in fault (424). Every command is refused in steer, as in busy (501; in position 508).

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
    ROLL = 4  # a compensated cycle waits for the PLC to roll the car (map version 5)
    STEER = 5  # a steering sweep waits for the front wheels to stand at a steer target (map version 6)


class Event(Enum):
    # from the PLC (values of the command register)
    MEASURE = 1
    CALIBRATION_CHECK = 2
    RESET_FAULT = 3
    ACKNOWLEDGE = 4
    MEASURE_COMPENSATED = 5  # measure with runout compensation: the station asks for rolls
    IN_POSITION = 6  # the car stands where the roll prompt asked
    MEASURE_CASTER = 7  # a steering sweep: caster, SAI, included angle; the station asks for each steer
    # from the station's own cycle
    CYCLE_OK = 101
    CYCLE_FAILED = 102
    ROLL_REQUEST = 103  # the compensated cycle needs the car rolled (the prompt is published)
    ROLL_TIMEOUT = 104  # the PLC did not confirm the roll within plc.roll_timeout_s
    STEER_REQUEST = 105  # the steering sweep needs the wheels steered (the steer prompt is published)
    STEER_REACHED = 106  # the wheels stand still at the target: the station captures
    STEER_FAILED = 107  # not reached within plc.steer_timeout_s, or the guide failed: the cycle then faults


PLC_EVENTS = (Event.MEASURE, Event.CALIBRATION_CHECK, Event.RESET_FAULT, Event.ACKNOWLEDGE,
              Event.MEASURE_COMPENSATED, Event.IN_POSITION, Event.MEASURE_CASTER)
TRIGGERS = (Event.MEASURE, Event.CALIBRATION_CHECK, Event.MEASURE_COMPENSATED, Event.MEASURE_CASTER)  # start a cycle
STATION_EVENTS = tuple(e for e in Event if e not in PLC_EVENTS)


# --- refusals: stable codes in the PLC area (5xx), defined in station/errors.py ---------------
from station.errors import (PlcBadJobId, PlcBusy, PlcCycleTimeout, PlcInternal,  # noqa: E402
                            PlcNoRollPending, PlcNothingToAcknowledge, PlcNotAcknowledged,
                            PlcUnknownCommand, RollNotConfirmed, SteerNotReached)


_B = State.BUSY
TRANSITIONS: dict[tuple[State, Event], State] = {
    (State.IDLE, Event.MEASURE): _B,
    (State.IDLE, Event.CALIBRATION_CHECK): _B,
    (State.IDLE, Event.RESET_FAULT): State.IDLE,  # harmless: PLCs often pulse reset at start-up
    (State.IDLE, Event.MEASURE_COMPENSATED): _B,
    (State.IDLE, Event.MEASURE_CASTER): _B,
    (State.BUSY, Event.CYCLE_OK): State.DONE,
    (State.BUSY, Event.CYCLE_FAILED): State.FAULT,
    (State.BUSY, Event.ROLL_REQUEST): State.ROLL,
    (State.ROLL, Event.IN_POSITION): _B,
    (State.ROLL, Event.ROLL_TIMEOUT): _B,  # the cycle then ends in fault 415 (RollNotConfirmed)
    (State.ROLL, Event.CYCLE_FAILED): State.FAULT,  # the station stopping, a crash: never left in roll
    (State.BUSY, Event.STEER_REQUEST): State.STEER,
    (State.STEER, Event.STEER_REACHED): _B,  # the station captures; the PLC confirms nothing
    (State.STEER, Event.STEER_FAILED): _B,  # the cycle then ends in fault 424 (SteerNotReached) or the guide's code
    (State.STEER, Event.CYCLE_FAILED): State.FAULT,  # the station stopping, a crash: never left in steer
    (State.DONE, Event.ACKNOWLEDGE): State.IDLE,
    (State.FAULT, Event.ACKNOWLEDGE): State.IDLE,
    (State.FAULT, Event.RESET_FAULT): State.IDLE,
}

_ROLLING = "a cycle is running and waits for the car to be rolled; roll it as registers 115..118 say, then write 6"
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
    (State.BUSY, Event.MEASURE_COMPENSATED): (PlcBusy, "trigger refused: a cycle is running (not queued); wait for done or fault"),
    (State.DONE, Event.MEASURE_COMPENSATED): (PlcNotAcknowledged, "trigger refused: acknowledge the previous result first"),
    (State.FAULT, Event.MEASURE_COMPENSATED): (PlcNotAcknowledged, "trigger refused: acknowledge or reset the fault first"),
    (State.ROLL, Event.MEASURE): (PlcBusy, f"trigger refused: {_ROLLING}"),
    (State.ROLL, Event.CALIBRATION_CHECK): (PlcBusy, f"trigger refused: {_ROLLING}"),
    (State.ROLL, Event.MEASURE_COMPENSATED): (PlcBusy, f"trigger refused: {_ROLLING}"),
    (State.ROLL, Event.RESET_FAULT): (PlcBusy, f"reset refused: {_ROLLING}"),
    (State.ROLL, Event.ACKNOWLEDGE): (PlcBusy, f"acknowledge refused: {_ROLLING}"),
    (State.BUSY, Event.MEASURE_CASTER): (PlcBusy, "trigger refused: a cycle is running (not queued); wait for done or fault"),
    (State.DONE, Event.MEASURE_CASTER): (PlcNotAcknowledged, "trigger refused: acknowledge the previous result first"),
    (State.FAULT, Event.MEASURE_CASTER): (PlcNotAcknowledged, "trigger refused: acknowledge or reset the fault first"),
    (State.ROLL, Event.MEASURE_CASTER): (PlcBusy, f"trigger refused: {_ROLLING}"),
}
_STEERING = ("a cycle is running and waits for the front wheels to stand at the steer target of registers "
             "225..227; it goes on by itself")
for _e, _what in ((Event.MEASURE, "trigger"), (Event.CALIBRATION_CHECK, "trigger"), (Event.MEASURE_COMPENSATED, "trigger"),
                  (Event.MEASURE_CASTER, "trigger"), (Event.RESET_FAULT, "reset"), (Event.ACKNOWLEDGE, "acknowledge")):
    REFUSALS[(State.STEER, _e)] = (PlcBusy, f"{_what} refused: {_STEERING}")
for _s in (State.IDLE, State.BUSY, State.DONE, State.FAULT, State.STEER):  # in position with no roll asked for
    REFUSALS[(_s, Event.IN_POSITION)] = (PlcNoRollPending, f"in position refused: no roll was asked for (state "
                                         f"{_s.name.lower()}); write 6 only while state is 4 (roll)")
for _s in State:  # the cycle's own events outside busy: a late cycle after a timeout
    for _e in (Event.CYCLE_OK, Event.CYCLE_FAILED):
        if (_s, _e) not in TRANSITIONS:
            REFUSALS[(_s, _e)] = (PlcInternal, f"cycle end ignored: the station is {_s.name.lower()}, not busy")
    if (_s, Event.ROLL_REQUEST) not in TRANSITIONS:  # a cycle abandoned after its timeout asking for a roll
        REFUSALS[(_s, Event.ROLL_REQUEST)] = (PlcInternal, f"roll prompt ignored: the station is {_s.name.lower()}, "
                                              "not busy")
    if (_s, Event.ROLL_TIMEOUT) not in TRANSITIONS:  # a timer that fired after the PLC's answer
        REFUSALS[(_s, Event.ROLL_TIMEOUT)] = (PlcInternal, f"roll timeout ignored: the station is {_s.name.lower()}, "
                                              "not waiting for a roll")
    if (_s, Event.STEER_REQUEST) not in TRANSITIONS:  # a cycle abandoned after its timeout asking for a steer
        REFUSALS[(_s, Event.STEER_REQUEST)] = (PlcInternal, f"steer prompt ignored: the station is {_s.name.lower()}, "
                                               "not busy")
    for _e in (Event.STEER_REACHED, Event.STEER_FAILED):  # a steer's end after its timeout
        if (_s, _e) not in TRANSITIONS:
            REFUSALS[(_s, _e)] = (PlcInternal, f"steer end ignored: the station is {_s.name.lower()}, not waiting "
                                  "for a steer")


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
                                "3 reset fault, 4 acknowledge, 5 measure with runout compensation, 6 in position, "
                                "7 measure caster)")
    return event


def roll_timeout_error(step: int, steps: int, timeout_s: float) -> RollNotConfirmed:
    """The fault of a roll the PLC did not confirm (its sentence fits ``fault_reason``, 64 characters)."""
    return RollNotConfirmed(f"roll {step}/{steps} not confirmed by the PLC within {timeout_s:g} s",
                            hint="the PLC moves the car as registers 115..118 say, then writes 6 (in position) "
                                 "into register 0; check its program and the conveyor")


def steer_timeout_error(step: int, steps: int, target_deg: float, timeout_s: float) -> SteerNotReached:
    """The fault of a steer target not reached in time (its sentence fits ``fault_reason``, 64 characters)."""
    return SteerNotReached(f"steer {step}/{steps} to {target_deg:+.1f} deg not reached within {timeout_s:g} s",
                           hint="steer the front wheels to the target of registers 225..227 (live angle 228..229) "
                                "and hold the steering wheel still; check the front cameras' view")


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
