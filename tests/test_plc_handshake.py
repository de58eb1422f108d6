"""The PLC handshake table, the register map's encodings and the result encoding (no transport)."""

import math
import struct
from pathlib import Path

import pytest

from station.errors import MeasurementError, PlcError, RimNotFound
from station.plc import register_map as rm
from station.plc.handshake import (PLC_EVENTS, REFUSALS, TRANSITIONS, Event, PlcBusy, PlcNotAcknowledged,
                                   PlcNothingToAcknowledge, PlcUnknownCommand, State, event_for_command,
                                   markdown_table, next_state)
from station.plc.results import (result_angles, result_registers, result_station_warning_bits, result_verdicts,
                                 result_warning_bits)
from station.plc.runner import CycleRequest, job_number, synthetic_result
from station.result import Measurement, WarningFlag

ROOT = Path(__file__).resolve().parent.parent

LEGAL = {
    (State.IDLE, Event.MEASURE): State.BUSY,
    (State.IDLE, Event.CALIBRATION_CHECK): State.BUSY,
    (State.IDLE, Event.RESET_FAULT): State.IDLE,
    (State.BUSY, Event.CYCLE_OK): State.DONE,
    (State.BUSY, Event.CYCLE_FAILED): State.FAULT,
    (State.DONE, Event.ACKNOWLEDGE): State.IDLE,
    (State.FAULT, Event.ACKNOWLEDGE): State.IDLE,
    (State.FAULT, Event.RESET_FAULT): State.IDLE,
    # runout compensation (map version 5): the station asks for rolls, the PLC confirms each
    (State.IDLE, Event.MEASURE_COMPENSATED): State.BUSY,
    (State.BUSY, Event.ROLL_REQUEST): State.ROLL,
    (State.ROLL, Event.IN_POSITION): State.BUSY,
    (State.ROLL, Event.ROLL_TIMEOUT): State.BUSY,
    (State.ROLL, Event.CYCLE_FAILED): State.FAULT,
    # the steering sweep (map version 6): the station asks for steers and goes on by itself
    (State.IDLE, Event.MEASURE_CASTER): State.BUSY,
    (State.BUSY, Event.STEER_REQUEST): State.STEER,
    (State.STEER, Event.STEER_REACHED): State.BUSY,
    (State.STEER, Event.STEER_FAILED): State.BUSY,
    (State.STEER, Event.CYCLE_FAILED): State.FAULT,
}
# the refusal code each illegal PLC move must carry
ILLEGAL_PLC = {
    (State.IDLE, Event.ACKNOWLEDGE): 503,
    (State.BUSY, Event.MEASURE): 501, (State.BUSY, Event.CALIBRATION_CHECK): 501,
    (State.BUSY, Event.RESET_FAULT): 501, (State.BUSY, Event.ACKNOWLEDGE): 501,
    (State.DONE, Event.MEASURE): 502, (State.DONE, Event.CALIBRATION_CHECK): 502,
    (State.DONE, Event.RESET_FAULT): 503,
    (State.FAULT, Event.MEASURE): 502, (State.FAULT, Event.CALIBRATION_CHECK): 502,
    (State.BUSY, Event.MEASURE_COMPENSATED): 501, (State.DONE, Event.MEASURE_COMPENSATED): 502,
    (State.FAULT, Event.MEASURE_COMPENSATED): 502,
    **{(s, Event.IN_POSITION): 508 for s in (State.IDLE, State.BUSY, State.DONE, State.FAULT, State.STEER)},
    **{(State.ROLL, e): 501 for e in (Event.MEASURE, Event.CALIBRATION_CHECK, Event.MEASURE_COMPENSATED,
                                      Event.RESET_FAULT, Event.ACKNOWLEDGE, Event.MEASURE_CASTER)},
    (State.BUSY, Event.MEASURE_CASTER): 501, (State.DONE, Event.MEASURE_CASTER): 502,
    (State.FAULT, Event.MEASURE_CASTER): 502,
    **{(State.STEER, e): 501 for e in (Event.MEASURE, Event.CALIBRATION_CHECK, Event.MEASURE_COMPENSATED,
                                       Event.RESET_FAULT, Event.ACKNOWLEDGE, Event.MEASURE_CASTER)},
}


