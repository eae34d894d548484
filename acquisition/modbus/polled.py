"""Modbus driver for a controller described by a register profile (:mod:`acquisition.modbus.profile`).

The controller has no trace ring: each sample is polled, with the reads the profile
planned (one request when motor and table lie in one block: mode ``latched``; two when
they cannot: mode ``separate``, with the skew bound reported). Samples carry the host's
clock (the counter is microseconds since the start), and the trace reports the rate the
polling reached as its sample rate.

Active mode (this driver's :meth:`acquire_async`): mebm writes the profile's start
coil/register, polls until the done flag rises or the running flag falls, then releases
the start (writes 0). :meth:`poll` is the plain "read one sample now" path that a
passive recorder (the CNC starts the round trip) uses. TCP or RTU, as
:class:`~acquisition.modbus.driver.ModbusDriver`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from acquisition.errors import AcquisitionError
from acquisition.modbus.driver import ModbusDriver
from acquisition.modbus.profile import RegisterProfile, ValueSpec
from acquisition.types import AcquiredTrace, AxisState, ControllerStatus, RoundTripProgram, SampleBlock

COUNTER_HZ = 1e6  # the counter of polled samples: microseconds of the host clock since the start
#: Passive mode: a repeated reading counts as a new sample after this long (the axis rests).
REST_TICK_S = 0.02


@dataclass(frozen=True)
class PolledSample:
    """One sample read now. ``t_s``: host monotonic clock at the motor reading (middle of its
    request); ``skew_s``: bound on the time between the motor and table readings (0 when
    one PDU carried both); ``running``/``done``: None when the profile has no such flag."""

    t_s: float
    motor_rev: float
    table_mm: float
    temperature_c: float
    running: bool | None
    done: bool | None
    skew_s: float
    table_t_s: float = float("nan")  # host clock at the table reading (= t_s when one PDU)
    timing_s: float = 0.0  # bound on the error of t_s and table_t_s together (half of each request)


@dataclass
class _PollCycle:
    t0: float
    seen_running: bool = False
    seen_done_low: bool = False
    last_counter: int = -1
    last_raw: tuple[float, float] | None = None  # (motor, table) as last read
    prev_table: tuple[float, float] | None = None  # (host time, table mm) of the previous table read
    # passive mode: the flag of the last poll, and when a sample was last delivered as new
    last_running: bool | None = None
    last_new_t: float = float("-inf")


class ProfileModbusDriver(ModbusDriver):
    """Polls a Modbus controller laid out as ``profile`` says (TCP, or RTU with ``serial=``)."""

    def __init__(self, host: str, port: int = 502, *, profile: RegisterProfile, **kwargs):
        kwargs.setdefault("poll_interval_s", 0.001)
        kwargs.pop("mode", None)
        self.profile = profile  # before the base's checks: has_running_flag reads it
        super().__init__(host, port, mode=profile.mode, **kwargs)
        self.continuous = False

    @property
    def has_running_flag(self) -> bool:
        """Passive mode follows the profile's ``[running]`` flag when it has one."""
        return self.profile.get("running") is not None

    def describe(self) -> str:
        return f"{super().describe()} (profile {self.profile.name})"

    # -- wire ---------------------------------------------------------------------------------
    async def _read_fn(self, function: str, address: int, count: int, what: str) -> list:
        c, dev = self._client, self.device_id
        calls = {
            "holding": lambda: c.read_holding_registers(address, count=count, device_id=dev),
            "input": lambda: c.read_input_registers(address, count=count, device_id=dev),
            "coil": lambda: c.read_coils(address, count=count, device_id=dev),
            "discrete_input": lambda: c.read_discrete_inputs(address, count=count, device_id=dev),
        }
        rr = await self._request(what, calls[function])
        return list(rr.bits[:count]) if function in ("coil", "discrete_input") else list(rr.registers)

    async def _write_value(self, spec: ValueSpec, value: int, what: str) -> None:
        c, dev = self._client, self.device_id
        if spec.function == "coil":
            await self._request(what, lambda: c.write_coil(spec.address, bool(value), device_id=dev))
        else:
            await self._request(what, lambda: c.write_register(spec.address, int(value), device_id=dev))

    async def _connect(self) -> None:
        await self._open()
        self.servo_rate_hz = COUNTER_HZ
        await self.poll()  # every planned read once: a wrong address fails here, naming the request

    def _read_order(self) -> list[int]:
        """The profile's reads in the order of one poll. Following the running flag
        (passive), the flag is read first: it reads set only once the round trip has started,
        so the positions read after it in the same poll belong to the round trip. Read the
        other way round, a start between the two reads paired the rest position with the set
        flag, and the round trip was measured from the wrong start.
        Otherwise the motor position's read comes first. (The read order does not cause the
        RTU test's outliers on a loaded host: they occur with motor-first too.)"""
        order = list(range(len(self.profile.reads)))
        if self.trigger == "passive" and self.running_flag:
            order.sort(key=lambda i: 0 if "running" in self.profile.reads[i].values else 1)
        return order

    async def poll(self) -> PolledSample:
        """Read one sample now (connect first: :meth:`connect`)."""
        reads = self.profile.reads
        payloads, spans = [None] * len(reads), [(0.0, 0.0)] * len(reads)
        for i in self._read_order():
            req = reads[i]
            t_a = time.monotonic()
            payloads[i] = await self._read_fn(
                req.function, req.address, req.count,
                f"reading {', '.join(req.values)} ({req.function} {req.address}..{req.address + req.count - 1})")
            spans[i] = (t_a, time.monotonic())
        v = self.profile.decode(payloads)
        i_m = next(i for i, r in enumerate(self.profile.reads) if "motor" in r.values)
        i_t = next(i for i, r in enumerate(self.profile.reads) if "table" in r.values)
        t_m, t_t = (0.5 * (spans[i][0] + spans[i][1]) for i in (i_m, i_t))
        timing = 0.5 * ((spans[i_m][1] - spans[i_m][0]) + (spans[i_t][1] - spans[i_t][0]))
        if i_m == i_t:
            skew = 0.0
        else:
            # the two readings may straddle one refresh of the controller's registers
            lo, hi = min(spans[i_m][0], spans[i_t][0]), max(spans[i_m][1], spans[i_t][1])
            skew = (hi - lo) + self.profile.update_period_s
        flag = lambda k: bool(v[k]) if k in v else None  # noqa: E731
        return PolledSample(t_m, v["motor"], v["table"], v.get("temperature", float("nan")), flag("running"),
                            flag("done"), skew, t_t, timing)

    async def _read_status(self) -> ControllerStatus:
        s = await self.poll()
        return ControllerStatus(AxisState.RUNNING if s.running else AxisState.IDLE, 0, s.temperature_c,
                                self.servo_rate_hz)

    async def _start(self, program: RoundTripProgram) -> int | None:
        start = self.profile.get("start")
        s = await self.poll()
        # a done flag still set from the last round trip must fall before its rise counts
        self.cycle.wire = _PollCycle(t0=time.monotonic(), seen_done_low=not s.done)
        await self._write_value(start, start.value, "writing the start value")
        return 0

    async def _abort(self) -> None:
        abort = self.profile.get("abort")
        if abort is None:
            raise AcquisitionError(f"profile {self.profile.name!r} has no abort value")
        await self._write_value(abort, abort.value, "writing the abort value")

    async def _acknowledge(self) -> None:
        """Nothing to acknowledge: a profile's controller is IDLE whenever it is not running."""

    async def _passive_drain(self) -> SampleBlock:
        """Passive mode: one poll, never a write; ``running`` from the profile's flag, if any."""
        cur = self.cycle.wire
        if cur is None:
            cur = self.cycle.wire = _PollCycle(t0=time.monotonic())
        s = await self.poll()
        if (s.motor_rev, s.table_mm) == cur.last_raw and (
                (s.running is not None and s.running != cur.last_running) or s.t_s - cur.last_new_t > REST_TICK_S):
            # the same values again, but the flag changed, or the axis rests (a perfect encoder at
            # standstill repeats itself): a new sample, so the detector sees the flag fall and
            # the rest last, instead of a stream that stopped
            cur.last_raw = None
        before = cur.last_counter
        block = self._sample(cur, s, finished=False)
        if cur.last_counter != before:
            cur.last_new_t = s.t_s
        cur.last_running = s.running
        return block if s.running is None else replace(block, running=np.array([bool(s.running)]))

    async def _drain(self) -> SampleBlock:
        cur: _PollCycle = self.cycle.wire
        s = await self.poll()
        if s.running:
            cur.seen_running = True
        if s.done is False:
            cur.seen_done_low = True
        if self.profile.get("done") is not None:
            finished = bool(s.done) and cur.seen_done_low
        else:
            finished = cur.seen_running and not s.running
        if finished:
            start = self.profile.get("start")
            try:  # release the start (a PLC's start is an edge): the sample is kept if this fails
                await self._write_value(start, 0, "releasing the start value")
            except AcquisitionError as exc:
                self.note_link_trouble(exc)
        return self._sample(cur, s, finished)

    def _sample(self, cur: _PollCycle, s: PolledSample, finished: bool) -> SampleBlock:
        """The polled sample as a block (the table interpolated to the motor's read time when
        they were read separately; a repeated controller update keeps its counter)."""
        table, skew = s.table_mm, s.skew_s
        if s.skew_s > 0 and cur.prev_table is not None and cur.prev_table[0] < s.t_s < s.table_t_s:
            # separate reads: the table at the motor's read time, interpolated between this table
            # read and the previous one; what remains is the timing of each read within its
            # request, plus one refresh of the controller's registers
            (t0, x0), (t1, x1) = cur.prev_table, (s.table_t_s, s.table_mm)
            table = x0 + (x1 - x0) * (s.t_s - t0) / (t1 - t0)
            skew = s.timing_s + self.profile.update_period_s
        if s.skew_s > 0:
            cur.prev_table = (s.table_t_s, s.table_mm)
        counter = max(cur.last_counter + 1, int(round((s.t_s - cur.t0) * COUNTER_HZ)))
        if (s.motor_rev, s.table_mm) == cur.last_raw:
            # the same controller update read twice (polled faster than it refreshes): the same
            # sample again, not a new one at a later time; the assembler counts it as a duplicate
            counter = cur.last_counter
        cur.last_counter, cur.last_raw = counter, (s.motor_rev, s.table_mm)
        c = np.array([counter], dtype=np.int64)
        return SampleBlock(c, np.array([s.motor_rev]), np.array([table]), finished=finished,
                           time_s=c / COUNTER_HZ, skew_s=skew, clock_s=s.timing_s)

    # -- the cycle ------------------------------------------------------------------------------
    async def acquire_async(self, program: RoundTripProgram, axis) -> AcquiredTrace:
        """Active mode: start the controller's round-trip program and record it. The trace's
        ``servo_rate_hz`` is the rate the polling reached (samples over their time span)."""
        if self.trigger == "active" and not self.profile.can_start:
            raise AcquisitionError(
                f"profile {self.profile.name!r} has no start value: mebm cannot start the round trip on "
                f"{self.describe()} (add [start] and [done] or [running], or let the CNC start it)")
        trace = await super().acquire_async(program, axis)
        span = float(trace.time_s[-1] - trace.time_s[0]) if len(trace) > 1 else 0.0
        rate = (len(trace) - 1) / span if span > 0 else float("nan")
        how = "one request" if self.latched else "separate requests, the table interpolated to the motor's read time"
        note = f"polled at {rate:.0f} samples/s ({how}; profile {self.profile.name})" if math.isfinite(rate) else "polled"
        return replace(trace, servo_rate_hz=rate, notes=(*trace.notes, note))
