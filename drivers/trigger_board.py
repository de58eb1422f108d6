"""The trigger board: fires the cameras' hardware trigger inputs and the strobes together.

A small line protocol over a serial line (pyserial), documented in docs/cameras.md:
ASCII, one command per line ending in LF, exactly one reply line per command, replies start
with ``OK`` or ``ERR <code> <text>``. FIRE carries a sequence number that its reply echoes,
so a late reply to an earlier command is recognised and skipped, never taken for this one.

    board = TriggerBoard("/dev/ttyUSB0", 115200).open()
    report = board.fire()            # every line; or fire(mask=0b101)
    report.seq, report.board_time_us, report.fired_mask

Every read has a deadline (``timeout_s``); a silent, wrong or faulty board is a DriverError
naming the port (and the lines that did not fire).
"""

from __future__ import annotations

import itertools
import logging
import time
from dataclasses import dataclass

from drivers.errors import DriverError, TriggerBoardError

log = logging.getLogger("station.drivers.trigger_board")



@dataclass(frozen=True)
class FireReport:
    seq: int
    board_time_us: int  # the board's clock at the trigger edge
    fired_mask: int  # the outputs that actually fired
    host_ns: int  # host monotonic clock when the command was sent


class TriggerBoard:
    def __init__(self, port: str, baudrate: int = 115200, timeout_s: float = 0.5,
                 n_lines: int | None = None):
        self.port = port
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.n_lines = n_lines
        self.model = ""
        self.firmware = ""
        self._serial = None
        self._seq = itertools.count(1)

    # --- connection -------------------------------------------------------------------------
    def open(self) -> "TriggerBoard":
        import serial  # pyserial; a station without a board never imports it

        try:
            self._serial = serial.Serial(self.port, self.baudrate, timeout=self.timeout_s,
                                         write_timeout=self.timeout_s)
        except (serial.SerialException, OSError) as e:
            raise TriggerBoardError(f"trigger board: cannot open {self.port} ({e})",
                                    hint="check trigger_board.port in the station configuration and the USB cable") from None
        self._serial.reset_input_buffer()
        words = self._command("ID?", "ID")
        if len(words) < 3 or not words[2].startswith("LINES="):
            raise TriggerBoardError(f"trigger board on {self.port}: unexpected identity {' '.join(words)!r}")
        self.model, self.firmware = words[0], words[1]
        lines = int(words[2].split("=", 1)[1])
        if self.n_lines is not None and lines < self.n_lines:
            raise TriggerBoardError(f"trigger board on {self.port} has {lines} lines, the station needs {self.n_lines}")
        self.n_lines = lines
        log.info("trigger board %s %s on %s, %d lines", self.model, self.firmware, self.port, lines)
        return self

    def close(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            finally:
                self._serial = None

    def __enter__(self):
        return self if self._serial is not None else self.open()

    def __exit__(self, *exc):
        self.close()

    # --- commands ---------------------------------------------------------------------------
    def ping(self) -> float:
        """Round-trip time in seconds."""
        t = time.monotonic()
        token = f"{next(self._seq)}"
        words = self._command(f"PING {token}", "PONG")
        if words != [token]:
            raise TriggerBoardError(f"trigger board on {self.port}: PING {token} answered {words}")
        return time.monotonic() - t

    def set_strobe_us(self, us: int) -> None:
        self._command(f"STROBE {int(us)}", "STROBE")

    def set_pulse_us(self, us: int) -> None:
        self._command(f"PULSE {int(us)}", "PULSE")

    def status(self) -> dict[str, int]:
        words = self._command("STATUS?", "STATUS")
        out = {}
        for w in words:
            k, _, v = w.partition("=")
            out[k.lower()] = int(v, 16) if k == "FAULT" else int(v)
        return out

    def fire(self, mask: int | None = None) -> FireReport:
        """Fire the lines in ``mask`` (default: all) and the strobes on one edge."""
        if self.n_lines is None:
            raise TriggerBoardError(f"trigger board on {self.port}: fire() before open()")
        mask = (1 << self.n_lines) - 1 if mask is None else mask
        seq = next(self._seq)
        host_ns = time.monotonic_ns()
        words = self._command(f"FIRE {seq} {mask:02X}", "FIRED", seq=seq)
        try:
            board_us, fired = int(words[1]), int(words[2], 16)
        except (IndexError, ValueError):
            raise TriggerBoardError(f"trigger board on {self.port}: malformed FIRED reply {words}") from None
        if fired != mask:
            dead = [str(i) for i in range(self.n_lines) if (mask & ~fired) >> i & 1]
            err = TriggerBoardError(f"trigger board on {self.port}: line(s) {', '.join(dead)} did not fire",
                                    hint="check the trigger cable of the camera on that line")
            err.dead_lines = [int(i) for i in dead]
            raise err
        return FireReport(seq, board_us, fired, host_ns)

    # --- the line protocol ------------------------------------------------------------------
    def _command(self, line: str, expect: str, seq: int | None = None) -> list[str]:
        """Send one line, return the words after ``OK <expect>`` of its reply (within the deadline)."""
        import serial

        if self._serial is None:
            raise TriggerBoardError(f"trigger board on {self.port} is not open")
        deadline = time.monotonic() + self.timeout_s
        try:
            self._serial.write((line + "\n").encode("ascii"))
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._serial.timeout = remaining
                raw = self._serial.readline()
                if not raw.endswith(b"\n"):
                    break  # timed out mid-line or with nothing
                words = raw.decode("ascii", "replace").split()
                if not words:
                    continue
                if words[0] == "ERR":
                    raise TriggerBoardError(f"trigger board on {self.port} refused {line!r}: {' '.join(words[1:])}")
                if words[0] == "OK" and len(words) >= 2 and words[1] == expect:
                    if seq is not None and (len(words) < 3 or words[2] != str(seq)):
                        log.warning("trigger board: skipping a stale reply %r", raw)
                        continue
                    return words[2:]
                log.warning("trigger board: unexpected reply %r to %r", raw, line)
        except serial.SerialException as e:
            raise TriggerBoardError(f"trigger board on {self.port}: {e}",
                                    hint="check the board's USB cable and power") from None
        err = TriggerBoardError(f"trigger board on {self.port}: no answer to {line.split()[0]} "
                                f"within {self.timeout_s:.3g} s", hint="check the board's power and cable")
        err.timeout = True
        raise err