def test_table_is_exactly_the_documented_handshake():
    assert TRANSITIONS == LEGAL
    for (s, e), new in LEGAL.items():
        assert next_state(s, e) is new


@pytest.mark.parametrize("state,event", [(s, e) for s in State for e in Event if (s, e) not in LEGAL])
def test_every_illegal_move_is_refused_with_its_code(state, event):
    with pytest.raises(PlcError) as info:
        next_state(state, event)
    if event in PLC_EVENTS:
        assert info.value.code == ILLEGAL_PLC[(state, event)]
    else:  # the station's own cycle end outside busy: a late cycle, ignored
        assert info.value.code == 507
    assert str(info.value)


def test_trigger_while_busy_is_refused_not_queued():
    with pytest.raises(PlcBusy):
        next_state(State.BUSY, Event.MEASURE)
    with pytest.raises(PlcNotAcknowledged):  # a finished result is never overwritten unread
        next_state(State.DONE, Event.MEASURE)
    with pytest.raises(PlcNothingToAcknowledge):
        next_state(State.IDLE, Event.ACKNOWLEDGE)


@pytest.mark.parametrize("value", [0, 8, 101, 102, 103, 104, 105, 106, 107, 999, 65535])
def test_unknown_command_values(value):
    with pytest.raises(PlcUnknownCommand) as info:
        event_for_command(value)
    assert info.value.code == 504 and str(value) in str(info.value)


def test_command_values_map_to_plc_events():
    assert [event_for_command(v) for v in (1, 2, 3, 4, 5, 6, 7)] == list(PLC_EVENTS)
    assert {v: rm.COMMANDS[v] for v in (1, 2, 3, 4, 5, 6, 7)} == {
        1: "measure", 2: "calibration_check", 3: "reset_fault", 4: "acknowledge",  # unchanged since version 1
        5: "measure_compensated", 6: "in_position", 7: "measure_caster"}
    assert {v: rm.STATES[v] for v in range(6)} == {0: "idle", 1: "busy", 2: "done", 3: "fault", 4: "roll",
                                                   5: "steer"}


def test_refusal_codes_are_plc_area_and_distinct_from_other_areas():
    codes = {cls.code for cls, _ in REFUSALS.values()}
    assert codes <= set(range(501, 600))
    assert "busy" in markdown_table()


# --- encodings ----------------------------------------------------------------------------------
def test_float32_is_big_endian_word_order_abcd():
    regs = rm.f32_to_regs(1.5)  # 0x3FC00000
    assert regs == [0x3FC0, 0x0000]
    assert rm.f32_to_regs(-0.123) == list(struct.unpack(">HH", struct.pack(">f", -0.123)))
    assert rm.regs_to_f32(rm.f32_to_regs(-0.123)) == pytest.approx(-0.123, abs=1e-7)
    assert math.isnan(rm.regs_to_f32(rm.f32_to_regs(None)))


@pytest.mark.parametrize("deg,reg", [(0.123, 12), (-0.126, (-13) & 0xFFFF), (0.005, 0), (-0.015, (-2) & 0xFFFF),
                                     (400.0, 32766), (-400.0, (-32766) & 0xFFFF), (None, 0x8000),
                                     (math.nan, 0x8000)])
def test_int16_scaling_saturation_and_missing(deg, reg):
    assert rm.deg_to_i16(deg) == reg
    back = rm.i16_to_deg(reg)
    if deg is None or not math.isfinite(deg):
        assert back is None
    else:
        assert back == pytest.approx(max(-327.66, min(327.66, round(deg * 100) / 100)))


def test_ascii_two_characters_per_register_high_byte_first():
    regs = rm.ascii_to_regs("WVWZZZ1KZAW000001", 16)
    assert len(regs) == 16 and regs[0] == (ord("W") << 8) | ord("V")
    assert regs[8] == ord("1") << 8 and regs[9:] == [0] * 7  # 17 characters, NUL padded
    assert rm.regs_to_ascii(regs) == "WVWZZZ1KZAW000001"
    assert rm.regs_to_ascii(rm.ascii_to_regs("x" * 40, 4)) == "xxxxxxxx"  # cut to the field
    with pytest.raises(ValueError):
        rm.regs_to_ascii([0x4101])  # "A" then a control character


