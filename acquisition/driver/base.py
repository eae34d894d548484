"""The driver base class: it owns the measurement loop; subclasses own only the wire.

Like python-can's ``BusABC.recv()`` over ``_recv_internal()``: :meth:`ControllerDriver.acquire`
checks the axis is idle, starts the round trip and drains samples until the controller
reports the end. The pieces it composes, each in its own module:

- :class:`acquisition.driver.retry.RetryPolicy`: how every exchange (connection set-up, each
  request, the abort) is retried, boundedly;
- :class:`acquisition.driver.trace_assembler.TraceAssembler`: counter continuity, gaps, duplicates;
- :class:`acquisition.driver.encoder_monitor.EncoderMonitor`: stuck, jumping and glitching encoders;
- :class:`acquisition.driver.cycle_state.AcquisitionCycle`: everything one cycle knows, made
  fresh by each :meth:`acquire_async`, so a driver carries nothing from one cycle to the next.

On any failure after the start an abort is sent, so the axis is left stopped. Subclasses
implement the ``_connect``/``_close``/``_read_status``/``_start``/``_abort``/``_acknowledge``/
``_drain`` coroutines and translate their library's exceptions into :mod:`acquisition.errors`.

**Passive round trips** (``trigger="passive"``): the CNC runs the round-trip program and
mebm only records. The base connects, polls samples through the wire's
``_passive_drain`` (the one coroutine a wire adds for passive mode: samples since the
last call, with the controller's "program running" flag when it has one) and feeds them
to :class:`acquisition.driver.round_trip_detector.RoundTripDetector`; it never writes a start,
an abort or an acknowledge. The program of the returned trace is what was observed.
"""

from __future__ import annotations

import asyncio
import math
import time
from abc import ABC, abstractmethod
from dataclasses import replace

import numpy as np

from acquisition.driver.cycle_state import AcquisitionCycle
from acquisition.driver.encoder_monitor import EncoderMonitor
from acquisition.errors import (
    AcquisitionError,
    AxisBusyError,
    ControllerConnectionError,
    ControllerTimeoutError,
    DeviceBusyError,
    DeviceFaultError,
    DriverMisuseError,
    LostSamplesError,
    ProtocolError,
)
from acquisition.driver.retry import RetryPolicy
from acquisition.driver.round_trip_detector import DetectedRoundTrip, DetectorSettings, RoundTripDetector
from acquisition.driver.trace_assembler import TraceAssembler
from acquisition.types import AcquiredTrace, AxisState, ControllerStatus, RoundTripProgram, SampleBlock
from core.dataset import AxisSpec
from core.errors import InputError, require_positive

#: Samples the encoder checks wait for, so they run in batches: cheap per block, still online.
ENCODER_BATCH = 256


