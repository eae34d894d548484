"""A simulated server's asyncio loop in a daemon thread (tests, benchmarks, the demo)."""

from __future__ import annotations

import asyncio
import threading


class LoopThread:
    """Mixin: ``start_in_thread()`` runs ``await self.start()`` (which returns the port and
    sets ``self._loop``) on a new event loop in a daemon thread named ``thread_name``, and
    ``stop_thread()`` stops it (``await self.stop()`` runs on the way out)."""

    thread_name = "sim-server"
    what = "simulated server"
    _loop: asyncio.AbstractEventLoop | None = None
    _thread: threading.Thread | None = None

    def start_in_thread(self) -> int:
        """Run the server on its own event loop in a daemon thread; returns the port."""
        ready = threading.Event()
        box: dict = {}

        def run():
            loop = asyncio.new_event_loop()
            asyncio.set_event_loop(loop)
            try:
                box["port"] = loop.run_until_complete(self.start())
            except BaseException as exc:  # noqa: BLE001 - handed to the caller
                box["error"] = exc
                ready.set()
                return
            ready.set()
            loop.run_forever()
            loop.run_until_complete(self.stop())
            loop.close()

        self._thread = threading.Thread(target=run, name=self.thread_name, daemon=True)
        self._thread.start()
        if not ready.wait(10.0):
            raise RuntimeError(f"{self.what} did not start within 10 s")
        if "error" in box:
            raise box["error"]
        return box["port"]

    def stop_thread(self) -> None:
        if self._thread is not None and self._loop is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5.0)
            self._thread = None