def test_map_areas_and_block_read():
    assert all(f.writable for f in rm.PLC_FIELDS) and not any(f.writable for f in rm.STATION_FIELDS)
    assert rm.RESULT_BLOCK[1] - rm.RESULT_BLOCK[0] <= 125  # one Modbus read
    names = [f.name for f in rm.STATION_FIELDS]
    for needed in ("state", "fault_code", "heartbeat", "cycle_counter", "result_valid", "pass_bits",
                   "fault_reason", "thrust_f32", "thrust_i16", "front_total_toe_f32", "RR_camber_i16"):
        assert needed in names
    steering = [f.name for f in rm.STATION_FIELDS if f.address >= rm.STEER_BLOCK[0]]
    assert len([n for n in names if n.endswith("_f32") and "runout" not in n and n not in steering]) \
        == len(rm.ANGLES) == 11
    assert len([n for n in names if n.endswith("_runout_f32")]) == 4  # map version 5: one per wheel
    assert len([n for n in steering if n.endswith("_f32")]) == 8  # map version 6: 3 angles + offset, FL and FR


def test_docs_tables_are_generated_from_the_map():
    doc = (ROOT / "docs" / "plc.md").read_text()
    assert rm.markdown_tables() in doc, "docs/plc.md is stale: python -m station.plc.docs"
    assert markdown_table() in doc


# --- results ------------------------------------------------------------------------------------
def test_result_registers_round_trip_through_the_decoder():
    result = synthetic_result(CycleRequest("measure", "JOB-000007", "spec-a", 1))
    regs = [0] * (rm.RESULT_BLOCK[1] - rm.RESULT_BLOCK[0])
    for address, values in result_registers(result, "JOB-000007").items():
        i = address - rm.RESULT_BLOCK[0]
        regs[i:i + len(values)] = values
    block = rm.decode_block(regs)
    f32, i16 = rm.angles_from_block(block, "f32"), rm.angles_from_block(block, "i16")
    assert f32["RL.camber"] == pytest.approx(result.wheels["RL"].camber_deg, abs=1e-6)
    assert f32["thrust"] == pytest.approx(result.thrust_deg, abs=1e-6)
    assert f32["front.total_toe"] == pytest.approx(result.axles["front"].total_toe_deg, abs=1e-6)
    for name in rm.ANGLES:
        assert i16[name] == pytest.approx(round(f32[name] * 100) / 100, abs=1e-9)
    assert block["result_job_id"] == "JOB-000007"
    verdict = result.verdicts
    for i, name in enumerate(rm.ANGLES):
        assert (block["judged_bits"] >> i) & 1 == 1
        assert (block["pass_bits"] >> i) & 1 == verdict[name]
    assert (block["pass_bits"] >> rm.OVERALL_BIT) & 1 == verdict["overall"]


def test_warning_bits_name_the_kind_and_the_wheel():
    result = synthetic_result(CycleRequest("measure", "JOB-000004", None, 1))
    result.warnings, result.warning_flags = [], []
    assert result_warning_bits(result) == 0
    result.warnings = ["RL: toe +/-0.28 deg exceeds ...", "pair RR (cam7, cam8): ... could not check ..."]
    result.warning_flags = [WarningFlag("uncertain", "RL"), WarningFlag("unchecked", "RR"),
                               WarningFlag("drift", "FL"), WarningFlag("no such kind", "FL")]
    bits = result_warning_bits(result)
    assert bits == (1 << 2) | (1 << 11) | (1 << 4)
    regs = result_registers(result, "JOB-000004")
    assert regs[rm.FIELDS["warning_bits"].address] == [bits]
    assert regs[rm.FIELDS["station_warning_bits"].address] == [1 << rm.ANY_WARNING_BIT]
    # RR's runner-up is bit 15, and nothing else is (map version 2 also meant "any warning" there)
    result.warning_flags = [WarningFlag("runner_up", "RR")]
    assert result_warning_bits(result) == 1 << 15
    result.warning_flags = []                          # a warning text alone: "any warning" only
    assert result_warning_bits(result) == 0 and result_station_warning_bits(result) == 1 << rm.ANY_WARNING_BIT
    result.warning_flags = [WarningFlag("exposure", "RL", camera="cam6"),
                               WarningFlag("small_rim", "FR", camera="cam2")]
    assert result_warning_bits(result) == 0
    assert result_station_warning_bits(result) == (1 << rm.ANY_WARNING_BIT) | (1 << 1) | (1 << 3)
    result.warning_flags = [WarningFlag("rim_size", "FL")]   # a rim another size than its partner's
    assert result_warning_bits(result) == 0
    assert result_station_warning_bits(result) == (1 << rm.ANY_WARNING_BIT) | (1 << 4)
    result.warnings, result.warning_flags = [], []
    assert result_station_warning_bits(result) == 0


