"""The simulated controller's axis: a twin released sample by sample by the (scaled) wall clock.

Shared by the simulated Modbus controller and the simulated CANopen drive. On START
the whole round trip is precomputed with the twin; the servo counter runs at
``servo_rate_hz * time_scale`` samples per wall-clock second, and every query
(latched registers, trace ring buffer, SYNC) sees the samples whose servo cycle has
passed. Thread-safe: the Modbus server calls it from its event loop, the CANopen
drive from python-can's notifier thread.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from acquisition.scale import EncoderScale
from acquisition.sim.faults import Fault, FaultSchedule
from acquisition.sim.twin import Twin
from acquisition.types import AxisState, RoundTripProgram
from core.errors import InputError, require_positive


class SimAxis:
    """One simulated axis with a servo counter, latched sample and trace buffer."""

    def __init__(
        self,
        twin: Twin,
        *,
        servo_rate_hz: float = 1000.0,
        time_scale: float = 1.0,
        scale: EncoderScale | None = None,
        faults=(),
        ring_records: int = 2000,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.twin = twin
        self.servo_rate_hz = require_positive("servo_rate_hz", servo_rate_hz)
        self.time_scale = require_positive("time_scale", time_scale)
        self.scale = scale or EncoderScale()
        self.faults = faults if isinstance(faults, FaultSchedule) else FaultSchedule(faults)
        self.ring_records = int(ring_records)
        self.clock = clock
        self._lock = threading.RLock()
        self._epoch = clock()
        self.state = AxisState.IDLE
        self.fault_code = 0
        self.cycles_started = 0
        self.on_fault: Callable[[int], None] | None = None  # called once when a device fault occurs
        self._hold_counts = (0, 0)
        self._first = 0  # servo counter of sample 0 of the current trace
        self._n = 0  # samples the trace will have (shortened by a fault or abort)
        self._motor = np.zeros(0, dtype=np.int64)
        self._table = np.zeros(0, dtype=np.int64)
        self._rec_idx = np.zeros(0, dtype=np.int64)  # sample index of each trace record
        self._emcy_at: int | None = None
        self._emcy_code = 0
        self._t_start = self._epoch
        self.program: RoundTripProgram | None = None
        self.active_faults: list[Fault] = []
        self.duration_wall_s = 0.0
        # boot before serving, as a controller does: the first motion program otherwise pays
        # the twin's imports and JIT compilation (0.6 s to seconds) inside the start
        # request's timeout. warm_up() leaves the twin's state (nut side, noise) as it was.
        warm_up = getattr(twin, "warm_up", None)
        if warm_up is not None:
            warm_up()

    # -- clock ---------------------------------------------------------------------------
    def counter(self, now: float | None = None) -> int:
        """Servo cycle counter (unbounded int; the wire carries it modulo 2**32)."""
        now = self.clock() if now is None else now
        return int((now - self._epoch) * self.time_scale * self.servo_rate_hz)

    def progress(self, now: float | None = None) -> float:
        """Fraction of the running round trip done (by wall clock), 0 when idle."""
        if self.program is None or self.duration_wall_s <= 0:
            return 0.0
        now = self.clock() if now is None else now
        return (now - self._t_start) / self.duration_wall_s

    def fault(self, kind: str) -> Fault | None:
        for f in self.active_faults:
            if f.kind == kind:
                return f
        return None

    def clear_faults(self) -> None:
        """End every injected fault now, including the one of the running cycle."""
        self.faults.clear()
        self.active_faults = []

    # -- commands --------------------------------------------------------------------------
    def prepare(self, program: RoundTripProgram) -> None:
        """Compute the round trip ahead of :meth:`start`, as a drive does when the program is
        written: the start command then takes effect at once, not after the twin has run."""
        trace = self.twin.round_trip(program, self.servo_rate_hz)
        with self._lock:
            self._prepared = (program, self.cycles_started, trace)

    def start(self, program: RoundTripProgram) -> None:
        """Precompute the round trip with the twin (unless prepared) and start releasing it.
        Raises if not idle."""
        with self._lock:
            self.update()
            if self.state in (AxisState.RUNNING, AxisState.FAULT):
                raise InputError(f"axis is {self.state.name}, cannot start a round trip")
            prepared, self._prepared = getattr(self, "_prepared", None), None
            if prepared is not None and prepared[0] == program and prepared[1] == self.cycles_started:
                trace = prepared[2]
            else:
                trace = self.twin.round_trip(program, self.servo_rate_hz)
            motor = self.scale.motor_counts(trace.motor_rev)
            table = self.scale.table_counts(trace.table_mm)
            n = len(trace)
            self.active_faults = self.faults.begin_cycle()
            written = np.ones(n, dtype=bool)
            self._emcy_at = None
            for f in self.active_faults:
                i = min(int(f.at * (n - 1)), n - 1)
                if f.kind == "stuck":
                    table[i:] = table[i]
                elif f.kind == "jump":
                    table[i:] += int(self.scale.table_counts(f.value("mm")))
                elif f.kind == "glitch":
                    at = i + (n // 100) * np.arange(int(f.value("n")))
                    table[at[at < n]] += int(self.scale.table_counts(f.value("mm")))
                elif f.kind == "lost":
                    written[i : i + int(f.value("n"))] = False
                elif f.kind == "emcy":
                    self._emcy_at, self._emcy_code = max(i, 1), int(f.value("code"))
            now = self.clock()
            self._first = self.counter(now) + 1
            self._t_start = now
            self._motor, self._table, self._n = motor, table, n
            self._rec_idx = np.flatnonzero(written)
            self.program = program
            self.duration_wall_s = n / (self.servo_rate_hz * self.time_scale)
            self.state = AxisState.RUNNING
            self.fault_code = 0
            self.cycles_started += 1

    def abort(self) -> None:
        with self._lock:
            self.update()
            if self.state == AxisState.RUNNING:
                k = self._k()
                self._stop_at(max(k, 1))
                self.state = AxisState.ABORTED

    def acknowledge(self) -> None:
        """Clear DONE/ABORTED/FAULT back to IDLE (a fault reset)."""
        with self._lock:
            self.update()
            if self.state != AxisState.RUNNING:
                self.state = AxisState.IDLE
                self.fault_code = 0

    # -- state -----------------------------------------------------------------------------
    def _k(self, now: float | None = None) -> int:
        """Samples of the trace whose servo cycle has passed."""
        return max(0, self.counter(now) - self._first + 1)

    def _stop_at(self, n: int) -> None:
        self._n = min(self._n, n)
        self._rec_idx = self._rec_idx[self._rec_idx < self._n]
        i = self._n - 1
        self._hold_counts = (int(self._motor[i]), int(self._table[i]))

    def update(self, now: float | None = None) -> AxisState:
        """Advance the state machine to ``now`` (end of program, scheduled device fault)."""
        with self._lock:
            if self.state != AxisState.RUNNING:
                return self.state
            k = self._k(now)
            if self._emcy_at is not None and k > self._emcy_at:
                self._stop_at(self._emcy_at)
                self.state = AxisState.FAULT
                self.fault_code = self._emcy_code
                self._emcy_at = None
                if self.on_fault is not None:
                    self.on_fault(self.fault_code)
            elif k >= self._n:
                self._stop_at(self._n)
                self.state = AxisState.DONE
            return self.state

    def latched(self, now: float | None = None) -> tuple[int, int, int]:
        """(servo counter, motor counts, table counts) latched in the current servo cycle."""
        with self._lock:
            self.update(now)
            c = self.counter(now)
            if self.state == AxisState.RUNNING:
                i = min(max(c - self._first, 0), self._n - 1)
                return c, int(self._motor[i]), int(self._table[i])
            return c, self._hold_counts[0], self._hold_counts[1]

    def snapshot(self, now: float | None = None) -> tuple[AxisState, int, int, int]:
        """(state, servo counter, motor counts, table counts) of one servo cycle, taken under
        the axis' lock: a controller's register image is consistent, so a round trip started
        between two separate reads cannot pair the old rest position with the new running flag."""
        with self._lock:
            counter, motor, table = self.latched(now)
            return self.state, counter, motor, table

    def position_at(self, now: float | None = None) -> tuple[float, float]:
        """Motor (rev) and table (mm) at wall time ``now``, interpolated between servo cycles."""
        with self._lock:
            self.update(now)
            if self.state != AxisState.RUNNING:
                m, t = self._hold_counts
            else:
                now = self.clock() if now is None else now
                u = (now - self._t_start) * self.time_scale * self.servo_rate_hz
                i = int(min(max(u, 0.0), self._n - 1.000001))
                f = min(max(u - i, 0.0), 1.0)
                j = min(i + 1, self._n - 1)
                m = self._motor[i] + f * (self._motor[j] - self._motor[i])
                t = self._table[i] + f * (self._table[j] - self._table[i])
            return float(self.scale.motor_rev(m)), float(self.scale.table_mm(t))

    @property
    def trace_first(self) -> int:
        return self._first

    def trace_count(self, now: float | None = None) -> int:
        """Records written to the trace buffer so far in this round trip."""
        with self._lock:
            if self.program is None:
                return 0
            self.update(now)
            k = min(self._k(now), self._n)
            return int(np.searchsorted(self._rec_idx, k))

    def ring_records_at(self, slot0: int, n: int, now: float | None = None) -> np.ndarray:
        """Trace-buffer records in slots slot0..slot0+n-1: int64 array (n, 3) of counter, motor, table."""
        with self._lock:
            w_count = self.trace_count(now)
            slots = np.arange(slot0, slot0 + n, dtype=np.int64)
            N = self.ring_records
            w = (w_count - 1) - ((w_count - 1 - slots) % N)
            out = np.zeros((n, 3), dtype=np.int64)
            ok = (w >= 0) & (w < w_count)
            if ok.any():
                idx = self._rec_idx[w[ok]]
                out[ok, 0] = self._first + idx
                out[ok, 1] = self._motor[idx]
                out[ok, 2] = self._table[idx]
            return out
