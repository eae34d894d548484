"""The driver base class: it owns the measurement loop; subclasses own only the wire.

Like python-can's ``BusABC.recv()`` over ``_recv_internal()``: :meth:`ControllerDriver.acquire`
checks the axis is idle, starts the round trip, drains samples until the controller
reports the end, with a timeout on every exchange and a bounded number of retries;
it checks counter continuity and encoder plausibility as samples arrive and sends
an abort on any failure, so the axis is left stopped. Subclasses implement the
``_connect``/``_close``/``_read_status``/``_start``/``_abort``/``_acknowledge``/``_drain``
coroutines and translate their library's exceptions into :mod:`acquisition.errors`.
"""

from __future__ import annotations

import asyncio
import math
import time
from abc import ABC, abstractmethod

import numpy as np

from acquisition.errors import (
    AcquisitionError,
    AxisBusyError,
    ControllerConnectionError,
    ControllerTimeoutError,
    DeviceFaultError,
    LostSamplesError,
    ProtocolError,
)
from acquisition.encoder_monitor import EncoderMonitor
from acquisition.types import AcquiredTrace, AxisState, ControllerStatus, RoundTripProgram, SampleBlock
from core.dataset import AxisSpec
from core.errors import InputError, require_positive


class ControllerDriver(ABC):
    """Acquires one round trip from a controller. Subclasses implement the wire.

    ``timeout_s`` bounds every exchange and the connection set-up; transient failures
    (timeouts, dropped connections, busy replies) are retried ``retries`` times with a
    reconnect in between; ``max_lost_samples`` is how many missing counter values a
    trace may have (0: any gap fails the cycle).
    """

    protocol = "?"
    #: Acquisition mode: "trace" (ring buffer), "sync" (CANopen), "latched" (poll), "separate" (unlatched).
    mode = "?"
    #: Counter values are consecutive servo/SYNC cycles (gaps mean lost samples).
    continuous = True
    #: Motor and table of a sample were latched in the same cycle.
    latched = True
    #: Request/reply exchanges of ``_connect`` (each bounded by ``timeout_s`` on the wire); the
    #: connection set-up as a whole gets this many timeouts, the first unanswered one ends it.
    connect_exchanges = 2
    #: The wire bounds every request by ``timeout_s`` itself (pymodbus does), so the base
    #: need not wrap each call in an asyncio timeout (a measurable cost per block).
    wire_timeouts = False

    def __init__(
        self,
        *,
        timeout_s: float = 1.0,
        retries: int = 2,
        poll_interval_s: float = 0.005,
        max_lost_samples: int = 0,
        jump_margin_mm: float = 0.05,
        stuck_travel_mm: float = 1.0,
        stall_timeout_s: float | None = None,
    ):
        self.timeout_s = require_positive("timeout_s", timeout_s)
        if retries < 0:
            raise InputError(f"retries (={retries}) must be >= 0")
        self.retries = int(retries)
        self.poll_interval_s = require_positive("poll_interval_s", poll_interval_s)
        self.max_lost_samples = int(max_lost_samples)
        self.jump_margin_mm = jump_margin_mm
        self.stuck_travel_mm = stuck_travel_mm
        self.stall_timeout_s = stall_timeout_s if stall_timeout_s is not None else max(2.0, 3 * self.timeout_s)
        self._connected = False
        self._ever_connected = False
        self.connect_attempts = 0  # connection set-ups tried by this driver (tests count them)
        self.link_trouble: str | None = None  # last transient fault recovered from in this cycle
        self.servo_rate_hz = float("nan")

    # -- the wire (subclasses) ----------------------------------------------------------------
    @abstractmethod
    def describe(self) -> str:
        """Where the controller is, for messages (``modbus://127.0.0.1:5020``)."""

    @abstractmethod
    async def _connect(self) -> None:
        """Open the link and read the configuration (sets ``servo_rate_hz``)."""

    @abstractmethod
    async def _close(self) -> None:
        """Close the link; never raises."""

    @abstractmethod
    async def _read_status(self) -> ControllerStatus: ...

    @abstractmethod
    async def _start(self, program: RoundTripProgram) -> int | None:
        """Send the program and the start command; return the first sample counter if known."""

    @abstractmethod
    async def _abort(self) -> None: ...

    @abstractmethod
    async def _acknowledge(self) -> None: ...

    @abstractmethod
    async def _drain(self) -> SampleBlock:
        """Samples latched since the last drain (possibly none) and whether the program has ended."""

    # -- plumbing ----------------------------------------------------------------------------------
    async def connect(self) -> None:
        """Open the link; refused connections are retried within ``timeout_s``, an unanswered
        request ends it after one ``timeout_s``."""
        t_start = time.monotonic()
        deadline = t_start + self.timeout_s
        budget_end = t_start + self.timeout_s * self.connect_exchanges
        attempt = 0
        while True:
            attempt += 1
            self.connect_attempts += 1
            remaining = budget_end - time.monotonic()
            try:
                await asyncio.wait_for(self._connect(), max(remaining, 0.01))
                self._connected = True
                self._ever_connected = True
                return
            except AcquisitionError as exc:
                await self._close()
                backoff = min(0.05 * 2**attempt, 0.5)
                refused = isinstance(exc, ControllerConnectionError)  # an unanswered request is not retried
                if not refused or attempt > self.retries or time.monotonic() + backoff > deadline:
                    raise
                await asyncio.sleep(backoff)
            except asyncio.TimeoutError:
                await self._close()
                raise ControllerTimeoutError(
                    f"no answer from {self.describe()} within {time.monotonic() - t_start:.1f} s: check the address "
                    "(host, port, node id) and that the controller is on and connected"
                ) from None

    async def close(self) -> None:
        self._connected = False
        await self._close()

    async def _call(self, what: str, fn, *args, retries: int | None = None):
        """``fn(*args)`` with the timeout and bounded retries (reconnecting after link failures)."""
        last: AcquisitionError | None = None
        retries = self.retries if retries is None else retries
        for attempt in range(retries + 1):
            try:
                if not self._connected:
                    await self.connect()
                if self.wire_timeouts:
                    return await fn(*args)  # every request already bounded by the wire's own timeout
                async with asyncio.timeout(self.timeout_s):
                    return await fn(*args)
            except AcquisitionError as exc:  # before TimeoutError: ours subclass it
                if not exc.transient or not self._ever_connected:
                    raise  # the first connection has its own budget (connect()); never retried beyond it
                last = exc
                self.link_trouble = str(exc)
                if isinstance(exc, (ControllerConnectionError, ControllerTimeoutError)):
                    await self.close()
            except asyncio.TimeoutError:
                last = ControllerTimeoutError(f"no reply from {self.describe()} within {self.timeout_s:g} s")
                self.link_trouble = str(last)
                await self.close()
            if attempt < retries:
                await asyncio.sleep(min(0.05 * 2**attempt, 0.5))
        n = retries + 1
        msg = f"{what}: {last} (gave up after {n} attempt{'s' if n > 1 else ''})"
        if isinstance(last, TimeoutError):
            raise ControllerTimeoutError(msg) from last
        if isinstance(last, ConnectionError):
            raise ControllerConnectionError(msg) from last
        raise ProtocolError(msg, code=getattr(last, "code", None)) from last

    async def _safe_abort(self) -> str:
        """Best effort to leave the axis stopped; returns a note for the failure reason."""
        deadline = time.monotonic() + max(3.0 * self.timeout_s, 2.0)
        err: Exception | None = None
        for _ in range(20):
            if time.monotonic() > deadline:
                break
            try:
                if not self._connected:
                    await self.connect()
                await asyncio.wait_for(self._abort(), self.timeout_s)
                return "abort sent, axis stopped"
            except (AcquisitionError, asyncio.TimeoutError) as exc:
                err = exc
                await self.close()
                await asyncio.sleep(0.1)
        return f"abort could NOT be sent ({err or 'timeout'}): stop the axis at the controller"

    # -- the measurement loop -------------------------------------------------------------------
    async def acquire_async(self, program: RoundTripProgram, axis: AxisSpec) -> AcquiredTrace:
        """Run one round trip and return its trace; raise :class:`AcquisitionError` on any fault.

        On failure after the start, an abort is sent first; the exception's
        ``abort_note`` says whether it reached the controller.
        """
        started = False
        self._ever_connected = False
        self.link_trouble = None
        t_wall0 = time.monotonic()
        try:
            status = await self._call("reading the axis state", self._read_status)
            if status.state == AxisState.RUNNING:
                raise AxisBusyError(
                    f"axis {axis.name} on {self.describe()} is RUNNING another program: "
                    "wait for it to finish or abort it, then retry"
                )
            if status.state != AxisState.IDLE:
                # DONE/ABORTED from a previous cycle, or FAULT: acknowledge (fault reset) once
                await self._call("acknowledging the previous state", self._acknowledge)
                status = await self._call("reading the axis state", self._read_status)
                if status.state != AxisState.IDLE:
                    code = f" (fault code 0x{status.fault_code:04X})" if status.fault_code else ""
                    raise AxisBusyError(
                        f"axis {axis.name} on {self.describe()} is {status.state.name}{code} and did not "
                        "return to IDLE after an acknowledge: clear the fault at the controller"
                    )
            temp0 = status.temperature_c
            started = True  # from here on, any failure sends an abort
            # not retried: a start that timed out may have started the axis; the abort handles it
            first = await self._call("starting the round trip", self._start, program, retries=0)
            trace = await self._drain_loop(program, axis, first, t_wall0, temp0)
            started = False
            return trace
        except (AcquisitionError, asyncio.CancelledError, KeyboardInterrupt) as exc:
            if started:
                note = await self._safe_abort()
                if isinstance(exc, AcquisitionError):
                    exc.abort_note = note
            raise
        finally:
            await self.close()

    async def _drain_loop(self, program, axis, first, t_wall0, temp0) -> AcquiredTrace:
        rate = self.servo_rate_hz
        monitor = EncoderMonitor(program, axis.transmission_mm_per_rev, rate,
                                 jump_margin_mm=self.jump_margin_mm, stuck_travel_mm=self.stuck_travel_mm)
        counters, motors, tables, times = [], [], [], []
        expected = first  # next counter value (continuous modes)
        last_counter = None
        lost = 0
        skew_s = 0.0
        deadline = time.monotonic() + 1.5 * program.duration_s + 3 * self.timeout_s + 5.0
        max_iter = int((deadline - time.monotonic()) / min(self.poll_interval_s, 0.001)) + 1000
        last_progress = time.monotonic()
        finished = False
        pending, pending_n = [], 0  # samples not yet through the encoder monitor
        t_first_block = None
        for _ in range(max_iter):
            now = time.monotonic()
            if now > deadline:
                raise ControllerTimeoutError(
                    f"the round trip did not finish within {deadline - t_wall0:.1f} s "
                    f"(programmed {program.duration_s:.1f} s)"
                )
            block = await self._call("reading samples", self._drain)
            c = np.asarray(block.counter, dtype=np.int64)
            m, t = block.motor_rev, block.table_mm
            if c.size and not self.continuous and last_counter is not None:
                keep = c > last_counter  # the same latched sample read twice
                c, m, t = c[keep], m[keep], t[keep]
            if c.size:
                prev = expected if self.continuous and expected is not None else None
                if prev is None and self.continuous:
                    prev = int(c[0])
                contiguous = (self.continuous and int(c[0]) == prev and int(c[-1]) - prev == c.size - 1
                              and bool((c[1:] > c[:-1]).all()))  # the common case, checked cheaply
                if self.continuous and not contiguous:
                    steps = np.diff(np.concatenate([[prev - 1], c]))
                    if np.any(steps <= 0):
                        i = int(np.argmax(steps <= 0))
                        raise ProtocolError(
                            f"sample counter went backwards or repeated ({int(c[i])} after {prev - 1 if i == 0 else int(c[i - 1])})"
                        )
                    gaps = steps - 1
                    if gaps.any():
                        i = int(np.argmax(gaps > 0))
                        lost += int(gaps.sum())
                        if lost > self.max_lost_samples:
                            before = int(c[i]) - int(gaps[i])
                            tm = float(t[i])
                            raise LostSamplesError(
                                f"{int(gaps[i])} sample(s) lost: counter jumps from {before - 1} to {int(c[i])} "
                                f"(table near {tm:.3f} mm); {lost} lost in all. Samples are never "
                                "interpolated: check the network load and the trace-buffer/SYNC settings",
                                lost_samples=lost, first_missing=before,
                            )
                if self.continuous:
                    expected = int(c[-1]) + 1
                skew_s = max(skew_s, block.skew_s)
                pending.append((c, m, t))
                pending_n += c.size
                if pending_n >= 256:  # encoder checks in batches: cheap per block, still online
                    monitor.check(*_join(pending), skew_s=skew_s)
                    pending, pending_n = [], 0
                counters.append(c)
                motors.append(np.asarray(m, dtype=float))
                tables.append(np.asarray(t, dtype=float))
                if block.time_s is not None:
                    times.append(np.asarray(block.time_s, dtype=float)[-c.size:])
                last_counter = int(c[-1])
                if t_first_block is None:
                    t_first_block = now
                last_progress = time.monotonic()
            if block.finished:
                finished = True
                break
            if block.caught_up and pending:
                monitor.check(*_join(pending), skew_s=skew_s)
                pending, pending_n = [], 0
            if c.size == 0 and time.monotonic() - last_progress > self.stall_timeout_s:
                raise ControllerTimeoutError(
                    f"{self.describe()} delivered no new sample for {self.stall_timeout_s:g} s while "
                    "the round trip should be running"
                )
            if block.caught_up:
                await asyncio.sleep(self.poll_interval_s)
        if not finished:
            raise ControllerTimeoutError(f"the round trip did not finish ({max_iter} reads)")
        if pending:
            monitor.check(*_join(pending), skew_s=skew_s)
        monitor.finish(skew_s=skew_s)
        counter = np.concatenate(counters) if counters else np.zeros(0, dtype=np.int64)
        if counter.size < 2:
            raise ControllerTimeoutError(f"{self.describe()} reported the round trip done with {counter.size} sample(s)")
        if times:
            time_s = np.concatenate(times)
            time_s = time_s - time_s[0]
        else:
            time_s = (counter - counter[0]) / rate
        status = await self._call("reading the axis state", self._read_status)
        temps = [x for x in (temp0, status.temperature_c) if math.isfinite(x)]
        return AcquiredTrace(
            protocol=self.protocol,
            mode=self.mode,
            time_s=time_s,
            counter=counter,
            motor_rev=np.concatenate(motors),
            table_mm=np.concatenate(tables),
            temperature_c=float(np.mean(temps)) if temps else float("nan"),
            latched=self.latched,
            skew_uncertainty_um=skew_s * program.speed_mm_s * 1e3,
            lost_samples=lost,
            servo_rate_hz=rate,
            program=program,
            wall_time_s=time.monotonic() - t_wall0,
            drain_time_s=(last_progress - t_first_block) if t_first_block is not None else float("nan"),
        )

    def acquire(self, program: RoundTripProgram, axis: AxisSpec) -> AcquiredTrace:
        """Blocking form of :meth:`acquire_async` for threads (runs its own event loop)."""
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return asyncio.run(self.acquire_async(program, axis))
        raise InputError("acquire() called inside a running event loop: await acquire_async() instead")


def _join(blocks):
    return tuple(np.concatenate([b[i] for b in blocks]) for i in range(3))


def raise_device_fault(status: ControllerStatus, where: str, link_trouble: str | None = None) -> None:
    """Turn a FAULT/ABORTED status seen mid-cycle into the matching error.

    ``link_trouble``: the communication fault recovered from earlier in the cycle, if any;
    a controller that aborted on its own after it is reporting a lost link.
    """
    if status.state == AxisState.FAULT:
        raise DeviceFaultError(f"{where} reported a fault during the round trip", code=status.fault_code)
    if status.state == AxisState.ABORTED and link_trouble:
        raise ControllerConnectionError(
            f"{where} stopped the round trip on its own after a communication fault ({link_trouble})"
        )
    if status.state == AxisState.ABORTED:
        raise AcquisitionError(f"the round trip was aborted at {where} (not by mebm)")
    if status.state == AxisState.IDLE:
        raise AcquisitionError(f"{where} returned to IDLE during the round trip (reset or program change?)")