class ControllerDriver(ABC):
    """Acquires one round trip from a controller. Subclasses implement the wire.

    ``timeout_s`` bounds every exchange and the connection set-up; transient failures
    (timeouts, dropped connections, busy replies) are retried ``retries`` times with a
    reconnect in between (``retry`` replaces the whole policy: attempts, back-off, and the
    sleep and clock it uses); ``max_lost_samples`` is how many missing counter values a
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
    #: The wire implements ``_passive_drain`` (passive round trips).
    supports_passive = False
    #: The wire's passive samples carry the controller's "program running" flag.
    has_running_flag = False

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
        retry: RetryPolicy | None = None,
        trigger: str = "active",
        passive: dict | None = None,
        running_flag: bool | None = None,
    ):
        self.timeout_s = require_positive("timeout_s", timeout_s)
        if retries < 0:
            raise InputError(f"retries (={retries}) must be >= 0")
        self.retry = retry or RetryPolicy(attempts=int(retries) + 1)
        self.poll_interval_s = require_positive("poll_interval_s", poll_interval_s)
        if max_lost_samples < 0:
            raise InputError(f"max_lost_samples (={max_lost_samples}) must be >= 0")
        self.max_lost_samples = int(max_lost_samples)
        self.jump_margin_mm = jump_margin_mm
        self.stuck_travel_mm = stuck_travel_mm
        self.stall_timeout_s = stall_timeout_s if stall_timeout_s is not None else max(2.0, 3 * self.timeout_s)
        self._connected = False
        self.connect_attempts = 0  # connection set-ups tried by this driver (tests count them)
        self.servo_rate_hz = float("nan")
        if trigger not in TRIGGERS:
            raise InputError(f"trigger (={trigger!r}) must be one of {TRIGGERS}")
        if trigger == "passive" and not self.supports_passive:
            raise InputError(f"trigger = 'passive': {self.protocol} driver {type(self).__name__} cannot detect a "
                             "round trip it did not start (no passive sample path); use trigger = 'active'")
        if running_flag and not self.has_running_flag:
            raise InputError(f"running_flag: {type(self).__name__} reads no 'program running' flag from the "
                             "controller; detect the round trip from the positions (running_flag off)")
        self.trigger = trigger
        self.running_flag = self.has_running_flag if running_flag is None else bool(running_flag)
        self.passive = dict(passive or {})
        unknown = sorted(set(self.passive) - set(DetectorSettings.__dataclass_fields__))
        if unknown:
            raise InputError(f"passive: unknown option(s) {unknown} (allowed: "
                             f"{sorted(DetectorSettings.__dataclass_fields__)})")
        self._cycle: AcquisitionCycle | None = None  # the cycle under way
        self.last_cycle: AcquisitionCycle | None = None  # the cycle that ended last (for inspection)

    @property
    def retries(self) -> int:
        return self.retry.attempts - 1

    @property
    def cycle(self) -> AcquisitionCycle:
        """The cycle under way; the wire keeps its per-cycle state in ``cycle.wire``."""
        if self._cycle is None:
            raise DriverMisuseError("no acquisition cycle is under way on this driver")
        return self._cycle

    @property
    def link_trouble(self) -> str | None:
        """The last transient fault recovered from in the cycle under way (or the last one)."""
        c = self._cycle or self.last_cycle
        return c.link_trouble if c is not None else None

    def note_link_trouble(self, exc: Exception) -> None:
        if self._cycle is not None:
            self._cycle.link_trouble = str(exc)

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

    async def _passive_drain(self) -> SampleBlock:
        """Passive mode: samples since the last call (possibly none), without commanding
        anything; ``running`` set per sample when the wire reads a running flag, and
        ``run_start`` when a block begins with the first sample of the program's run.
        Wires that support passive mode (``supports_passive``) override it."""
        raise DriverMisuseError(f"{type(self).__name__} has no passive sample path")

    # -- exchanges, each under the one retry policy -------------------------------------------
    async def connect(self) -> None:
        """Open the link; refused connections are retried within ``timeout_s``, an unanswered
        request ends it after one ``timeout_s``."""
        clock = self.retry.clock
        t_start = clock()
        budget_end = t_start + self.timeout_s * self.connect_exchanges

        async def once(_attempt: int) -> None:
            self.connect_attempts += 1
            try:
                await asyncio.wait_for(self._connect(), max(budget_end - clock(), 0.01))
            except AcquisitionError:
                raise  # before TimeoutError: ours subclass it
            except asyncio.TimeoutError:
                raise ControllerTimeoutError(
                    f"no answer from {self.describe()} within {clock() - t_start:.1f} s: check the address "
                    "(host, port, node id) and that the controller is on and connected"
                ) from None
            self._connected = True
            if self._cycle is not None:
                self._cycle.ever_connected = True

        async def close_link(_exc: Exception) -> None:
            await self._close()

        # only a refused connection is retried: an unanswered request is not
        await self.retry.with_(budget_s=self.timeout_s).run(
            once, retryable=lambda exc: isinstance(exc, ControllerConnectionError), on_failure=close_link,
            errors=(AcquisitionError,))

    async def close(self) -> None:
        self._connected = False
        await self._close()

    async def _call(self, what: str, fn, *args, attempts: int | None = None):
        """``fn(*args)`` under the retry policy, reconnecting after link failures.

        Transient failures are retried once the link has come up in this cycle (the first
        connection has its own budget, :meth:`connect`); others end the cycle at once.
        """
        cycle = self.cycle

        async def once(_attempt: int):
            if not self._connected:
                await self.connect()
            if self.wire_timeouts:
                return await fn(*args)  # every request already bounded by the wire's own timeout
            try:
                async with asyncio.timeout(self.timeout_s):
                    return await fn(*args)
            except AcquisitionError:
                raise
            except TimeoutError:
                raise ControllerTimeoutError(f"no reply from {self.describe()} within {self.timeout_s:g} s") from None

        def retryable(exc: AcquisitionError) -> bool:
            return exc.transient and cycle.ever_connected

        async def on_failure(exc: AcquisitionError) -> None:
            if retryable(exc):
                cycle.link_trouble = str(exc)
                if isinstance(exc, (ControllerConnectionError, ControllerTimeoutError)):
                    await self.close()  # a late reply must never answer the next request

        policy = self.retry if attempts is None else self.retry.with_(attempts=attempts)
        try:
            return await policy.run(once, retryable=retryable, on_failure=on_failure, errors=(AcquisitionError,))
        except AcquisitionError as exc:
            if not retryable(exc):
                raise
            raise _gave_up(what, exc) from exc

    async def _safe_abort(self) -> str:
        """Best effort to leave the axis stopped; returns a note for the failure reason."""

        async def once(_attempt: int) -> None:
            if not self._connected:
                await self.connect()
            try:
                await asyncio.wait_for(self._abort(), self.timeout_s)
            except AcquisitionError:
                raise
            except asyncio.TimeoutError:
                raise ControllerTimeoutError(f"no reply to the abort within {self.timeout_s:g} s") from None

        async def close_link(_exc: Exception) -> None:
            await self.close()

        policy = self.retry.with_(attempts=20, backoff_s=0.1, backoff_max_s=0.1,
                                  budget_s=max(3.0 * self.timeout_s, 2.0))
        try:
            await policy.run(once, retryable=lambda _exc: True, on_failure=close_link, errors=(AcquisitionError,))
        except AcquisitionError as err:
            return f"abort could NOT be sent ({err}): stop the axis at the controller"
        return "abort sent, axis stopped"

    # -- the measurement loop -------------------------------------------------------------------
    async def acquire_async(self, program: RoundTripProgram, axis: AxisSpec) -> AcquiredTrace:
        """Run one round trip and return its trace; raise :class:`AcquisitionError` on any fault.

        On failure after the start, an abort is sent first; the exception's
        ``abort_note`` says whether it reached the controller. One cycle at a time per driver.
        """
        if self._cycle is not None:
            raise DriverMisuseError(
                f"a cycle is already under way on the driver for {self.describe()}: one cycle at a time per driver"
            )
        cycle = self._cycle = AcquisitionCycle(program=program, axis=axis, t_wall0=time.monotonic())
        if self.trigger == "passive":
            try:
                return await self._listen(cycle)
            finally:
                await self.close()
                self._cycle, self.last_cycle = None, cycle
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
            cycle.temperature0_c = status.temperature_c
            cycle.started = True  # from here on, any failure sends an abort
            # not retried: a start that timed out may have started the axis; the abort handles it
            first = await self._call("starting the round trip", self._start, program, attempts=1)
            trace = await self._drain_loop(cycle, first)
            cycle.started = False
            return trace
        except (AcquisitionError, asyncio.CancelledError, KeyboardInterrupt) as exc:
            if cycle.started:
                note = await self._safe_abort()
                if isinstance(exc, AcquisitionError):
                    exc.abort_note = note
            raise
        finally:
            await self.close()
            self._cycle, self.last_cycle = None, cycle

    async def _drain_loop(self, cycle: AcquisitionCycle, first: int | None) -> AcquiredTrace:
        program, axis = cycle.program, cycle.axis
        rate = self.servo_rate_hz
        monitor = EncoderMonitor(program, axis.transmission_mm_per_rev, rate,
                                 jump_margin_mm=self.jump_margin_mm, stuck_travel_mm=self.stuck_travel_mm)
        assembler = cycle.assembler = TraceAssembler(
            continuous=self.continuous, max_lost_samples=self.max_lost_samples,
            first_counter=first if self.continuous else None)
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
                    f"the round trip did not finish within {deadline - cycle.t_wall0:.1f} s "
                    f"(programmed {program.duration_s:.1f} s)"
                )
            block = await self._call("reading samples", self._drain)
            c, m, t = assembler.add(block)
            if c.size:
                pending.append((c, m, t))
                pending_n += c.size
                if pending_n >= ENCODER_BATCH:
                    monitor.check(*_join(pending), skew_s=assembler.skew_s, clock_s=assembler.clock_s)
                    pending, pending_n = [], 0
                if t_first_block is None:
                    t_first_block = now
                last_progress = time.monotonic()
            if block.finished:
                finished = True
                break
            if block.caught_up and pending:
                monitor.check(*_join(pending), skew_s=assembler.skew_s, clock_s=assembler.clock_s)
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
            monitor.check(*_join(pending), skew_s=assembler.skew_s, clock_s=assembler.clock_s)
        monitor.finish(skew_s=assembler.skew_s, clock_s=assembler.clock_s)
        time_s, counter, motor, table = assembler.arrays(rate)
        if counter.size < 2:
            raise ControllerTimeoutError(f"{self.describe()} reported the round trip done with {counter.size} sample(s)")
        status = await self._call("reading the axis state", self._read_status)
        temps = [x for x in (cycle.temperature0_c, status.temperature_c) if math.isfinite(x)]
        return AcquiredTrace(
            protocol=self.protocol,
            mode=self.mode,
            time_s=time_s,
            counter=counter,
            motor_rev=motor,
            table_mm=table,
            temperature_c=float(np.mean(temps)) if temps else float("nan"),
            latched=self.latched,
            skew_uncertainty_um=assembler.skew_s * program.speed_mm_s * 1e3,
            clock_uncertainty_s=assembler.clock_s,
            lost_samples=assembler.lost_samples,
            servo_rate_hz=rate,
            program=program,
            wall_time_s=time.monotonic() - cycle.t_wall0,
            drain_time_s=(last_progress - t_first_block) if t_first_block is not None else float("nan"),
        )

    # -- passive round trips -----------------------------------------------------------------
    def detector_settings(self, axis: AxisSpec) -> DetectorSettings:
        """The detection settings for ``axis``: the configured ones over defaults that fit its
        travel (the stroke must cover 90 % of the useful travel; back within 1 mm, or 10 % of
        the travel on a short axis)."""
        lo, hi = axis.travel_mm
        span = abs(hi - lo)
        tol = min(1.0, 0.1 * span)
        base = DetectorSettings(min_stroke_mm=0.9 * span, return_tolerance_mm=tol,
                                rest_band_mm=min(DetectorSettings.rest_band_mm, tol))
        try:
            return replace(base, **self.passive)
        except TypeError as exc:
            raise InputError(f"passive settings: {exc}") from None

    async def _listen(self, cycle: AcquisitionCycle) -> AcquiredTrace:
        """Passive mode: record samples until the detector has one whole round trip."""
        settings = self.detector_settings(cycle.axis)
        detector = RoundTripDetector(settings, use_flag=self.running_flag)
        status = await self._call("reading the axis state", self._read_status)
        cycle.temperature0_c = status.temperature_c
        rate = self.servo_rate_hz
        # the detector's time-outs run on the samples' clock; this bounds the wall clock too
        deadline = time.monotonic() + settings.start_timeout_s + settings.max_duration_s + 3 * self.timeout_s + 5.0
        last_counter: int | None = None
        skew_s = clock_s = 0.0
        last_progress = time.monotonic()
        t_first_block = None
        while True:
            now = time.monotonic()
            if now > deadline:
                detector.finish()  # raises what the samples so far mean
            block = await self._call("reading samples", self._passive_drain)
            c = np.asarray(block.counter, dtype=np.int64)
            if c.size and last_counter is not None:
                keep = c > last_counter  # a sample read twice (ring and latched) counts once
                if not keep.all():
                    block = _take(block, keep)
                    c = c[keep]
            if c.size:
                if t_first_block is None:
                    t_first_block = now
                last_counter = int(c[-1])
                last_progress = time.monotonic()
                skew_s = max(skew_s, block.skew_s)
                clock_s = max(clock_s, block.clock_s)
                t = block.time_s if block.time_s is not None else c / rate
                found = detector.feed(t, block.motor_rev, block.table_mm, block.running, run_start=block.run_start)
                if found is not None:
                    break
            elif time.monotonic() - last_progress > self.stall_timeout_s:
                raise ControllerTimeoutError(
                    f"{self.describe()} delivered no new sample for {self.stall_timeout_s:g} s while mebm "
                    f"listened for a round trip ({detector.phase})")
            if block.caught_up:
                await asyncio.sleep(self.poll_interval_s)
        return self._passive_trace(cycle, found, rate, skew_s, t_first_block, last_progress, clock_s)

    def _passive_trace(self, cycle: AcquisitionCycle, found: DetectedRoundTrip, rate: float, skew_s: float,
                       t_first_block: float | None, last_progress: float, clock_s: float = 0.0) -> AcquiredTrace:
        axis = cycle.axis
        counter = np.rint(found.t_s * rate).astype(np.int64) if math.isfinite(rate) and rate > 0 \
            else np.arange(len(found), dtype=np.int64)
        # lost samples: counter gaps between consecutive samples of the controller's own
        # trace (flag set), where every servo cycle should be there; the polled rest
        # around it is decimated by design
        lost = 0
        if self.continuous and found.running is not None and len(found) > 1:
            both = found.running[1:] & found.running[:-1]
            lost = int((np.diff(counter)[both] - 1).clip(min=0).sum())
        if lost > self.max_lost_samples:
            raise LostSamplesError(f"{lost} samples missing from the controller's trace of the round trip "
                                   f"(allowed {self.max_lost_samples})", lost_samples=lost)
        program = observed_program(found, fallback=cycle.program)
        monitor = EncoderMonitor(program, axis.transmission_mm_per_rev, rate,
                                 jump_margin_mm=self.jump_margin_mm, stuck_travel_mm=self.stuck_travel_mm)
        monitor.check(counter, found.motor_rev, found.table_mm, skew_s=skew_s, clock_s=clock_s)
        monitor.finish(skew_s=skew_s, clock_s=clock_s)
        temps = [x for x in (cycle.temperature0_c,) if math.isfinite(x)]
        return AcquiredTrace(
            protocol=self.protocol, mode=self.mode, time_s=found.t_s - found.t_s[0], counter=counter,
            motor_rev=found.motor_rev, table_mm=found.table_mm,
            temperature_c=float(np.mean(temps)) if temps else float("nan"), latched=self.latched,
            skew_uncertainty_um=skew_s * program.speed_mm_s * 1e3, clock_uncertainty_s=clock_s, lost_samples=lost,
            servo_rate_hz=rate,
            program=program, wall_time_s=time.monotonic() - cycle.t_wall0,
            drain_time_s=(last_progress - t_first_block) if t_first_block is not None else float("nan"),
            notes=(f"passive: found by the {found.found_by}, stroke {found.stroke_mm:.3f} mm at "
                   f"{found.feed_mm_min:.0f} mm/min",),
            trigger="passive",
        )

    def acquire(self, program: RoundTripProgram, axis: AxisSpec) -> AcquiredTrace:
        """Blocking form of :meth:`acquire_async` for threads (runs its own event loop)."""
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return asyncio.run(self.acquire_async(program, axis))
        raise DriverMisuseError("acquire() called inside a running event loop: await acquire_async() instead")


#: Who starts the round trip: mebm ("active") or the CNC, mebm only recording ("passive").
TRIGGERS = ("active", "passive")


class BlockingLinkDriver(ControllerDriver):
    """A driver whose link is a blocking library (python-can, canopen): ``_connect`` and
    ``_close`` run its ``_connect_blocking``/``_close_blocking`` in a thread, and a link
    that fails half-open is closed again before the error goes up."""

    @abstractmethod
    def _connect_blocking(self) -> None: ...

    @abstractmethod
    def _close_blocking(self) -> None:
        """Close whatever is open; never raises."""

    async def _connect(self) -> None:
        await asyncio.to_thread(self._close_blocking)
        try:
            await asyncio.to_thread(self._connect_blocking)
        except BaseException:
            await asyncio.to_thread(self._close_blocking)
            raise

    async def _close(self) -> None:
        await asyncio.to_thread(self._close_blocking)


def observed_program(found: DetectedRoundTrip, *, fallback: RoundTripProgram) -> RoundTripProgram:
    """The round trip as it was run (passive mode): observed start, reversal, feed and dwell;
    the acceleration is the configured one (it is not observed)."""
    feed = found.feed_mm_min if math.isfinite(found.feed_mm_min) and found.feed_mm_min > 0 else fallback.feed_mm_min
    return RoundTripProgram(found.start_mm, found.reversal_mm, feed, acceleration_mm_s2=fallback.acceleration_mm_s2,
                            dwell_s=max(found.dwell_s, 0.0))


def _take(block: SampleBlock, keep: np.ndarray) -> SampleBlock:
    return replace(block, counter=block.counter[keep], motor_rev=block.motor_rev[keep],
                   table_mm=block.table_mm[keep], time_s=None if block.time_s is None else block.time_s[keep],
                   running=None if block.running is None else block.running[keep],
                   run_start=block.run_start and bool(keep[0]))


def _join(blocks):
    return tuple(np.concatenate([b[i] for b in blocks]) for i in range(3))


def _gave_up(what: str, last: AcquisitionError) -> AcquisitionError:
    """The error that ends a cycle once a transient fault outlived its retries: same kind, with
    the attempts in the message (a busy controller stays busy; any other reply, a protocol error)."""
    n = getattr(last, "attempts", 1)
    msg = f"{what}: {last} (gave up after {n} attempt{'s' if n > 1 else ''})"
    if isinstance(last, TimeoutError):
        return ControllerTimeoutError(msg)
    if isinstance(last, ConnectionError):
        return ControllerConnectionError(msg)
    if isinstance(last, DeviceBusyError):
        return DeviceBusyError(msg, code=last.code)
    return ProtocolError(msg, code=getattr(last, "code", None))


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
