"""The steering sweep over the PLC (issue 33, map version 6): command 7 runs station caster; the
station asks for each steer in state 5 (steer) with the prompt in 225..227, publishes the front
wheels' live steer angle in 228..231 and goes on by itself once they stand still at the target;
the caster, SAI, included angle and kingpin offset land in 232..256. Here the handshake's
table, the registers, the dry run's failing sweep and the steer operator; over Modbus TCP in
tests/test_plc_steer_modbus.py."""

from __future__ import annotations

import math

import pytest

from station.errors import MeasurementError, PlcError, SteerNotReached
from station.plc import register_map as rm
from station.plc.dry_steering import SyntheticSteering, wheel_angles
from station.plc.handshake import PLC_EVENTS, REFUSALS, Event, State, event_for_command, modbus_exception, next_state
from station.plc.results import (cleared_registers, result_registers, steer_live_registers, steer_prompt_registers)
from station.plc.runner import CycleRequest, synthetic_result
from station.plc.steer_operator import PlcSteerOperator, SteerPrompt, steer_plan
from tests.plc_steer_common import CASTER, CLEARED_STEER, FRONT, PLAN_DEG, STEER


# --- the table ----------------------------------------------------------------------------------
def test_the_targets_the_prompts_announce_are_the_procedures():
    assert steer_plan() == PLAN_DEG
    assert steer_plan(20.0) == [20.0, -20.0, 0.0]


def test_measure_caster_is_the_next_free_command_steer_the_next_state_and_map_version_6_added_them():
    assert event_for_command(CASTER) is Event.MEASURE_CASTER and rm.COMMANDS[CASTER] == "measure_caster"
    assert rm.STATES[STEER] == "steer" and State(STEER) is State.STEER
    assert rm.MAP_VERSION >= 6  # 7 added bit 5 of station_warning_bits and moved nothing
    from station.plc.functions import IDENTIFICATION
    assert IDENTIFICATION.endswith(f"register map {rm.MAP_VERSION}")
    with pytest.raises(PlcError) as info:
        event_for_command(8)
    assert info.value.code == 504 and "7 measure caster" in str(info.value)


def test_steer_state_moves():
    assert next_state(State.IDLE, Event.MEASURE_CASTER) is State.BUSY
    assert next_state(State.BUSY, Event.STEER_REQUEST) is State.STEER
    assert next_state(State.STEER, Event.STEER_REACHED) is State.BUSY  # the station goes on by itself
    assert next_state(State.STEER, Event.STEER_FAILED) is State.BUSY  # then the cycle faults 424
    assert next_state(State.STEER, Event.CYCLE_FAILED) is State.FAULT
    for state in (State.IDLE, State.DONE, State.FAULT, State.ROLL, State.STEER):  # an abandoned cycle's prompt
        assert REFUSALS[(state, Event.STEER_REQUEST)][0].code == 507
    for state in (State.IDLE, State.BUSY, State.DONE, State.FAULT, State.ROLL):  # a steer's end after its timeout
        assert REFUSALS[(state, Event.STEER_REACHED)][0].code == 507
        assert REFUSALS[(state, Event.STEER_FAILED)][0].code == 507
    assert REFUSALS[(State.STEER, Event.CYCLE_OK)][0].code == 507


@pytest.mark.parametrize("event", [e for e in PLC_EVENTS if e is not Event.IN_POSITION])
def test_in_steer_every_command_is_refused_as_busy(event):
    with pytest.raises(PlcError) as info:
        next_state(State.STEER, event)
    assert info.value.code == 501 and modbus_exception(info.value) == 6
    assert "front wheels" in str(info.value) and "225..227" in str(info.value)


def test_in_position_in_steer_is_508_and_measure_caster_is_refused_like_every_trigger():
    with pytest.raises(PlcError) as info:
        next_state(State.STEER, Event.IN_POSITION)
    assert info.value.code == 508 and modbus_exception(info.value) == 3
    for state, code, exception in ((State.BUSY, 501, 6), (State.ROLL, 501, 6), (State.DONE, 502, 3),
                                   (State.FAULT, 502, 3)):
        for trigger in (Event.MEASURE, Event.MEASURE_CASTER):
            with pytest.raises(PlcError) as info:
                next_state(state, trigger)
            assert (info.value.code, modbus_exception(info.value)) == (code, exception), (state, trigger)


