"""Assembling a trace from the sample blocks a wire delivers: counter continuity, gaps, duplicates.

Pure (no I/O, no clock): the driver hands it each :class:`SampleBlock` in arrival order
and gets back the samples that are new; the assembler keeps them, counts what is missing
and refuses what cannot be trusted. The counter is the controller's servo or SYNC cycle,
unwrapped to int64 by the wire's codec.

- *Continuous* wires (a trace ring, SYNC-latched PDOs) number consecutive cycles: a gap
  is that many lost samples (never interpolated), counted in ``lost_samples`` and a
  :class:`LostSamplesError` past ``max_lost_samples``; a counter that repeats or goes
  back (a late, duplicated or torn block the wire let through) is a :class:`ProtocolError`.
- *Polled* wires (``continuous=False``) skip cycles by nature: a gap is not a loss, and a
  sample read again (the same latched cycle polled twice, a late reply) is dropped and
  counted in ``duplicates``.
"""

from __future__ import annotations

import numpy as np

from acquisition.errors import LostSamplesError, ProtocolError
from acquisition.types import SampleBlock
from core.errors import InputError


class TraceAssembler:
    """Collects the samples of one round trip; ``first_counter``: the counter the first
    sample must carry when the wire knows it (else the first block's first counter)."""

    def __init__(self, *, continuous: bool, max_lost_samples: int = 0, first_counter: int | None = None):
        if max_lost_samples < 0:
            raise InputError(f"max_lost_samples (={max_lost_samples}) must be >= 0")
        self.continuous = continuous
        self.max_lost_samples = int(max_lost_samples)
        self.lost_samples = 0  # missing counter values (continuous wires)
        self.duplicates = 0  # samples dropped as already assembled (polled wires)
        self.skew_s = 0.0  # worst motor/table skew of any block (unlatched wires)
        self.clock_s = 0.0  # worst error of any block's time stamps (polled wires)
        self.samples = 0
        self._expected = first_counter  # next counter (continuous)
        self._last: int | None = None  # last counter kept
        self._counter: list[np.ndarray] = []
        self._motor: list[np.ndarray] = []
        self._table: list[np.ndarray] = []
        self._time: list[np.ndarray] = []

    @property
    def last_counter(self) -> int | None:
        return self._last

    def add(self, block: SampleBlock) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Take one block; return its new samples (counter, motor_rev, table_mm), maybe none."""
        c = np.asarray(block.counter, dtype=np.int64)
        m = np.asarray(block.motor_rev, dtype=float)
        t = np.asarray(block.table_mm, dtype=float)
        if c.size and not self.continuous:
            floor = -(2**62) if self._last is None else self._last
            keep = c > np.maximum.accumulate(np.concatenate([[floor], c[:-1]]))
            if not keep.all():
                self.duplicates += int(c.size - np.count_nonzero(keep))
                c, m, t = c[keep], m[keep], t[keep]
        if c.size == 0:
            return c, m, t
        if self.continuous:
            self._check_continuity(c, t)
            self._expected = int(c[-1]) + 1
        self.skew_s = max(self.skew_s, float(block.skew_s))
        self.clock_s = max(self.clock_s, float(block.clock_s))
        self._counter.append(c)
        self._motor.append(m)
        self._table.append(t)
        if block.time_s is not None:
            self._time.append(np.asarray(block.time_s, dtype=float)[-c.size:])
        self._last = int(c[-1])
        self.samples += c.size
        return c, m, t

    def _check_continuity(self, c: np.ndarray, t: np.ndarray) -> None:
        prev = self._expected if self._expected is not None else int(c[0])
        if int(c[0]) == prev and int(c[-1]) - prev == c.size - 1 and bool((c[1:] > c[:-1]).all()):
            return  # the common case, checked cheaply
        steps = np.diff(np.concatenate([[prev - 1], c]))
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            raise ProtocolError(
                f"sample counter went backwards or repeated ({int(c[i])} after {prev - 1 if i == 0 else int(c[i - 1])})"
            )
        gaps = steps - 1
        i = int(np.argmax(gaps > 0))
        self.lost_samples += int(gaps.sum())
        if self.lost_samples > self.max_lost_samples:
            before = int(c[i]) - int(gaps[i])
            raise LostSamplesError(
                f"{int(gaps[i])} sample(s) lost: counter jumps from {before - 1} to {int(c[i])} "
                f"(table near {float(t[i]):.3f} mm); {self.lost_samples} lost in all. Samples are never "
                "interpolated: check the network load and the trace-buffer/SYNC settings",
                lost_samples=self.lost_samples, first_missing=before,
            )

    def arrays(self, servo_rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(time_s from the first sample, counter, motor_rev, table_mm) of everything kept.
        Time is the wire's when every block carried one, else the counter over the servo rate."""
        counter = np.concatenate(self._counter) if self._counter else np.zeros(0, dtype=np.int64)
        motor = np.concatenate(self._motor) if self._motor else np.zeros(0)
        table = np.concatenate(self._table) if self._table else np.zeros(0)
        if self._time and sum(x.size for x in self._time) == counter.size:
            time_s = np.concatenate(self._time)
            time_s = time_s - time_s[0]
        else:
            time_s = (counter - counter[0]) / servo_rate_hz if counter.size else np.zeros(0)
        return time_s, counter, motor, table
