"""A PLC simulator: a Modbus master that runs measurement cycles through the station's handshake,
checks every step and prints the results.

    station serve --dry-run &                      # or the real station: station serve
    python -m station.plc.master --cycles 3 --dry-run-check
    python -m station.plc.master --cycles 3 --compensate --dry-run-check   # runout compensation
    python -m station.plc.master --cycles 3 --caster --dry-run-check       # a steering sweep
    python -m station.plc.master --rtu /dev/ttyUSB0 --cycles 3

Per cycle it writes job id, vehicle spec and the trigger in one request, polls the state, reads
the whole result block in one request, acknowledges, and checks: the station leaves idle at
once; no result is visible while busy; the cycle counter moves by exactly one; a finished result
is valid, belongs to this job and its float32 and int16 copies agree; a fault carries a code and
a reason; acknowledge returns to idle with no fault. With ``--dry-run-check`` the angles are
also compared with the dry-run runner's expected values, so a result of another job is caught.

With ``--compensate`` every trigger is command 5 (measure with runout compensation), and the
simulator is the line's conveyor too: whenever the station is in state roll it reads the roll
prompt (115..118), checks it (the next step, its distance adding up to its position), "moves the
car" (``--conveyor-s``) and writes 6 (in position); it prints each roll and each wheel's runout,
and checks that the result says it is compensated.

With ``--caster`` every trigger is command 7 (a steering sweep: caster, SAI, included angle,
kingpin offset). The simulator confirms nothing: while the station is in state steer it reads
the steer prompt and the live steer angle (225..231) at every poll and checks the prompt
(station/plc/steer_watch.py); it prints each steer with the live readings it saw and the steering
result (232..256), and checks it (float32 against int16, ``steering_valid``, with
``--dry-run-check`` the dry run's values).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException

from calibration.station_frame import WHEELS
from station.errors import StationError
from station.plc import register_map as rm
from station.plc.roll_operator import roll_plan
from station.plc.runner import CycleRequest, synthetic_result
from station.plc.steer_operator import steer_plan
from station.plc.steer_watch import SteerWatch, check_steering, format_steering, steering_values


@dataclass
class CycleReport:
    job_id: str
    spec: str | None = None
    command: int = 1
    state: str = ""  # done | fault
    fault_code: int = 0
    reason: str = ""
    angles: dict = field(default_factory=dict)  # float32 copy, degrees or None
    pass_bits: int = 0
    judged_bits: int = 0
    measure_s: float = 0.0  # the station's own measurement time
    total_s: float = 0.0  # trigger sent -> idle after acknowledge, at the PLC
    problems: list = field(default_factory=list)
    rolls: list = field(default_factory=list)  # runout compensation: the RollStep of each roll made
    compensated: int = 0  # runout_compensated of the result
    runout: dict = field(default_factory=dict)  # wheel -> (deg (float32 copy), mm) or None
    steers: list = field(default_factory=list)  # a steering sweep: the SteerStep of each steer seen
    steering_valid: int = 0  # steering_valid of the result
    steering: dict = field(default_factory=dict)  # FL, FR -> {caster, sai, included_angle, kingpin_offset_mm}
    uncertain: dict = field(default_factory=dict)  # a 404: wheel -> why (register_map.uncertain_reasons_of)

    @property
    def handshake_s(self) -> float:
        """PLC-side cycle time minus the measurement, the conveyor's rolls and the steering: the
        cost of the handshake itself."""
        return self.total_s - self.measure_s - sum(r.seconds for r in self.rolls) - sum(s.seconds for s in self.steers)


@dataclass(frozen=True)
class RollStep:
    """One roll the station asked for (registers 115..118) and how long the conveyor took."""

    step: int
    steps: int
    distance_mm: int
    position_mm: int
    seconds: float

    def describe(self) -> str:
        way = "forward" if self.distance_mm > 0 else "back"
        return (f"roll {self.step}/{self.steps}: {way} {abs(self.distance_mm)} mm (to {self.position_mm:+d} mm), "
                f"in position after {self.seconds:.2f} s").replace("(to +0 mm)", "(to the start)")


class ModbusFailure(Exception):
    pass


class PlcSimulator:
    """Drives the handshake over a connected pymodbus sync client."""

    def __init__(self, client, *, device_id: int = 1, timeout_s: float = 60.0, poll_s: float = 0.0,
                 conveyor_s: float = 0.0, on_roll=None, on_steer=None):
        """``conveyor_s``: how long moving the car takes at each roll prompt; ``on_roll(step)``:
        called with each RollStep once confirmed (a PLC program's log, the CLI's output);
        ``on_steer(step)``: with each SteerStep of a steering sweep once the cycle ended."""
        self.client = client
        self.device_id = device_id
        self.timeout_s = timeout_s
        self.poll_s = poll_s
        self.conveyor_s = conveyor_s
        self.on_roll = on_roll
        self.on_steer = on_steer

    # --- Modbus primitives ----------------------------------------------------------------------
    def read_block(self, status_only: bool = False) -> dict:
        """Decode the station's output: the whole block (one read of 108 registers), or only
        the status registers 100..119 as a PLC polls them."""
        lo, hi = rm.RESULT_BLOCK
        hi = rm.STATUS_END if status_only else hi
        r = self.client.read_holding_registers(lo, count=hi - lo, device_id=self.device_id)
        if r.isError():
            raise ModbusFailure(f"reading registers {lo}..{hi - 1} failed: {r}")
        return rm.decode_block(r.registers, lo)

    def read(self, address: int, count: int) -> list[int]:
        r = self.client.read_holding_registers(address, count=count, device_id=self.device_id)
        if r.isError():
            raise ModbusFailure(f"reading registers {address}..{address + count - 1} failed: {r}")
        return r.registers

    def write(self, address: int, values: list[int]):
        """Write registers; returns the response (check ``isError()``)."""
        if len(values) == 1:
            return self.client.write_register(address, values[0], device_id=self.device_id)
        return self.client.write_registers(address, values, device_id=self.device_id)

    # --- one cycle ------------------------------------------------------------------------------
    def run_cycle(self, job_id: str, spec: str | None = None, command: int = 1,
                  expect=None) -> CycleReport:
        """One full handshake. ``expect(job_id, spec, command)`` -> ("done", result) or
        ("fault", code), to check the values too."""
        rep = CycleReport(job_id, spec, command)
        before = self.read_block(status_only=True)
        if before["state"] in (rm.STATE_CODES["done"], rm.STATE_CODES["fault"]):
            rep.problems.append(f"station was {rm.STATES[before['state']]} before the trigger; acknowledged it")
            self.acknowledge(rep)
            before = self.read_block(status_only=True)
        counter0 = before["cycle_counter"]
        f_job, f_spec = rm.FIELDS["job_id"], rm.FIELDS["vehicle_spec"]
        payload = [command] + rm.ascii_to_regs(job_id, f_job.count) + rm.ascii_to_regs(spec, f_spec.count)
        t0 = time.perf_counter()
        r = self.write(rm.COMMAND, payload)
        if r.isError():
            rep.problems.append(f"trigger refused: {r}")
            return rep
        deadline = t0 + self.timeout_s
        steering = command == rm.COMMAND_CODES["measure_caster"]
        watch = SteerWatch(self.read)
        while True:
            b = self.read_block(status_only=True)
            state = rm.STATES.get(b["state"], str(b["state"]))
            if state == "idle":
                rep.problems.append("station idle after the trigger")
            elif b["active_command"] != command:
                rep.problems.append(f"active_command {b['active_command']} != {command}")
            if state in ("busy", "roll"):
                if b["result_valid"] or b["cycle_counter"] != counter0:
                    rep.problems.append(f"a result is visible while {state}")
            if state == "roll":
                self.roll(rep, b)
                deadline += self.conveyor_s  # the conveyor's time is the PLC's
            elif state == "steer" and not steering:
                rep.problems.append(f"state steer in a cycle without a steering sweep (command {command})")
            if steering and state in ("busy", "steer"):
                before = watch.seconds
                watch.poll(b["state"])
                deadline += watch.seconds - before  # the technician's time at the steering wheel
            elif state in ("done", "fault", "idle"):
                break
            if time.perf_counter() > deadline:
                break
            if self.poll_s:
                time.sleep(self.poll_s)
        rep.state = state
        rep.steers = watch.steps
        rep.problems += watch.problems
        if steering and self.on_steer is not None:
            for step in rep.steers:
                self.on_steer(step)
        if state not in ("done", "fault"):
            rep.problems.append(f"no result within {self.timeout_s:g} s (state {state})")
            return rep
        b = self.read_block()  # the whole result in one read: it cannot change until acknowledged
        if rm.STATES.get(b["state"]) != state:
            rep.problems.append(f"state changed from {state} to {rm.STATES.get(b['state'])} before acknowledge")
        if (b["cycle_counter"] - counter0) % 65536 != 1:
            rep.problems.append(f"cycle counter moved from {counter0} to {b['cycle_counter']}")
        rep.measure_s = b["cycle_time_us"] / 1e6
        rep.fault_code, rep.reason = b["fault_code"], b["fault_reason"] or ""
        rep.uncertain = rm.uncertain_reasons_of(b["uncertain_reasons"])
        rep.angles = rm.angles_from_block(b, "f32")
        rep.pass_bits, rep.judged_bits = b["pass_bits"], b["judged_bits"]
        if steering:  # the steering block: a second read (other cycles leave it alone: one read less)
            lo, hi = rm.STEER_BLOCK
            sb = rm.decode_block(self.read(lo, hi - lo), lo)
            rep.steering_valid, rep.steering = sb["steering_valid"], steering_values(sb)
            rep.problems += check_steering(sb, steering, state == "done")
        self._check(rep, b, expect)
        self.acknowledge(rep)
        rep.total_s = time.perf_counter() - t0
        return rep

    def roll(self, rep: CycleReport, b: dict) -> None:
        """The station asks for a roll (state roll): check the prompt, move the car, confirm."""
        t0 = time.perf_counter()
        step, steps, distance, position = (b[k] for k in ("roll_step", "roll_steps", "roll_distance_mm",
                                                           "roll_position_mm"))
        p = rep.problems
        if rep.command != rm.COMMAND_CODES["measure_compensated"]:
            p.append(f"roll {step} asked for in a cycle without runout compensation (command {rep.command})")
        before = rep.rolls[-1].position_mm if rep.rolls else 0
        if step != len(rep.rolls) + 1 or not 1 <= step <= steps:
            p.append(f"roll prompt step {step} of {steps} after {len(rep.rolls)} rolls")
        if rep.rolls and steps != rep.rolls[-1].steps:
            p.append(f"roll prompt: {steps} steps, earlier {rep.rolls[-1].steps}")
        if distance == 0 or position != before + distance:
            p.append(f"roll prompt: {distance:+d} mm from {before:+d} mm does not end at {position:+d} mm")
        if self.conveyor_s:
            time.sleep(self.conveyor_s)  # the conveyor moves the car
        r = self.write(rm.COMMAND, [rm.COMMAND_CODES["in_position"]])
        if r.isError():
            p.append(f"in position refused: {r}")
        done = RollStep(step, steps, distance, position, time.perf_counter() - t0)
        rep.rolls.append(done)
        if self.on_roll is not None:
            self.on_roll(done)

    def _check(self, rep: CycleReport, b: dict, expect) -> None:
        p = rep.problems
        compensate = rep.command == rm.COMMAND_CODES["measure_compensated"]
        rep.compensated = b["runout_compensated"]
        rep.runout = {w: (None if math.isnan(b[f"{w}_runout_f32"]) else b[f"{w}_runout_f32"], b[f"{w}_runout_mm_i16"])
                      for w in WHEELS}
        if rep.state == "done":
            if rep.compensated != int(compensate):
                p.append(f"runout_compensated {rep.compensated} after command {rep.command}")
            if compensate and rep.rolls and rep.rolls[-1].step != rep.rolls[-1].steps:
                p.append(f"done after {len(rep.rolls)} of {rep.rolls[-1].steps} rolls")
            for w in WHEELS:
                deg, mm, i16 = rep.runout[w][0], rep.runout[w][1], b[f"{w}_runout_i16"]
                if (deg is None) != (i16 is None) or (deg is None) != (mm is None) or (deg is None) == compensate:
                    p.append(f"{w}: runout {deg} deg (int16 {i16}, {mm} mm) in a cycle "
                             f"{'with' if compensate else 'without'} runout compensation")
                elif deg is not None and abs(deg - i16) > 0.0051:
                    p.append(f"{w}: runout float32 {deg:.4f} and int16 {i16:.2f} disagree")
            if b["result_valid"] != 1 or b["fault_code"]:
                p.append(f"done with result_valid {b['result_valid']}, fault_code {b['fault_code']}")
            if b["result_job_id"] != rep.job_id:
                p.append(f"result belongs to job {b['result_job_id']!r}, not {rep.job_id!r}")
            ints = rm.angles_from_block(b, "i16")
            for name, v in rep.angles.items():
                if v is None or ints[name] is None:
                    if (v is None) != (ints[name] is None):
                        p.append(f"{name}: float32 {v} but int16 {ints[name]}")
                elif abs(v - ints[name]) > 0.0051:
                    p.append(f"{name}: float32 {v:.4f} and int16 {ints[name]:.2f} disagree")
        else:
            if b["result_valid"] or not b["fault_code"] or not b["fault_reason"]:
                p.append(f"fault with result_valid {b['result_valid']}, code {b['fault_code']}, "
                         f"reason {b['fault_reason']!r}")
        if expect is None:
            return
        kind, want = expect(rep.job_id, rep.spec, rep.command)
        if kind != rep.state:
            p.append(f"expected {kind}, got {rep.state}")
        elif kind == "fault" and want != rep.fault_code:
            p.append(f"expected fault code {want}, got {rep.fault_code}")
        elif kind == "done":
            for name, v in rep.angles.items():
                w = want.angle(name)
                if v is None or not math.isclose(v, w, rel_tol=1e-6, abs_tol=1e-6):
                    p.append(f"{name}: got {v}, expected {w:.6f}")
            for w in WHEELS if want.runout_compensated else ():
                deg, mm = rep.runout[w]
                if deg is None or not math.isclose(deg, want.wheels[w].runout_deg, abs_tol=1e-6) \
                        or mm is None or abs(mm - want.wheels[w].runout_mm) > 0.0051:
                    p.append(f"{w}: runout {deg} deg, {mm} mm, expected {want.wheels[w].runout_deg:.4f} deg, "
                             f"{want.wheels[w].runout_mm:.2f} mm")
        if kind == rep.state == "done" and want.steering is not None:
            for w, values in rep.steering.items():
                sw = want.steering.wheels[w]
                for key, got, exp in [(k, values[k], getattr(sw, f"{k}_deg")) for k, _ in rm.STEERING_ANGLES] + \
                        [("kingpin_offset_mm", values["kingpin_offset_mm"], sw.kingpin_offset_m * 1000)]:
                    if got is None or not math.isclose(got, exp, abs_tol=1e-4):
                        p.append(f"{w} {key}: got {got}, expected {exp:.4f}")
        if kind in ("done", "fault") and rep.command == rm.COMMAND_CODES["measure_caster"]:
            plan = steer_plan()  # the dry run walks every steer, then fails or not
            if [s.target_deg for s in rep.steers] != plan:
                p.append(f"steer targets {[s.target_deg for s in rep.steers]} deg, expected {plan} deg")
        if kind in ("done", "fault") and rep.command == rm.COMMAND_CODES["measure_compensated"]:
            plan = [round(d * 1000) for d in roll_plan()]  # the dry run asks for every roll, then fails or not
            if [r.distance_mm for r in rep.rolls] != plan:
                p.append(f"rolls {[r.distance_mm for r in rep.rolls]} mm, expected {plan} mm")

    def acknowledge(self, rep: CycleReport | None = None) -> None:
        r = self.write(rm.COMMAND, [rm.COMMAND_CODES["acknowledge"]])
        b = self.read_block(status_only=True)
        problems = rep.problems if rep else []
        if r.isError():
            problems.append(f"acknowledge refused: {r}")
        if b["state"] != rm.STATE_CODES["idle"] or b["fault_code"]:
            problems.append(f"after acknowledge: state {rm.STATES.get(b['state'])}, fault {b['fault_code']}")


def dry_run_expectation(fail_every: int = 10):
    """``expect`` callable matching ``station serve --dry-run``."""
    def expect(job_id, spec, command):
        name = rm.COMMANDS[command]
        try:
            return "done", synthetic_result(CycleRequest(name, job_id, spec, 0), fail_every)
        except StationError as e:
            return "fault", e.code
    return expect


# --- command line -------------------------------------------------------------------------------
def connect(args):
    if args.rtu:
        client = ModbusSerialClient(args.rtu, baudrate=args.baudrate, parity=args.parity,
                                    timeout=args.timeout, retries=3)
        where = f"Modbus RTU on {args.rtu}"
    else:
        client = ModbusTcpClient(args.host, port=args.port, timeout=args.timeout, retries=3)
        where = f"Modbus TCP {args.host}:{args.port}"
    if not client.connect():
        raise ModbusFailure(f"cannot connect to {where}: is `station serve` running there?")
    return client, where


def format_row(i: int, rep: CycleReport) -> str:
    vals = " ".join("     -" if rep.angles.get(a) is None else f"{rep.angles[a]:+6.2f}" for a in rm.ANGLES)
    verdict = "-"
    if rep.judged_bits >> rm.OVERALL_BIT & 1:
        verdict = "pass" if rep.pass_bits >> rm.OVERALL_BIT & 1 else "FAIL"
    status = rep.state if rep.state != "fault" else f"fault {rep.fault_code}"
    line = f"{i:>4} {rep.job_id:<12} {status:<9} {vals} {verdict:>4} {rep.handshake_s * 1e3:6.1f}"
    if rep.state == "fault":
        line += f"  {rep.reason}"
    if rep.uncertain:
        line += "\n       uncertain: " + ", ".join(f"{w} {why}" for w, why in rep.uncertain.items())
    if rep.steering_valid:
        line += "\n       " + format_steering(rep.steering)
    if rep.compensated:
        line += "\n       runout compensated: " + ", ".join(
            f"{w} {deg:.3f} deg {mm:.2f} mm" if deg is not None and mm is not None else f"{w} -"
            for w, (deg, mm) in rep.runout.items())
    return line


def header() -> str:
    names = " ".join(f"{a.replace('.total_toe', '.tt').replace('.camber', '.cb'):>6}" for a in rm.ANGLES)
    return f"{'#':>4} {'job':<12} {'state':<9} {names} {'spec':>4} {'hs ms':>6}"


HEARTBEAT_WINDOW_S = 1.0  # docs/plc.md: a heartbeat unchanged for a second means the station is down


def watch_heartbeat(sim: PlcSimulator, first: int, since: float) -> int:
    """The heartbeat register now, read again until it differs from ``first`` or
    HEARTBEAT_WINDOW_S has passed since ``since`` (a short run must not pass for a stopped one)."""
    while True:
        now = sim.read_block(status_only=True)["heartbeat"]
        if now != first or time.perf_counter() - since >= HEARTBEAT_WINDOW_S:
            return now
        time.sleep(0.02)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m station.plc.master", description=__doc__.split("\n\n")[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=5020)
    ap.add_argument("--rtu", metavar="DEVICE", help="Modbus RTU on this serial device instead of TCP")
    ap.add_argument("--baudrate", type=int, default=19200)
    ap.add_argument("--parity", default="E", choices=("N", "E", "O"))
    ap.add_argument("--device-id", type=int, default=1)
    ap.add_argument("--cycles", type=int, default=3)
    ap.add_argument("--job-prefix", default="JOB-")
    ap.add_argument("--first-job", type=int, default=1)
    ap.add_argument("--spec", default=None, help="vehicle spec id sent with every trigger")
    ap.add_argument("--timeout", type=float, default=3.0, help="Modbus response timeout (s)")
    ap.add_argument("--dry-run-check", action="store_true",
                    help="also check the angles against `station serve --dry-run`'s synthetic results")
    ap.add_argument("--fail-every", type=int, default=10, help="the dry run's --fail-every")
    ap.add_argument("--poll-s", type=float, default=0.005,
                    help="pause between state polls while the station is busy (s; 0: none)")
    ap.add_argument("--compensate", action="store_true",
                    help="every trigger measures with runout compensation (command 5): the simulator rolls "
                         "the car whenever the station asks (state 4) and confirms each roll (command 6)")
    ap.add_argument("--caster", action="store_true",
                    help="every trigger is a steering sweep (command 7): the simulator watches the steer state "
                         "(5) and the live steer angle, and prints each steer and the caster, SAI, included angle "
                         "and kingpin offset")
    ap.add_argument("--conveyor-s", type=float, default=0.2,
                    help="with --compensate: seconds the simulated conveyor takes to move the car (default 0.2)")
    ap.add_argument("--quiet", action="store_true", help="print only the summary")
    args = ap.parse_args(argv)
    if args.conveyor_s < 0:
        ap.error(f"--conveyor-s {args.conveyor_s:g}: expected 0 or more seconds")
    if args.caster and args.compensate:
        ap.error("--caster and --compensate: a cycle is one or the other (command 7 or 5)")
    try:
        client, where = connect(args)
    except ModbusFailure as e:
        print(f"plc_sim: {e}", file=sys.stderr)
        return 2
    show = None if args.quiet else (lambda r: print(f"       {r.describe()}", flush=True))
    sim = PlcSimulator(client, device_id=args.device_id, poll_s=args.poll_s, conveyor_s=args.conveyor_s,
                       on_roll=show, on_steer=show)
    expect = dry_run_expectation(args.fail_every) if args.dry_run_check else None
    if args.caster:
        steer_plan()  # the procedure's module imported now, not inside the first cycle's time
    command = rm.COMMAND_CODES["measure_compensated" if args.compensate else "measure_caster" if args.caster
                               else "measure"]
    kind = ", runout compensation (command 5)" if args.compensate else ", steering sweep (command 7)" if args.caster \
        else ""
    print(f"PLC simulator: {args.cycles} cycles on {where}, device id {args.device_id}{kind}")
    if not args.quiet:
        print(header())
    bad = rolls = steers = 0
    try:
        hb0 = sim.read_block()["heartbeat"]
        t_start = time.perf_counter()
        for i in range(args.cycles):
            rep = sim.run_cycle(f"{args.job_prefix}{args.first_job + i:06d}", args.spec, command, expect=expect)
            bad += bool(rep.problems)
            rolls += len(rep.rolls)
            steers += len(rep.steers)
            if not args.quiet:
                print(format_row(i + 1, rep))
                for p in rep.problems:
                    print(f"       problem: {p}")
        hb1 = watch_heartbeat(sim, hb0, t_start)
    except (ModbusFailure, ModbusException) as e:
        print(f"plc_sim: the station stopped answering: {e}", file=sys.stderr)
        return 2
    finally:
        client.close()
    beat = (f"advancing ({hb0} -> {hb1})" if hb1 != hb0
            else f"STOPPED (still {hb0} after {time.perf_counter() - t_start:.1f} s)")
    made = f", {rolls} rolls of the car" if args.compensate else f", {steers} steers" if args.caster else ""
    print(f"{args.cycles} cycles, {bad} with problems{made}; heartbeat {beat}")
    return 1 if bad or hb1 == hb0 else 0


if __name__ == "__main__":
    sys.exit(main())
