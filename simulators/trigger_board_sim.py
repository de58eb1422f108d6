"""The trigger board, simulated on a pseudo-terminal, and the wires it drives.

``TriggerBoardSim`` answers the line protocol of drivers/trigger_board.py (docs/cameras.md)
on the master side of a pty; the driver opens ``sim.port`` (the slave's path) with pyserial
exactly as it opens /dev/ttyUSB0 on the station. FIRE pulses :class:`TriggerLines`, the
simulated trigger wires that hardware-triggered SimCameras listen on
(``context["trigger_lines"]``).

Faults are data, set on the instance: ``fault_mask`` (outputs that do not fire, e.g. a cut
wire: FIRE reports them), ``mute`` (the board stops answering), ``reply_delay_s``.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

MODEL = "TB8-SIM"
FIRMWARE = "1.0"


class TriggerLines:
    """The trigger wires: a pulse count and the time of the last pulse per line."""

    def __init__(self, n_lines: int = 8):
        self.n_lines = n_lines
        self._cond = threading.Condition()
        self._counts = [0] * n_lines
        self._last_ns = [0] * n_lines

    def pulse(self, mask: int, t_ns: int | None = None) -> None:
        t_ns = time.monotonic_ns() if t_ns is None else t_ns
        with self._cond:
            for line in range(self.n_lines):
                if mask >> line & 1:
                    self._counts[line] += 1
                    self._last_ns[line] = t_ns
            self._cond.notify_all()

    def count(self, line: int) -> int:
        with self._cond:
            return self._counts[line]

    def wait(self, line: int, seen: int, timeout_s: float) -> tuple[int, int] | None:
        """Wait until ``line`` has more than ``seen`` pulses: (count, time of the pulse), or None."""
        if not 0 <= line < self.n_lines:
            raise ValueError(f"trigger line {line} does not exist (0..{self.n_lines - 1})")
        with self._cond:
            if not self._cond.wait_for(lambda: self._counts[line] > seen, max(0.0, timeout_s)):
                return None
            return self._counts[line], self._last_ns[line]


class TriggerBoardSim:
    """The board on a pty. ``with TriggerBoardSim(lines) as sim: TriggerBoard(sim.port)``."""

    def __init__(self, lines: TriggerLines | None = None, n_lines: int = 8):
        self.lines = lines or TriggerLines(n_lines)
        self.n_lines = self.lines.n_lines
        self.fault_mask = 0
        self.mute = False
        self.reply_delay_s = 0.0
        self.strobe_us = 1000
        self.pulse_us = 100
        self.fired = 0
        self.received: list[str] = []
        self._t0 = time.monotonic_ns()
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line editing: a serial line, not a terminal
        self.port = os.ttyname(self._slave)
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._serve, daemon=True, name="trigger-board-sim")
        self._thread.start()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self._thread.is_alive():
            os.write(self._stop_w, b"x")
            self._thread.join(2)
        for fd in (self._master, self._slave, self._stop_r, self._stop_w):
            try:
                os.close(fd)
            except OSError:
                pass

    # --- the board's firmware ---------------------------------------------------------------
    def _serve(self) -> None:
        buf = b""
        while True:
            ready, _, _ = select.select([self._master, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            try:
                data = os.read(self._master, 4096)
            except OSError:
                return
            buf += data
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                line = raw.decode("ascii", "replace").strip()
                if not line:
                    continue
                self.received.append(line)
                reply = self.handle(line)
                if self.mute or reply is None:
                    continue
                if self.reply_delay_s:
                    time.sleep(self.reply_delay_s)
                os.write(self._master, (reply + "\n").encode("ascii"))

    def handle(self, line: str) -> str | None:
        """One command line -> one reply line (the protocol table in docs/cameras.md)."""
        parts = line.split()
        cmd, args = parts[0].upper(), parts[1:]
        try:
            if cmd == "ID?" and not args:
                return f"OK ID {MODEL} {FIRMWARE} LINES={self.n_lines}"
            if cmd == "PING" and len(args) == 1:
                return f"OK PONG {args[0]}"
            if cmd in ("STROBE", "PULSE") and len(args) == 1:
                us = int(args[0])
                if not 1 <= us <= 100_000:
                    return f"ERR 2 {cmd} {us}: out of range 1..100000 us"
                setattr(self, "strobe_us" if cmd == "STROBE" else "pulse_us", us)
                return f"OK {cmd} {us}"
            if cmd == "STATUS?" and not args:
                return (f"OK STATUS FIRED={self.fired} STROBE={self.strobe_us} PULSE={self.pulse_us} "
                        f"FAULT={self.fault_mask:02X}")
            if cmd == "FIRE" and len(args) == 2:
                seq, mask = int(args[0]), int(args[1], 16)
                if mask <= 0 or mask >> self.n_lines:
                    return f"ERR 2 FIRE mask {args[1]}: lines 0..{self.n_lines - 1} only"
                fired = mask & ~self.fault_mask
                t_ns = time.monotonic_ns()
                self.lines.pulse(fired, t_ns)  # cameras and strobes on the same edge
                self.fired += 1
                return f"OK FIRED {seq} {(t_ns - self._t0) // 1000} {fired:02X}"
        except ValueError:
            return f"ERR 2 bad argument in {line!r}"
        return f"ERR 1 unknown command {line!r}"
