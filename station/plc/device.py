"""The station as a Modbus device: register memory, the handshake, cycles, the heartbeat.

Transport-free: :mod:`station.plc.server` puts it on TCP or on a serial line. Everything that
touches the registers runs on the asyncio event loop, in one synchronous step per change, so a
Modbus request (also handled on the loop) sees a result either wholly before or wholly after
it is written. The cycle itself (the injected :data:`runner.CycleRunner`) runs in a worker
thread.

A cycle with runout compensation (command 5) asks for the car to be rolled from its worker
thread (station/plc/gates.py, station/plc/roll_operator.py): the prompt is published and state roll
entered on the loop, and the thread waits until the PLC's in position (command 6), the roll
timeout (``roll_timeout_s``: back to busy, the cycle ends in fault 415) or the server stopping.

A steering sweep (command 7) asks for each steer of the front wheels the same way
(station/plc/steer_operator.py): the steer prompt is published and state steer entered; the
station's guide hands every live reading on (the live steer registers) and ends the steer once
the wheels stand still at the target (back to busy: the PLC confirms nothing). A steer not ended
within ``steer_timeout_s`` goes back to busy on its own, clears the steer registers and fails the
guide's next reading, so the cycle ends in fault 424.

Time spent in roll and in steer is the operator's (the PLC's conveyor, the technician at the
steering wheel), not the station's: it counts neither against the cycle timeout nor in
``cycle_time_us``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from station.errors import (CODED_ERRORS, MeasurementError, PlcError, RollNotConfirmed, StationError,
                            SteerNotReached)
from station.plc import register_map as rm
from station.plc.gates import LoopRollGate, LoopSteerGate
from station.plc.handshake import (TRIGGERS, Event, PlcBadJobId, PlcCycleTimeout, State, event_for_command,
                                   modbus_exception, next_state, roll_timeout_error, steer_timeout_error)
from station.plc.results import (cleared_registers, result_registers, roll_prompt_registers, steer_live_registers,
                                 steer_prompt_registers, warning_registers)
from station.plc.roll_operator import RollPrompt
from station.plc.runner import CycleRequest, CycleRunner
from station.plc.steer_operator import SteerPrompt
from station.result import Measurement

log = logging.getLogger("station.plc")

BIT_FUNCTIONS = (1, 2, 5, 15)  # coils / discrete inputs: the map has none
REQUEST_COMMANDS = {Event.MEASURE: "measure", Event.CALIBRATION_CHECK: "calibration_check",
                    Event.MEASURE_COMPENSATED: "measure_compensated", Event.MEASURE_CASTER: "measure_caster"}


@dataclass
class _PendingRoll:
    """The roll the station waits for: its cycle, prompt, the waiting thread's future, the timer."""

    cycle: int
    prompt: RollPrompt
    done: concurrent.futures.Future
    timer: asyncio.TimerHandle | None
    t0: float


@dataclass
class _PendingSteer:
    """The steer the station waits for: its cycle, prompt, timer, start; ``error``: why it ended
    without the wheels at the target (the timeout, the station stopping), raised at the guide's
    next reading."""

    cycle: int
    prompt: SteerPrompt
    timer: asyncio.TimerHandle | None
    t0: float
    error: Exception | None = None