# --- the registers ------------------------------------------------------------------------------
V5_ADDRESSES = {"command": 0, "job_id": 1, "vehicle_spec": 17, "state": 100, "fault_code": 101, "heartbeat": 102,
                "cycle_counter": 103, "result_valid": 104, "active_command": 105, "reject_code": 106,
                "reject_count": 107, "pass_bits": 108, "judged_bits": 109, "cycle_time_us": 110, "map_version": 112,
                "warning_bits": 113, "station_warning_bits": 114, "roll_step": 115, "roll_steps": 116,
                "roll_distance_mm": 117, "roll_position_mm": 118, "FL_toe_f32": 120, "thrust_f32": 140,
                "FL_toe_i16": 142, "thrust_i16": 152, "result_job_id": 160, "fault_reason": 176,
                "runout_compensated": 208, "FL_runout_f32": 209, "RR_runout_mm_i16": 224}


def test_map_version_6_moves_nothing_and_adds_one_block_of_one_read():
    for name, address in V5_ADDRESSES.items():
        assert rm.FIELDS[name].address == address, name
    assert rm.RESULT_BLOCK == (100, 225)  # a map-5 program's single read still returns all it knew
    assert rm.STEER_BLOCK == (225, 257) and rm.STEER_BLOCK[1] - rm.STEER_BLOCK[0] <= 125
    new = {f.name: (f.address, f.type) for f in rm.STATION_FIELDS if f.address >= 225}
    assert {a for a, _ in new.values()} == {*range(225, 233), *range(233, 245, 2), *range(245, 251), 251, 253, 255, 256}
    taken = [a for f in rm.STATION_FIELDS if f.address >= 225 for a in range(f.address, f.end)]
    assert sorted(taken) == list(range(225, 257))  # no gap, no overlap
    assert new["steer_target_i16"] == (227, "i16") and new["FL_steer_i16"] == (228, "i16")
    assert new["FR_steer_i16"] == (229, "i16") and new["steer_reached"] == (230, "u16")
    assert new["FL_caster_f32"] == (233, "f32") and new["FR_included_angle_f32"] == (243, "f32")
    assert new["FL_caster_i16"] == (245, "i16") and new["FR_included_angle_i16"] == (250, "i16")
    assert new["FL_kingpin_offset_mm_f32"] == (251, "f32") and new["FR_kingpin_offset_mm_i16"] == (256, "i16")
    assert rm.FIELDS["FL_kingpin_offset_mm_i16"].scale == 100 and rm.FIELDS["steer_target_i16"].scale == 100


def _decode(values: dict[int, list[int]], lo: int = 100, hi: int = 257) -> dict:
    regs = [0] * (hi - lo)
    for address, v in values.items():
        regs[address - lo:address - lo + len(v)] = v
    return rm.decode_block(regs, lo)


def test_the_steer_prompt_and_the_live_reading_are_signed_hundredths_of_a_degree():
    prompt = steer_prompt_registers(2, 3, -10.0)
    assert prompt == {225: [2], 226: [3], 227: [(-1000) & 0xFFFF]}
    live = steer_live_registers({"FL": 9.6, "FR": -0.004}, True, 70000)
    assert live[228] == [960] and live[229] == [0] and live[230] == [1] and live[231] == [70000 & 0xFFFF]
    lost = _decode(steer_live_registers({"FR": -10.4}, False, 5), 225, 232)
    assert (lost["FL_steer_i16"], lost["FR_steer_i16"], lost["steer_reached"]) == (None, -10.4, 0)
    assert _decode({**steer_prompt_registers(), **steer_live_registers()}, 225, 232) == CLEARED_STEER
    assert SteerPrompt(2, 3, -10.0).describe() == "steer 2/3: 10 deg right"
    assert SteerPrompt(3, 3, 0.0).describe() == "steer 3/3: straight ahead"


def test_a_steering_result_writes_each_front_wheels_geometry_and_says_so():
    result = synthetic_result(CycleRequest("measure_caster", "JOB-000007", None, 1))
    b = _decode(result_registers(result, "JOB-000007", steering_required=True))
    assert b["steering_valid"] == 1 and b["result_valid"] == 0  # the device sets result_valid itself
    for w in FRONT:
        s = result.steering.wheels[w]
        assert 2 <= s.caster_deg <= 7 and 9 <= s.sai_deg <= 14 and -10 <= s.kingpin_offset_m * 1000 <= 60
        assert s.included_angle_deg == pytest.approx(s.sai_deg + result.wheels[w].camber_deg, abs=1e-3)
        for key in ("caster", "sai", "included_angle"):
            value = getattr(s, f"{key}_deg")
            assert b[f"{w}_{key}_f32"] == pytest.approx(value, abs=1e-5), (w, key)
            assert b[f"{w}_{key}_i16"] == round(value * 100) / 100, (w, key)
        assert b[f"{w}_kingpin_offset_mm_f32"] == pytest.approx(s.kingpin_offset_m * 1000, abs=1e-4)
        assert b[f"{w}_kingpin_offset_mm_i16"] == round(s.kingpin_offset_m * 1000 * 100) / 100
    assert b["FL_caster_f32"] != pytest.approx(b["FR_caster_f32"], abs=1e-3)  # each wheel its own
    # the toe and camber of the last (straight-ahead) capture are the ordinary angles
    assert b["FL_camber_f32"] == pytest.approx(result.wheels["FL"].camber_deg, abs=1e-6)


