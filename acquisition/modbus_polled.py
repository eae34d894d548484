"""Modbus driver for a controller described by a register profile (:mod:`acquisition.modbus_profile`).

The controller has no trace ring: each sample is polled, with the reads the profile
planned (one request when motor and table lie in one block: mode ``latched``; two when
they cannot: mode ``separate``, with the skew bound reported). Samples carry the host's
clock (the counter is microseconds since the start), and the trace reports the rate the
polling reached as its sample rate.

Active mode (this driver's :meth:`acquire_async`): mebm writes the profile's start
coil/register, polls until the done flag rises or the running flag falls, then releases
the start (writes 0). :meth:`poll` is the plain "read one sample now" path that a
passive recorder (the CNC starts the round trip) uses. TCP or RTU, as
:class:`~acquisition.modbus.ModbusDriver`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from acquisition.errors import AcquisitionError
from acquisition.modbus import ModbusDriver
from acquisition.modbus_profile import RegisterProfile, ValueSpec
from acquisition.types import AcquiredTrace, AxisState, ControllerStatus, RoundTripProgram, SampleBlock

COUNTER_HZ = 1e6  # the counter of polled samples: microseconds of the host clock since the start


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


class ProfileModbusDriver(ModbusDriver):
    """Polls a Modbus controller laid out as ``profile`` says (TCP, or RTU with ``serial=``)."""

    def __init__(self, host: str, port: int = 502, *, profile: RegisterProfile, **kwargs):
        kwargs.setdefault("poll_interval_s", 0.001)
        kwargs.pop("mode", None)
        super().__init__(host, port, mode=profile.mode, **kwargs)
        self.profile = profile
        self.continuous = False

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

    async def poll(self) -> PolledSample:
        """Read one sample now (connect first: :meth:`connect`)."""
        payloads, spans = [], []
        for req in self.profile.reads:
            t_a = time.monotonic()
            payloads.append(await self._read_fn(
                req.function, req.address, req.count,
                f"reading {', '.join(req.values)} ({req.function} {req.address}..{req.address + req.count - 1})"))
            spans.append((t_a, time.monotonic()))
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
        if finished:
            start = self.profile.get("start")
            try:  # release the start (a PLC's start is an edge): the sample is kept if this fails
                await self._write_value(start, 0, "releasing the start value")
            except AcquisitionError as exc:
                self.note_link_trouble(exc)
        c = np.array([counter], dtype=np.int64)
        return SampleBlock(c, np.array([s.motor_rev]), np.array([table]), finished=finished,
                           time_s=c / COUNTER_HZ, skew_s=skew)

    # -- the cycle ------------------------------------------------------------------------------
    async def acquire_async(self, program: RoundTripProgram, axis) -> AcquiredTrace:
        """Active mode: start the controller's round-trip program and record it. The trace's
        ``servo_rate_hz`` is the rate the polling reached (samples over their time span)."""
        if not self.profile.can_start:
            raise AcquisitionError(
                f"profile {self.profile.name!r} has no start value: mebm cannot start the round trip on "
                f"{self.describe()} (add [start] and [done] or [running], or let the CNC start it)")
        trace = await super().acquire_async(program, axis)
        span = float(trace.time_s[-1] - trace.time_s[0]) if len(trace) > 1 else 0.0
        rate = (len(trace) - 1) / span if span > 0 else float("nan")
        how = "one request" if self.latched else "separate requests, the table interpolated to the motor's read time"
        note = f"polled at {rate:.0f} samples/s ({how}; profile {self.profile.name})" if math.isfinite(rate) else "polled"
        return replace(trace, servo_rate_hz=rate, notes=(*trace.notes, note))