class PlcDevice:
    """Register memory + handshake. ``stats`` counts cycles and refusals."""

    def __init__(self, runner: CycleRunner, *, device_id: int = 1, heartbeat_s: float = 0.1,
                 cycle_timeout_s: float = 300.0, roll_timeout_s: float = 120.0, steer_timeout_s: float = 120.0):
        self.runner = runner
        self.device_id = device_id
        self.heartbeat_s = heartbeat_s
        self.cycle_timeout_s = cycle_timeout_s
        self.roll_timeout_s = roll_timeout_s
        self.steer_timeout_s = steer_timeout_s
        self.state = State.IDLE
        self.cycle_number = 0  # cycles started
        self.stats = {"started": 0, "done": 0, "fault": 0, "acknowledged": 0, "refused": 0, "rolls": 0,
                      "roll_timeouts": 0, "steers": 0, "steer_timeouts": 0}
        self.last_result: Measurement | None = None
        self.stopped = False
        self._roll: _PendingRoll | None = None  # the roll the running cycle waits for
        self._steer: _PendingSteer | None = None  # the steer the running cycle waits for
        self._operator_s = 0.0  # time the running cycle has spent in roll and in steer
        self._steer_readings = 0  # live steer readings in the running cycle
        self._regs: list[int] | None = None
        self._start = 0
        self._task: asyncio.Task | None = None
        self._heartbeat: asyncio.Task | None = None
        # called on the loop after each complete step (a state entered, a command refused): the
        # OPC UA server mirrors the registers then (station/plc/opcua_server.py)
        self.listeners: list = []
        # One worker thread runs the cycles (one at a time by the handshake); a cycle that
        # overruns its timeout keeps its thread, and the next cycle gets a fresh one.
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="plc-cycle")

    # --- the pymodbus datastore -----------------------------------------------------------------
    def simdevice(self) -> SimDevice:
        """The SimDevice to serve: PLC fields writable, everything else read-only, nothing above
        the station area (exception 2 there)."""
        plc_end = max(f.end for f in rm.PLC_FIELDS)
        lo, hi = rm.STATION_AREA
        blocks = [SimData(0, count=plc_end, values=0, datatype=DataType.REGISTERS),
                  SimData(plc_end, count=lo - plc_end, values=0, datatype=DataType.REGISTERS, readonly=True),
                  SimData(lo, count=hi - lo, values=0, datatype=DataType.REGISTERS, readonly=True)]
        return SimDevice(id=self.device_id, simdata=blocks, action=self._action)

    def bind(self, registers: list[int], start: int) -> None:
        """Attach to the server's register memory (the list pymodbus serves) and initialise it."""
        self._regs, self._start = registers, start
        self._put(cleared_registers())
        self._set("map_version", rm.MAP_VERSION)
        self._set("state", self.state.value)

    def _set(self, name: str, value: int) -> None:
        self._regs[rm.FIELDS[name].address - self._start] = value & 0xFFFF

    def _get(self, name: str) -> int:
        return self._regs[rm.FIELDS[name].address - self._start]

    def _put(self, values: dict[int, list[int]]) -> None:
        for address, regs in values.items():
            i = address - self._start
            self._regs[i:i + len(regs)] = regs

    def registers(self, address: int, count: int) -> list[int]:
        """A copy of ``count`` registers from ``address`` (for tests and diagnostics)."""
        i = address - self._start
        return list(self._regs[i:i + count])

    # --- requests -------------------------------------------------------------------------------
    async def _action(self, function_code, start, address, count, current, values):
        """pymodbus calls this before applying a request (read: ``values`` is None). Writes to
        read-only registers never get here (pymodbus answers exception 2 first)."""
        if function_code in BIT_FUNCTIONS:
            return ExcCodes.ILLEGAL_FUNCTION
        if values is None or not address <= rm.COMMAND < address + count:
            return None
        i = rm.COMMAND - address
        if not values[i]:
            return None  # writing 0 ("none") just clears the mailbox
        plc = list(current[:rm.PLC_AREA[1]])  # the PLC area as it will be after this write
        plc[address - start:address - start + count] = values
        refused = self.submit(int(values[i]), plc)
        if refused is not None:
            return ExcCodes(modbus_exception(refused))
        # Consumed: the mailbox reads back 0 once this write is applied. The response still
        # echoes the written value, as function 6 requires (libmodbus checks the echo).
        asyncio.get_running_loop().call_soon(self._set, "command", 0)
        return None

    def submit(self, value: int, plc: list[int]) -> PlcError | None:
        """A command from any protocol (Modbus, OPC UA): applied, or refused with the refusal
        counted and kept in ``reject_code``/``reject_count`` (returned, None when applied)."""
        try:
            self.command(value, plc)
        except PlcError as e:
            self.refuse(e, value)
            return e
        return None

    def refuse(self, error: PlcError, value: int | str) -> None:
        """Count a refused command and show its code in ``reject_code``/``reject_count``."""
        self.stats["refused"] += 1
        self._set("reject_code", error.code)
        self._set("reject_count", self._get("reject_count") + 1)
        log.warning("PLC command %s refused (%d): %s", value, error.code, error)
        self._changed()

    def _changed(self) -> None:
        """Tell the listeners (another protocol's mirror of the registers) that a step is complete."""
        for listener in self.listeners:
            listener()

    def command(self, value: int, plc: list[int]) -> None:
        """Apply a PLC command; ``plc`` is the PLC area's registers. Raises PlcError to refuse."""
        event = event_for_command(value)
        new = next_state(self.state, event)
        if event in TRIGGERS:
            job, spec = (self._text(plc, name) for name in ("job_id", "vehicle_spec"))
            self._start_cycle(event, job, spec)
        elif event is Event.IN_POSITION:
            self._end_roll().done.set_result(None)
            log.info("cycle %d: the PLC confirmed the car in position", self.cycle_number)
        else:
            if self.state in (State.DONE, State.FAULT):
                self.stats["acknowledged"] += 1
            self._set("fault_code", 0)
            self._put({rm.FIELDS["fault_reason"].address: [0] * rm.FIELDS["fault_reason"].count})
        self._enter(new)

    @staticmethod
    def _text(plc: list[int], name: str) -> str | None:
        f = rm.FIELDS[name]
        try:
            return rm.regs_to_ascii(plc[f.address:f.end]) or None
        except ValueError as e:
            raise PlcBadJobId(f"trigger refused: {name} registers {f.address}..{f.end - 1} are not "
                              f"printable ASCII ({e})") from None

    def _enter(self, state: State) -> None:
        self.state = state
        self._set("state", state.value)
        self._changed()  # every step that changes the state ends here, its registers all written

    # --- cycles ---------------------------------------------------------------------------------
    def _start_cycle(self, event: Event, job: str | None, spec: str | None) -> None:
        self.cycle_number += 1
        self.stats["started"] += 1
        loop = asyncio.get_running_loop()
        roll = LoopRollGate(self, loop, self.cycle_number) if event is Event.MEASURE_COMPENSATED else None
        steer = LoopSteerGate(self, loop, self.cycle_number) if event is Event.MEASURE_CASTER else None
        request = CycleRequest(REQUEST_COMMANDS[event], job, spec, self.cycle_number, roll=roll, steer=steer)
        self._operator_s = 0.0
        self._steer_readings = 0
        self._put(cleared_registers())
        self._put(steer_live_registers())
        for name in ("result_valid", "fault_code"):
            self._set(name, 0)
        self._put({rm.FIELDS["cycle_time_us"].address: rm.u32_to_regs(0)})
        self._set("active_command", event.value)
        log.info("cycle %d: %s, job %s, spec %s", request.cycle, request.command, job, spec)
        self._task = loop.create_task(self._run(request))

    def _station_time(self, t0: float) -> float:
        """Seconds since ``t0`` that the station spent on the cycle: the time in roll and in steer,
        the operator's, left out."""
        now = time.perf_counter()
        waiting = sum(now - p.t0 for p in (self._roll, self._steer) if p is not None)
        return now - t0 - self._operator_s - waiting

    async def _wait(self, work: asyncio.Future, t0: float):
        """``work``'s result; asyncio.TimeoutError once the station's own time (not the time in
        roll) exceeds the cycle timeout."""
        while True:
            budget = self.cycle_timeout_s - self._station_time(t0)
            if budget <= 0 and self._roll is None and self._steer is None:
                raise asyncio.TimeoutError
            done, _ = await asyncio.wait({work}, timeout=max(budget, 0.05))
            if done:
                return work.result()

    async def _run(self, request: CycleRequest) -> None:
        t0 = time.perf_counter()
        try:
            work = asyncio.get_running_loop().run_in_executor(self._executor, self.runner, request)
            result = await self._wait(work, t0)
        except CODED_ERRORS as e:  # a camera or calibration fault too: its code is the fault code
            return self._fault(request, e.code, str(e), self._station_time(t0))
        except asyncio.TimeoutError:
            self._executor.shutdown(wait=False)
            self._executor = ThreadPoolExecutor(1, thread_name_prefix="plc-cycle")
            return self._fault(request, PlcCycleTimeout.code,
                               f"cycle timed out after {self.cycle_timeout_s:g} s", self._station_time(t0))
        except Exception as e:  # noqa: BLE001 - a bug in the pipeline must not stop the server
            log.exception("cycle %d: the runner crashed", request.cycle)
            return self._fault(request, StationError.code, f"internal error: {type(e).__name__}: {e}",
                               self._station_time(t0))
        elapsed = self._station_time(t0)
        self.last_result = result
        try:
            if not isinstance(result, Measurement):
                raise MeasurementError(f"the measurement returned {type(result).__name__}, not a result")
            if not result.valid:
                failure = result.failure
                code = failure.code if failure is not None and isinstance(failure.code, int) else MeasurementError.code
                return self._fault(request, code, str((failure and failure.message) or "invalid result"), elapsed,
                                   warning_registers(result))
            values = result_registers(result, request.job_id, request.command in ("measure", "measure_caster"),
                                      steering_required=request.command == "measure_caster")
        except StationError as e:
            return self._fault(request, e.code, str(e), elapsed)
        self._finish(request, Event.CYCLE_OK, values, elapsed)

    def _fault(self, request: CycleRequest, code: int, reason: str, elapsed: float,
               warnings: dict | None = None) -> None:
        """Publish a failed cycle: its code and reason, and ``warnings`` (a refused result's
        warning registers, ``warning_registers``: which wheels a 404 refused and why)."""
        f = rm.FIELDS["fault_reason"]
        self._finish(request, Event.CYCLE_FAILED,
                     {**(warnings or {}), f.address: rm.ascii_to_regs(reason, f.count),
                      rm.FIELDS["fault_code"].address: [code & 0xFFFF]}, elapsed)
        log.warning("cycle %d failed (%d): %s", request.cycle, code, reason)

    def _finish(self, request: CycleRequest, event: Event, values: dict, elapsed: float) -> None:
        """Publish a finished cycle in one step: results, flags, counter, then the state."""
        try:
            new = next_state(self.state, event)
        except PlcError as e:  # a cycle that ended after its timeout: nothing to publish
            log.warning("cycle %d: %s", request.cycle, e)
            return
        if self._roll is not None:  # never left waiting in roll (a crash, the cycle timeout)
            self._end_roll().done.set_exception(RollNotConfirmed(f"cycle {request.cycle} ended"))
        if self._steer is not None:  # nor in steer
            self._release_steer().error = SteerNotReached(f"cycle {request.cycle} ended")
        self._put(steer_live_registers())  # a steering sweep's last live reading goes with its cycle
        self._put(values)
        self._put({rm.FIELDS["cycle_time_us"].address: rm.u32_to_regs(round(elapsed * 1e6))})
        self._set("result_valid", int(event is Event.CYCLE_OK))
        self._set("cycle_counter", self._get("cycle_counter") + 1)
        self.stats["done" if event is Event.CYCLE_OK else "fault"] += 1
        self._enter(new)

    # --- the operator's waits (rolls, steers) ---------------------------------------------------
    def _wait_state(self, cycle: int, event: Event):
        """(the state cycle ``cycle`` enters to wait for the operator on ``event``, None) or
        (None, why it may not: a stopped server, a cycle abandoned after its timeout, a wait
        already pending)."""
        if self.stopped:
            return None, "the station stopped"
        if cycle != self.cycle_number or self._roll is not None or self._steer is not None:
            return None, f"cycle {cycle} is not the running cycle, or it waits for a roll or a steer already"
        try:
            return next_state(self.state, event), None
        except PlcError as e:  # a cycle abandoned after its timeout: the station is not busy
            return None, str(e)

    def _stop_waiting(self, pending, cleared_prompt: dict[int, list[int]]) -> None:
        """A wait that ends: its timer stopped, its time counted (the operator's, not the
        station's), its prompt registers cleared with ``cleared_prompt``."""
        if pending.timer is not None:
            pending.timer.cancel()
        self._operator_s += time.perf_counter() - pending.t0
        self._put(cleared_prompt)

    # --- rolls (runout compensation) -------------------------------------------------------------
    def _ask_roll(self, cycle: int, prompt: RollPrompt, done: concurrent.futures.Future) -> None:
        """On the loop: cycle ``cycle`` asks for ``prompt``. Publishes the prompt and enters roll,
        or answers ``done`` with the refusal (a cycle abandoned after its timeout, a stopped
        server: it must not wait)."""
        new, why = self._wait_state(cycle, Event.ROLL_REQUEST)
        if why is not None:
            log.warning("cycle %d: %s not asked of the PLC: %s", cycle, prompt.describe(), why)
            done.set_exception(RollNotConfirmed(f"roll {prompt.step}/{prompt.steps} not asked of the PLC: {why}"))
            return
        pending = _PendingRoll(cycle, prompt, done, None, time.perf_counter())
        pending.timer = asyncio.get_running_loop().call_later(self.roll_timeout_s, self._roll_timed_out, pending)
        self._roll = pending
        self.stats["rolls"] += 1
        self._put(roll_prompt_registers(prompt.step, prompt.steps, prompt.distance_mm, prompt.position_mm))
        self._enter(new)
        log.info("cycle %d: %s asked of the PLC", cycle, prompt.describe())

    def _end_roll(self) -> _PendingRoll:
        """The pending roll, no longer pending: its timer stopped, its time counted, the prompt
        cleared (the caller answers its thread and moves the state)."""
        pending, self._roll = self._roll, None
        self._stop_waiting(pending, roll_prompt_registers())
        return pending

    def _roll_timed_out(self, pending: _PendingRoll) -> None:
        if self._roll is not pending:
            return
        try:
            new = next_state(self.state, Event.ROLL_TIMEOUT)
        except PlcError as e:
            log.warning("cycle %d: %s", pending.cycle, e)
            return
        self._end_roll()
        self.stats["roll_timeouts"] += 1
        p = pending.prompt
        pending.done.set_exception(roll_timeout_error(p.step, p.steps, self.roll_timeout_s))
        self._enter(new)  # busy: the cycle ends in fault 415 as its worker thread unwinds
        log.warning("cycle %d: %s not confirmed within %g s", pending.cycle, p.describe(), self.roll_timeout_s)

    # --- steers (a steering sweep) ---------------------------------------------------------------
    def _ask_steer(self, cycle: int, prompt: SteerPrompt, done: concurrent.futures.Future) -> None:
        """On the loop: cycle ``cycle`` asks for ``prompt``. Publishes the prompt, no live reading
        yet, enters steer and answers ``done`` with the pending steer; or answers the refusal (a
        cycle abandoned after its timeout, a stopped server: it must not steer on)."""
        new, why = self._wait_state(cycle, Event.STEER_REQUEST)
        if why is not None:
            log.warning("cycle %d: %s not asked of the PLC: %s", cycle, prompt.describe(), why)
            done.set_exception(SteerNotReached(f"steer {prompt.step}/{prompt.steps} not asked of the PLC: {why}"))
            return
        pending = _PendingSteer(cycle, prompt, None, time.perf_counter())
        pending.timer = asyncio.get_running_loop().call_later(self.steer_timeout_s, self._steer_timed_out, pending)
        self._steer = pending
        self.stats["steers"] += 1
        self._put(steer_prompt_registers(prompt.step, prompt.steps, prompt.target_deg))
        self._put(steer_live_registers(readings=self._steer_readings))
        self._enter(new)
        done.set_result(pending)
        log.info("cycle %d: %s asked (state steer)", cycle, prompt.describe())

    def _steer_reading(self, pending: _PendingSteer, angles: dict[str, float], reached: bool) -> None:
        """On the loop: a live reading of the running steer -> the live registers (one that comes
        after its steer ended is dropped)."""
        if self._steer is not pending:
            return
        self._steer_readings += 1
        self._put(steer_live_registers(angles, reached, self._steer_readings))

    def _end_steer(self, pending: _PendingSteer, error: BaseException | None, done: concurrent.futures.Future) -> None:
        """On the loop: the guide is done with ``pending``: the wheels stand at the target (``error``
        None: busy, the last reading kept) or it gave up (busy, the live registers cleared; the
        cycle ends in fault with ``error``'s code)."""
        if self._steer is pending:
            try:
                new = next_state(self.state, Event.STEER_REACHED if error is None else Event.STEER_FAILED)
            except PlcError as e:
                log.warning("cycle %d: %s", pending.cycle, e)
                new = None
            self._release_steer()
            if error is not None:
                self._put(steer_live_registers(readings=self._steer_readings))
                self.stats["steer_timeouts"] += isinstance(error, SteerNotReached)
                log.warning("cycle %d: %s not reached: %s", pending.cycle, pending.prompt.describe(), error)
            if new is not None:
                self._enter(new)
        done.set_result(None)

    def _release_steer(self) -> _PendingSteer:
        """The pending steer, no longer pending: its timer stopped, its time counted (the operator's),
        the prompt cleared (the caller moves the state)."""
        pending, self._steer = self._steer, None
        self._stop_waiting(pending, steer_prompt_registers())
        return pending

    def _steer_timed_out(self, pending: _PendingSteer) -> None:
        if self._steer is not pending:
            return
        try:
            new = next_state(self.state, Event.STEER_FAILED)
        except PlcError as e:
            log.warning("cycle %d: %s", pending.cycle, e)
            return
        p = pending.prompt
        self._release_steer().error = steer_timeout_error(p.step, p.steps, p.target_deg, self.steer_timeout_s)
        self._put(steer_live_registers(readings=self._steer_readings))
        self.stats["steer_timeouts"] += 1
        self._enter(new)  # busy: the cycle ends in fault 424 at the guide's next reading
        log.warning("cycle %d: %s not reached within %g s", pending.cycle, p.describe(), self.steer_timeout_s)

    # --- heartbeat ------------------------------------------------------------------------------
    def start_heartbeat(self) -> None:
        async def beat():
            while True:
                await asyncio.sleep(self.heartbeat_s)
                self._set("heartbeat", self._get("heartbeat") + 1)
        self._heartbeat = asyncio.get_running_loop().create_task(beat())

    async def stop(self) -> None:
        self.stopped = True
        if self._roll is not None:  # let the cycle's thread go: nobody will confirm the roll now
            self._end_roll().done.set_exception(RollNotConfirmed("the station stopped waiting for the PLC's roll"))
        if self._steer is not None:  # the guide's next reading ends the cycle
            self._release_steer().error = SteerNotReached("the station stopped waiting for the steer")
        for task in (self._heartbeat, self._task):
            if task and not task.done():
                task.cancel()
                try:
                    await task
                except (asyncio.CancelledError, Exception):  # noqa: BLE001 - shutting down
                    pass
        self._executor.shutdown(wait=False)