def test_results_without_a_sweep_read_no_steering():
    for b in (_decode(result_registers(synthetic_result(CycleRequest("measure", "JOB-000007", None, 1)), "J")),
              _decode(result_registers(synthetic_result(CycleRequest("measure_compensated", "JOB-000007", None, 1)),
                                       "J")),
              _decode(cleared_registers())):
        assert b["steering_valid"] == 0
        for w in FRONT:
            for key in ("caster", "sai", "included_angle", "kingpin_offset_mm"):
                assert math.isnan(b[f"{w}_{key}_f32"]) and b[f"{w}_{key}_i16"] is None, (w, key)


def test_a_steering_result_without_its_geometry_is_malformed():
    result = synthetic_result(CycleRequest("measure_caster", "JOB-000007", None, 1))
    result.steering.wheels["FR"].sai_deg = math.nan
    with pytest.raises(MeasurementError, match="steering.wheels.FR.sai_deg"):
        result_registers(result, "JOB-000007", steering_required=True)
    del result.steering.wheels["FL"]
    with pytest.raises(MeasurementError, match="steering.wheels.FL"):
        result_registers(result, "JOB-000007")
    result.steering = None
    with pytest.raises(MeasurementError, match="lacks steering"):
        result_registers(result, "JOB-000007", steering_required=True)


def test_the_dry_run_fails_a_sweep_on_purpose_as_a_wheel_rolled_while_steered():
    from station.errors import WheelRolledWhileSteered

    with pytest.raises(WheelRolledWhileSteered) as info:
        synthetic_result(CycleRequest("measure_caster", "JOB-000020", None, 1), fail_every=10)
    assert info.value.code == 422


# --- the operator and the dry run's wheels ------------------------------------------------------
class RecordingGate:
    timeout_s = 5.0

    def __init__(self):
        self.events = []

    def begin(self, prompt):
        self.events.append(("begin", prompt))

    def reading(self, angles, reached):
        self.events.append(("reading", dict(angles), reached))

    def end(self, error=None):
        self.events.append(("end", error))


def test_the_operator_numbers_the_steers_and_hands_every_reading_on():
    gate = RecordingGate()
    op = PlcSteerOperator(gate, 3, lambda on_reading: SyntheticSteering(on_reading, reading_s=0.0))
    for target in PLAN_DEG:
        op.steer(target)
    begins = [e[1] for e in gate.events if e[0] == "begin"]
    assert [(p.step, p.steps, p.target_deg) for p in begins] == [(1, 3, 10.0), (2, 3, -10.0), (3, 3, 0.0)]
    assert [e for e in gate.events if e[0] == "end"] == [("end", None)] * 3
    kinds = [e[0] for e in gate.events]
    assert kinds == (["begin"] + ["reading"] * 10 + ["end"]) * 3
    readings = [e for e in gate.events if e[0] == "reading"]
    assert [r[2] for r in readings[:10]] == [False] * 9 + [True]  # reached once, on the last: the station goes on
    assert readings[9][1] == pytest.approx({"FL": 10.4, "FR": 9.6})  # the inner (left) wheel steers more
    assert readings[19][1] == pytest.approx({"FL": -9.6, "FR": -10.4})
    ramp = [r[1]["FL"] + r[1]["FR"] for r in readings[:8]]
    assert all(b > a for a, b in zip(ramp, ramp[1:]))  # the wheels turn, the live angle moves


def test_a_guide_that_gives_up_ends_the_steer_with_its_error():
    gate = RecordingGate()
    op = PlcSteerOperator(gate, 3, lambda on_reading: SyntheticSteering(on_reading, reading_s=0.01, reach=0.5,
                                                                        timeout_s=0.1))
    with pytest.raises(SteerNotReached) as info:
        op.steer(10.0)
    assert info.value.code == 424 and gate.events[-1] == ("end", info.value)
    assert not any(e[2] for e in gate.events if e[0] == "reading")  # never reached
    assert gate.events[-2][1] == pytest.approx(wheel_angles(5.0))  # stood at half the target
    with pytest.raises(PlcError, match="no steer gate"):
        CycleRequest("measure_caster", "J", None, 1).steer_operator(lambda r: None)
