"""Figure renders in a worker process, so a plot does not hold the service's interpreter.

A matplotlib render (165-240 ms for Fig. 10 of a long history) is Python and Agg code that
holds the interpreter lock. On the service's threads it made every status poll wait: in a
soak profile (py-spy --gil) renders held the lock ~40 % of the time, and status p99 was
~50 ms against a goal of 25 ms. :func:`api.service.figures.axis.render` queries the database on
the request's thread and hands only the drawing (plain arrays, dates and tasks) to
:meth:`PlotProcess.draw`, which runs it in a spawned process of its own.

- One process, kept warm (matplotlib imports once): renders queue behind each other, as
  they did behind the interpreter lock before, but the API's threads stay free.
- A render that does not finish within ``timeout_s`` raises :class:`RenderTimeout`; a
  process that dies (killed, out of memory) is replaced, the render is tried once more in
  the new one, and a second death raises :class:`RenderCrashed`. Both are 503s.
- ``use_process=False`` draws on the caller's thread (the library use, and tests of the
  figures themselves).
- :meth:`PlotProcess.warm_up` (the service calls it at start) spawns the process and draws
  a blank figure in the background, so the first plot a client asks for does not pay for
  the spawn, matplotlib's import and its fonts (2.5 s for the first trend plot of a year's
  history without it, against 0.34 s for the next ones).
- Renders are stateless, so the services of one interpreter share one process
  (:meth:`PlotProcess.shared`): a service that restarts in-process (and each test's
  service) finds it warm. It ends with the interpreter, or with its parent if killed.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool

from api.service.worker_process import IDLE_END_S, end_pool, spawn_pool
from core.errors import MebmError

log = logging.getLogger(__name__)


class RenderUnavailable(MebmError):
    """A figure could not be drawn now; asking again may succeed."""


class RenderTimeout(RenderUnavailable):
    """The render did not finish within the time-out."""


class RenderCrashed(RenderUnavailable):
    """The render process died twice in a row on this figure."""


class PlotProcess:
    """The service's figure renderer: ``draw(fn, *args, **kwargs)`` returns ``fn``'s PNG bytes."""

    def __init__(self, *, timeout_s: float = 60.0, use_process: bool = True):
        self.timeout_s = timeout_s
        self.use_process = use_process
        self.renders = 0
        self.crashes = 0
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None
        self.warmed = threading.Event()
        self.warm_pid: int | None = None

    _shared: PlotProcess | None = None
    _shared_lock = threading.Lock()

    @classmethod
    def shared(cls) -> PlotProcess:
        """The interpreter's one renderer."""
        with cls._shared_lock:
            if cls._shared is None:
                cls._shared = cls()
            return cls._shared

    def warm_up(self) -> None:
        """Spawn the process and draw a blank figure in it, on a thread of its own (start-up
        does not wait). ``warmed`` is set when done, ``warm_pid`` is the process' pid; a
        failure is logged and the first plot pays for the spawn, as without a warm-up."""
        if not self.use_process or self.warmed.is_set():
            return

        def run() -> None:
            try:
                self.warm_pid = self._process().submit(_warm).result(timeout=self.timeout_s)
            except Exception as exc:  # noqa: BLE001 - a warm-up that fails costs the first plot its time only
                log.warning("the plot process could not be warmed up: %s", exc)
            finally:
                self.warmed.set()

        threading.Thread(target=run, name="mebm-plot-warm-up", daemon=True).start()

    def draw(self, fn: Callable[..., bytes], *args, **kwargs) -> bytes:
        if not self.use_process:
            return fn(*args, **kwargs)
        for attempt in (1, 2):
            pool = self._process()
            try:
                png = pool.submit(fn, *args, **kwargs).result(timeout=self.timeout_s)
            except BrokenProcessPool:
                self.crashes += 1
                self._drop(pool)
                log.error("the plot process died while drawing %s (attempt %d)", fn.__name__, attempt)
                if attempt == 2:
                    raise RenderCrashed(f"the plot process died twice while drawing {fn.__name__}; "
                                        f"ask again to retry") from None
                continue
            except FutureTimeout:
                # the process may be stuck on this render: replace it, so the next one starts clean
                self._drop(pool, kill=True)
                raise RenderTimeout(f"drawing {fn.__name__} took longer than {self.timeout_s:g} s") from None
            self.renders += 1
            return png
        raise AssertionError("unreachable")  # pragma: no cover

    def _process(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = spawn_pool(what="plot")
            return self._pool

    def _drop(self, pool: ProcessPoolExecutor, *, kill: bool = False) -> None:
        with self._lock:
            if self._pool is pool:
                self._pool = None
        # end_pool, not shutdown(wait=False) alone: that leaves the ending to an exit hook that
        # races with the manager thread (see end_pool); a stuck render gets no grace
        end_pool(pool, grace_s=0.0 if kill else IDLE_END_S, what="plot")

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:  # a render is asked again, not waited for
            end_pool(pool, grace_s=IDLE_END_S, what="plot")


def _warm() -> int:
    """In the plot process: import matplotlib and draw with its fonts once."""
    from api.service.figures.plots import empty

    empty("warm-up", "the plot process is ready")
    return os.getpid()
