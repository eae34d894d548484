"""Running one measurement cycle on an axis: the runner the scheduler calls.

A runner takes the stored axis and the controller URL and returns a
:class:`CycleOutcome`; it never raises for a failed measurement (the failure is an
outcome with its reason). The production runner is the acquisition layer's cycle
(``acquisition.measurement.run_cycle``: a round trip with over-travel, trace validation,
criteria); tests inject their own.

The production runner runs each cycle in a warm worker process (:class:`CycleProcesses`)
when one is free. Draining a controller's trace (pymodbus decodes every response in
Python), assembling and analysing it hold the interpreter lock: profiled in the 30-minute
soak (py-spy ``--gil``, three axes cycling every 2 s), the cycle threads held it 51 % of
the time, the storing part 12 % of it, and every cached ``/status`` answer waited behind
them (p99 33.9 ms against a goal of 25 ms). In a process of its own a cycle only shares the
CPU. The storing stays in the service (it owns the database session, the dataset locks
and the spool).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from acquisition import measurement
from acquisition.driver.base import ControllerDriver
from acquisition.trigger import needs_callers_process
from acquisition.url import driver_from_url
from api.service.config.input import resolve_profile
from api.service.worker_process import end_pool, spawn_pool
from core.criteria import RoundTripResult, analyze_round_trip
from core.criteria.uncertainty import UncertaintyInputs
from core.errors import MebmError
from storage.db import AxisRecord


@dataclass(frozen=True)
class CycleOutcome:
    """What one cycle produced. ``ok``: the raw trace and its analysis are present.

    Arrays are the raw round trip (time_s, motor_rev, table_mm), kept on disk as the
    dataset run; ``uncertainty_um`` is the backlash uncertainty the acquisition states
    (sampling skew times speed for unlatched modes, 0 when latched)."""

    ok: bool
    reason: str | None = None
    time_s: np.ndarray | None = None
    motor_rev: np.ndarray | None = None
    table_mm: np.ndarray | None = None
    command_mm: np.ndarray | None = None
    temperature_c: float | None = None
    uncertainty_um: float | None = None
    round_trip: RoundTripResult | None = None
    feed_mm_min: float | None = None
    acceleration_mm_s2: float | None = None
    trigger: str | None = None  # "active" (mebm started the round trip) or "passive" (the CNC did)
    repeated_after: str | None = None  # why a first round trip was refused and run again (a hole)

    @staticmethod
    def failed(reason: str, temperature_c: float | None = None) -> "CycleOutcome":
        return CycleOutcome(ok=False, reason=reason, temperature_c=temperature_c)


class CycleRunner(Protocol):
    def __call__(self, axis: AxisRecord, controller_url: str) -> CycleOutcome: ...


def useful_travel_mm(axis: AxisRecord) -> tuple[float, float]:
    """For a trace programmed over the travel only (no over-travel): the travel minus
    the reversal zones (max(5 mm, 1 %) at each end) where the table still settles."""
    a, b = axis.spec.travel_mm
    inset = max(5.0, 0.01 * (b - a))
    if b - a <= 4 * inset:
        inset = (b - a) / 8
    return a + inset, b - inset


def analyse(axis: AxisRecord, time_s, motor_rev, table_mm, *,
            uncertainty: UncertaintyInputs | None = None) -> RoundTripResult:
    """Backlash profile and lead criteria of a raw round trip (core, Section 3).

    A trace programmed with over-travel (``acquisition.measurement.default_program``) is
    analysed over the whole travel, like the live cycle, so a spooled run re-analysed
    after a database outage gives the same result; a shorter one over the inset
    :func:`useful_travel_mm`. Without ``uncertainty``, the budget has the axis' instruments
    (``AxisSettings.instruments``) and no sampling bound."""
    x = np.asarray(table_mm, dtype=float)
    lo, hi = axis.spec.travel_mm
    travel = (lo, hi) if x.size and x.min() < lo - 0.5 and x.max() > hi + 0.5 else useful_travel_mm(axis)
    return analyze_round_trip(time_s, motor_rev, table_mm, axis.spec, useful_travel_mm=travel,
                              uncertainty=uncertainty or axis.settings.instruments.inputs())


log = logging.getLogger(__name__)

# how long a cycle still running in a worker process may take to finish when the service stops
CLOSE_GRACE_S = 10.0

# what a cycle process imports when it starts, so its first cycle is as fast as the others
CYCLE_IMPORTS = ("api.service.cycles.runner", "acquisition.modbus.driver", "acquisition.modbus.polled",
                 "acquisition.canopen.driver", "acquisition.canopen.listen", "core.criteria")


class NoFreeProcess(Exception):
    """Every cycle process is busy or still starting: the caller runs the cycle itself."""


class CycleProcessDied(MebmError):
    """The process running a cycle died (killed, out of memory) before it returned."""


class CycleNotRun(MebmError):
    """The service stopped after the cycle was handed to a process but before it started."""


class CycleProcesses:
    """Up to ``processes`` spawned, warm worker processes for the cycles of one service.

    :meth:`run` hands a cycle to a process that has started and is free, or raises
    :class:`NoFreeProcess` at once, so a cycle never waits for a process (a passive one
    must be listening when the CNC starts its round trip): it runs on the caller's thread
    instead, as every cycle did before. A process that dies fails its cycle with
    :class:`CycleProcessDied` (the axis may have been moving: it is not retried here; the
    schedule measures again) and a fresh set of processes starts in the background. A death
    breaks the whole pool (``concurrent.futures``): a cycle running in another of its
    processes at that moment fails the same way.
    """

    def __init__(self, processes: int):
        if processes < 0:
            raise ValueError(f"processes (={processes}) must be >= 0")
        self.processes = processes
        self.in_process = 0  # cycles run in a worker process
        self.inline = 0  # cycles run on the caller's thread (none free, or still starting)
        self.crashes = 0
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None
        self._free = 0  # started processes of the current pool not running a cycle
        self._closed = True

    def start(self) -> None:
        """Spawn the processes (in the background: they count as free once started)."""
        self._closed = False
        self._spawn()

    def _spawn(self) -> None:
        with self._lock:
            if self._pool is not None or self.processes == 0 or self._closed:
                return
            pool = self._pool = spawn_pool(what="cycle", workers=self.processes, imports=CYCLE_IMPORTS,
                                           log_level=logging.getLogger().getEffectiveLevel())
            self._free = 0
        for _ in range(self.processes):  # one task per process: the pool spawns one process per waiting task
            pool.submit(_started).add_done_callback(lambda f, p=pool: self._started(p, f))

    def _started(self, pool: ProcessPoolExecutor, fut: Future) -> None:
        with self._lock:
            if pool is self._pool and not fut.cancelled() and fut.exception() is None:
                self._free += 1

    def run(self, fn: Callable, *args):
        """``fn(*args)`` in a free worker process; :class:`NoFreeProcess` when there is none."""
        with self._lock:
            pool = self._pool
            if pool is not None and self._free > 0:
                self._free -= 1
            else:
                pool = None
        if pool is None:
            self._count("inline")
            raise NoFreeProcess
        try:
            try:
                fut = pool.submit(fn, *args)
            except BrokenProcessPool:  # died while idle: nothing was running in it
                self._count("crashes")
                self._drop(pool)
                self._spawn()
                self._count("inline")
                raise NoFreeProcess from None
            except RuntimeError:  # shut down: the service stops
                self._count("inline")
                raise NoFreeProcess from None
            try:
                out = fut.result()
            except CancelledError:  # close() cancelled it before a process took it
                raise CycleNotRun("the service stopped before the cycle started: nothing was measured") from None
            except BrokenProcessPool:
                self._count("crashes")
                self._drop(pool)
                self._spawn()
                raise CycleProcessDied("the process running the cycle died (killed or out of memory) before "
                                       "it returned; the next cycle runs in a fresh one") from None
            self._count("in_process")
            return out
        finally:
            with self._lock:
                if pool is self._pool:
                    self._free += 1

    def _count(self, what: str) -> None:
        with self._lock:
            setattr(self, what, getattr(self, what) + 1)

    def _drop(self, pool: ProcessPoolExecutor) -> None:
        with self._lock:
            if self._pool is pool:
                self._pool, self._free = None, 0
        pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        """Stop the processes (nothing new starts; a cycle running in one gets
        ``CLOSE_GRACE_S`` to finish, then its process is terminated)."""
        self._closed = True
        with self._lock:
            pool, self._pool, self._free = self._pool, None, 0
        if pool is not None:
            end_pool(pool, grace_s=CLOSE_GRACE_S, what="cycle")


def _started() -> bool:
    return True


def _cycle_in_process(axis: AxisRecord, controller_url: str, timeout_s: float) -> CycleOutcome:
    return DriverRunner(timeout_s=timeout_s).run_here(axis, controller_url)


class DriverRunner:
    """The production runner: the acquisition cycle through the driver for the URL
    (``modbus://…``, ``canopen://…``; ``acquisition.url``).

    With ``processes``, a cycle runs in one of them when one is free (see
    :class:`CycleProcesses`); not with an injected ``driver_factory`` (it stays in this
    process), nor for a controller that exists only in this process (CANopen on python-can's
    in-process ``virtual`` bus)."""

    def __init__(self, driver_factory: Callable[[str], ControllerDriver] | None = None, *, timeout_s: float = 2.0,
                 processes: CycleProcesses | None = None, profiles_dir: Path | None = None):
        self.timeout_s = timeout_s
        self.processes = processes if driver_factory is None else None
        self.driver_factory = driver_factory or (lambda url: driver_from_url(url, timeout_s=timeout_s))
        self.profiles_dir = profiles_dir  # where a controller URL's profile=NAME is read from

    def __call__(self, axis: AxisRecord, controller_url: str) -> CycleOutcome:
        if self.profiles_dir is not None:
            controller_url = resolve_profile(controller_url, self.profiles_dir)
        if self.processes is not None and not needs_callers_process(controller_url):
            try:
                return self.processes.run(_cycle_in_process, axis, controller_url, self.timeout_s)
            except NoFreeProcess:
                pass
            except (CycleProcessDied, CycleNotRun) as exc:
                log.error("axis %s: %s", axis.id, exc)
                return CycleOutcome.failed(f"{type(exc).__name__}: {exc}")
        return self.run_here(axis, controller_url)

    def run_here(self, axis: AxisRecord, controller_url: str) -> CycleOutcome:
        """The cycle on the caller's thread."""
        st = axis.settings
        try:
            driver = self.driver_factory(controller_url)
            program = measurement.default_program(st.spec, st.measure_feed_mm_min,
                                                acceleration_mm_s2=st.measure_acceleration_mm_s2)
        except MebmError as exc:
            return CycleOutcome.failed(f"{type(exc).__name__}: {exc}")
        res = measurement.run_cycle(driver, st.spec, program, instruments=st.instruments)
        trace = res.trace
        temp = trace.temperature_c if trace is not None and math.isfinite(trace.temperature_c) else None
        raw = {}
        if trace is not None:
            raw = dict(time_s=trace.time_s, motor_rev=trace.motor_rev, table_mm=trace.table_mm)
        # res.program: the round trip as run (passive mode: as observed, not as configured)
        common = dict(temperature_c=temp, feed_mm_min=res.program.feed_mm_min,
                      acceleration_mm_s2=res.program.acceleration_mm_s2,
                      trigger=trace.trigger if trace is not None else getattr(driver, "trigger", None),
                      repeated_after=res.repeated_after, **raw)
        if not res.ok:
            return CycleOutcome(ok=False, reason=f"{res.reason_code}: {res.reason}", **common)
        return CycleOutcome(ok=True, uncertainty_um=res.uncertainty_um, round_trip=res.result, **common)