def test_verdicts_without_spec_are_unjudged_and_wheel_pass_is_read():
    result = synthetic_result(CycleRequest("measure", "JOB-000003", None, 1))
    assert result_verdicts(result) == (0, 0)
    result.verdicts = {"FR.toe": True, "FR.camber": False}
    passed, judged = result_verdicts(result)
    fr_toe, fr_camber = rm.ANGLES.index("FR.toe"), rm.ANGLES.index("FR.camber")
    assert judged == (1 << fr_toe) | (1 << fr_camber) and passed == 1 << fr_toe


def test_malformed_result_names_the_key():
    result = synthetic_result(CycleRequest("measure", "JOB-000003", None, 1))
    result.axles["rear"].total_toe_deg = None
    with pytest.raises(MeasurementError, match="axles.rear.total_toe_deg"):
        result_angles(result)
    result = synthetic_result(CycleRequest("measure", "JOB-000003", None, 1))
    result.wheels["FL"].toe_deg = "0.1"
    with pytest.raises(MeasurementError, match="wheels.FL.toe_deg"):
        result_angles(result)


def test_dry_run_is_deterministic_per_job_and_fails_on_purpose():
    a = synthetic_result(CycleRequest("measure", "JOB-000011", None, 1))
    b = synthetic_result(CycleRequest("measure", "JOB-000011", None, 99))
    c = synthetic_result(CycleRequest("measure", "JOB-000012", None, 1))
    assert a.wheels == b.wheels and a.wheels != c.wheels
    with pytest.raises(RimNotFound) as info:
        synthetic_result(CycleRequest("measure", "JOB-000020", None, 1), fail_every=10)
    assert info.value.code == 401
    assert job_number("WVWZZZ1KZAW000017") == 17 and job_number("ABC") == job_number("ABC")


def test_measurement_runner_keeps_one_station_and_passes_the_plc_request(monkeypatch):
    import station.cycle
    from calibration.errors import CalibrationError
    from station.plc.runner import measurement_runner

    built, calls = [], []

    class FakeStation:
        def __init__(self, config, *, seed=None, progress=None):
            built.append((config, seed))

        def measure(self, *, job_id, vehicle_spec):
            calls.append((job_id, vehicle_spec))
            if job_id == "BAD-CAL":
                raise CalibrationError("calibration does not match")
            return Measurement(station="fake", valid=True, job_id=job_id)

        def calibration_check(self):
            return Measurement(station="fake", valid=True, job_id="calibration-check")

    monkeypatch.setattr(station.cycle, "Station", FakeStation)
    run = measurement_runner("CONFIG", seed=5)
    assert run(CycleRequest("measure", "VIN1", "spec-a", 12)).job_id == "VIN1"
    assert run(CycleRequest("measure", "VIN2", None, 13)).job_id == "VIN2"
    assert calls == [("VIN1", "spec-a"), ("VIN2", None)]
    assert built == [("CONFIG", 5)], "the station is assembled once, not per cycle"
    assert run(CycleRequest("calibration_check", None, None, 14)).job_id == "calibration-check"
    with pytest.raises(CalibrationError):
        run(CycleRequest("measure", "BAD-CAL", None, 15))
    run(CycleRequest("measure", "VIN3", None, 16))
    assert len(built) == 2, "a calibration problem makes the next command assemble the station again"
