"""A bound on the figure renders a service runs and queues at once.

A render costs a worker thread (the database reads behind the figure), a database
connection and the plot process' time (one process: renders run one after another). An
unbounded number of them held every worker thread and connection: clients asking for
many distinct figures at once made ``/healthz`` and every other answer wait for seconds.

:class:`RenderGate` admits at most ``workers + queue`` renders at once (``[limits]
plot_renders`` and ``plot_queue``); of those, ``workers`` run, each on a worker thread of
the gate's own, and the rest wait *without* a thread or a connection (on the event loop).
One more is refused at once with :class:`RenderBusy`, which says when to ask again (the
REST API answers 429 with ``Retry-After``): an estimate from the queue's length and the
recent render time.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections.abc import Callable
from typing import TypeVar

import anyio
import anyio.to_thread

from core.errors import MebmError

T = TypeVar("T")


class RenderBusy(MebmError):
    """Every render slot and queue place is taken; ``retry_after_s`` says when to ask again."""

    def __init__(self, message: str, retry_after_s: float):
        super().__init__(message)
        self.retry_after_s = retry_after_s


class RenderGate:
    """At most ``workers`` renders running and ``queue`` waiting; the rest refused."""

    def __init__(self, workers: int = 2, queue: int = 16, *, clock=time.monotonic):
        if workers < 1:
            raise ValueError(f"workers (={workers}) must be >= 1")
        if queue < 0:
            raise ValueError(f"queue (={queue}) must be >= 0")
        self.workers = workers
        self.queue = queue
        self.clock = clock
        self._lock = threading.Lock()
        self._admitted = 0
        self._limiter: anyio.CapacityLimiter | None = None  # made on the event loop, at first use
        self._loop = None
        self.mean_render_s = 0.5  # a moving mean of the recent renders, for Retry-After
        self.refused = 0
        self.rendered = 0

    @property
    def admitted(self) -> int:
        """Renders running or waiting now."""
        return self._admitted

    def _enter(self) -> None:
        with self._lock:
            if self._admitted >= self.workers + self.queue:
                self.refused += 1
                waiting = self._admitted - self.workers + 1
                wait_s = min(max(math.ceil(waiting * self.mean_render_s / self.workers), 1), 60)
                raise RenderBusy(f"{self.workers} figure(s) are being drawn and {self.queue} wait (limits.plot_renders, "
                                 f"limits.plot_queue); ask again in {wait_s} s", wait_s)
            self._admitted += 1

    def _leave(self, elapsed_s: float | None) -> None:
        with self._lock:
            self._admitted -= 1
            if elapsed_s is not None:
                self.rendered += 1
                self.mean_render_s = 0.8 * self.mean_render_s + 0.2 * elapsed_s

    async def run(self, fn: Callable[..., T], *args) -> T:
        """``fn(*args)`` on one of the gate's worker threads once a slot is free; raises
        :class:`RenderBusy` at once when ``workers + queue`` renders are admitted already."""
        self._enter()
        took: list[float] = []

        def timed() -> T:
            t0 = self.clock()
            try:
                return fn(*args)
            finally:
                took.append(self.clock() - t0)

        try:
            loop = asyncio.get_running_loop()
            if self._limiter is None or self._loop is not loop:  # (a test client runs a loop of its own)
                self._limiter, self._loop = anyio.CapacityLimiter(self.workers), loop
            # the queue: a render waits for the limiter on the event loop, holding no thread
            return await anyio.to_thread.run_sync(timed, limiter=self._limiter)
        finally:
            self._leave(took[0] if took else None)
