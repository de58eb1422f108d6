"""Run the PLC server on its own event loop in a background thread, for programs that are not
asyncio themselves (a GUI, the tests, the benchmark)."""

from __future__ import annotations

import asyncio
import threading

from station.plc.device import PlcDevice
from station.plc.server import PlcServer


class BackgroundServer:
    """``with BackgroundServer(device) as bg: port = bg.start_tcp()`` ... stops on exit."""

    def __init__(self, device: PlcDevice, **server_kwargs):
        self.device = device
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name="plc-server", daemon=True)
        self._thread.start()
        self.server: PlcServer = self.call(lambda: PlcServer(device, **server_kwargs))

    def run(self, coro, timeout: float = 30.0):
        """Run a coroutine on the server's loop and return its result."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call(self, fn, timeout: float = 30.0):
        """Run ``fn()`` on the server's loop (safe access to the device) and return its result."""
        async def wrap():
            return fn()
        return self.run(wrap(), timeout)

    def start_tcp(self, host: str = "127.0.0.1", port: int = 0) -> int:
        return self.run(self.server.start_tcp(host, port))

    def start_rtu(self, port: str, **kwargs) -> None:
        self.run(self.server.start_rtu(port, **kwargs))

    def stop(self) -> None:
        if self.loop.is_closed():
            return
        try:
            self.run(self.server.stop(), timeout=10)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(10)
            self.loop.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
