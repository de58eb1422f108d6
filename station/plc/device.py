"""The station as a Modbus device: register memory, the handshake, cycles, the heartbeat.

Transport-free: :mod:`station.plc.server` puts it on TCP or on a serial line. Everything that
touches the registers runs on the asyncio event loop, in one synchronous step per change, so a
Modbus request (also handled on the loop) sees a result either wholly before or wholly after
it is written. The cycle itself (the injected :data:`runner.CycleRunner`) runs in a worker
thread.
"""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import ThreadPoolExecutor

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from station.errors import CODED_ERRORS, MeasurementError, PlcError, StationError
from station.plc import register_map as rm
from station.plc.handshake import (Event, PlcBadJobId, PlcCycleTimeout, State, event_for_command,
                                   modbus_exception, next_state)
from station.plc.results import cleared_registers, result_registers
from station.plc.runner import CycleRequest, CycleRunner
from station.result import Measurement

log = logging.getLogger("station.plc")

BIT_FUNCTIONS = (1, 2, 5, 15)  # coils / discrete inputs: the map has none


class PlcDevice:
    """Register memory + handshake. ``stats`` counts cycles and refusals."""

    def __init__(self, runner: CycleRunner, *, device_id: int = 1, heartbeat_s: float = 0.1,
                 cycle_timeout_s: float = 300.0):
        self.runner = runner
        self.device_id = device_id
        self.heartbeat_s = heartbeat_s
        self.cycle_timeout_s = cycle_timeout_s
        self.state = State.IDLE
        self.cycle_number = 0  # cycles started
        self.stats = {"started": 0, "done": 0, "fault": 0, "acknowledged": 0, "refused": 0}
        self.last_result: Measurement | None = None
        self._regs: list[int] | None = None
        self._start = 0
        self._task: asyncio.Task | None = None
        self._heartbeat: asyncio.Task | None = None
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
        try:
            self.command(int(values[i]), plc)
        except PlcError as e:
            self.stats["refused"] += 1
            self._set("reject_code", e.code)
            self._set("reject_count", self._get("reject_count") + 1)
            log.warning("PLC command %s refused (%d): %s", values[i], e.code, e)
            return ExcCodes(modbus_exception(e))
        # Consumed: the mailbox reads back 0 once this write is applied. The response still
        # echoes the written value, as function 6 requires (libmodbus checks the echo).
        asyncio.get_running_loop().call_soon(self._set, "command", 0)
        return None

    def command(self, value: int, plc: list[int]) -> None:
        """Apply a PLC command; ``plc`` is the PLC area's registers. Raises PlcError to refuse."""
        event = event_for_command(value)
        new = next_state(self.state, event)
        if event in (Event.MEASURE, Event.CALIBRATION_CHECK):
            job, spec = (self._text(plc, name) for name in ("job_id", "vehicle_spec"))
            self._start_cycle(event, job, spec)
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

    # --- cycles ---------------------------------------------------------------------------------
    def _start_cycle(self, event: Event, job: str | None, spec: str | None) -> None:
        self.cycle_number += 1
        self.stats["started"] += 1
        request = CycleRequest("measure" if event is Event.MEASURE else "calibration_check",
                               job, spec, self.cycle_number)
        self._put(cleared_registers())
        for name in ("result_valid", "fault_code"):
            self._set(name, 0)
        self._put({rm.FIELDS["cycle_time_us"].address: rm.u32_to_regs(0)})
        self._set("active_command", event.value)
        log.info("cycle %d: %s, job %s, spec %s", request.cycle, request.command, job, spec)
        self._task = asyncio.get_running_loop().create_task(self._run(request))

    async def _run(self, request: CycleRequest) -> None:
        t0 = time.perf_counter()
        try:
            work = asyncio.get_running_loop().run_in_executor(self._executor, self.runner, request)
            result = await asyncio.wait_for(work, self.cycle_timeout_s)
        except CODED_ERRORS as e:  # a camera or calibration fault too: its code is the fault code
            return self._fault(request, e.code, str(e), time.perf_counter() - t0)
        except asyncio.TimeoutError:
            self._executor.shutdown(wait=False)
            self._executor = ThreadPoolExecutor(1, thread_name_prefix="plc-cycle")
            return self._fault(request, PlcCycleTimeout.code,
                               f"cycle timed out after {self.cycle_timeout_s:g} s", time.perf_counter() - t0)
        except Exception as e:  # noqa: BLE001 - a bug in the pipeline must not stop the server
            log.exception("cycle %d: the runner crashed", request.cycle)
            return self._fault(request, StationError.code, f"internal error: {type(e).__name__}: {e}",
                               time.perf_counter() - t0)
        elapsed = time.perf_counter() - t0
        self.last_result = result
        try:
            if not isinstance(result, Measurement):
                raise MeasurementError(f"the measurement returned {type(result).__name__}, not a result")
            if not result.valid:
                failure = result.failure
                code = failure.code if failure is not None and isinstance(failure.code, int) else MeasurementError.code
                return self._fault(request, code, str((failure and failure.message) or "invalid result"), elapsed)
            values = result_registers(result, request.job_id, request.command == "measure")
        except StationError as e:
            return self._fault(request, e.code, str(e), elapsed)
        self._finish(request, Event.CYCLE_OK, values, elapsed)

    def _fault(self, request: CycleRequest, code: int, reason: str, elapsed: float) -> None:
        f = rm.FIELDS["fault_reason"]
        self._finish(request, Event.CYCLE_FAILED,
                     {f.address: rm.ascii_to_regs(reason, f.count),
                      rm.FIELDS["fault_code"].address: [code & 0xFFFF]}, elapsed)
        log.warning("cycle %d failed (%d): %s", request.cycle, code, reason)

    def _finish(self, request: CycleRequest, event: Event, values: dict, elapsed: float) -> None:
        """Publish a finished cycle in one step: results, flags, counter, then the state."""
        try:
            new = next_state(self.state, event)
        except PlcError as e:  # a cycle that ended after its timeout: nothing to publish
            log.warning("cycle %d: %s", request.cycle, e)
            return
        self._put(values)
        self._put({rm.FIELDS["cycle_time_us"].address: rm.u32_to_regs(round(elapsed * 1e6))})
        self._set("result_valid", int(event is Event.CYCLE_OK))
        self._set("cycle_counter", self._get("cycle_counter") + 1)
        self.stats["done" if event is Event.CYCLE_OK else "fault"] += 1
        self._enter(new)

    # --- heartbeat ------------------------------------------------------------------------------
    def start_heartbeat(self) -> None:
        async def beat():
            while True:
                await asyncio.sleep(self.heartbeat_s)
                self._set("heartbeat", self._get("heartbeat") + 1)
        self._heartbeat = asyncio.get_running_loop().create_task(beat())

    async def stop(self) -> None:
        for task in (self._heartbeat, self._task):
            if task and not task.done():
                task.cancel()
                try:
                    await task
                except (asyncio.CancelledError, Exception):  # noqa: BLE001 - shutting down
                    pass
        self._executor.shutdown(wait=False)
