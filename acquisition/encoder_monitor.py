"""Online plausibility of the motor and table encoders during a round trip."""

from __future__ import annotations

import numpy as np

from acquisition.errors import EncoderFaultError
from acquisition.types import RoundTripProgram


class EncoderMonitor:
    """Online plausibility of the two encoders (vectorised per block).

    *Jumping*: a step between consecutive samples larger than twice the programmed
    speed allows, plus ``jump_margin_mm``. *Stuck*: one encoder does not change while
    the other travels more than ``stuck_travel_mm`` (well beyond any backlash).
    """

    def __init__(self, program: RoundTripProgram, transmission_mm_per_rev: float, servo_rate_hz: float, *,
                 jump_margin_mm: float, stuck_travel_mm: float):
        self.v_mm_s = program.speed_mm_s
        self.k_a = transmission_mm_per_rev
        self.rate = servo_rate_hz
        self.margin = jump_margin_mm
        self.stuck = stuck_travel_mm
        self._prev: tuple[int, float, float] | None = None  # counter, motor mm, table mm
        self._anchor = {"table": None, "motor": None}  # other encoder's position at last change

    def check(self, counter: np.ndarray, motor_rev: np.ndarray, table_mm: np.ndarray, skew_s: float = 0.0) -> None:
        """``skew_s``: worst-case time between the motor and table readings (unlatched modes)."""
        if counter.size == 0:
            return
        motor_mm = motor_rev * self.k_a
        if self._prev is not None:
            c = np.concatenate([[self._prev[0]], counter])
            m = np.concatenate([[self._prev[1]], motor_mm])
            t = np.concatenate([[self._prev[2]], table_mm])
        else:
            c, m, t = counter, motor_mm, table_mm
        if c.size >= 2:
            dt = np.diff(c) / self.rate
            limit = 2.0 * self.v_mm_s * (dt + 2.0 * skew_s) + self.margin
            for name, x, what in (("table", t, "linear (table)"), ("motor", m, "rotary (motor)")):
                step = np.abs(np.diff(x))
                bad = np.flatnonzero(step > limit)
                if bad.size:
                    i = int(bad[0])
                    raise EncoderFaultError(
                        f"{what} encoder jumped by {step[i]:.4f} mm between samples {int(c[i])} and "
                        f"{int(c[i + 1])} (at most {limit[i]:.4f} mm possible at "
                        f"{self.v_mm_s * 60:g} mm/min): check the scale, reading head and cable",
                        encoder=name,
                    )
            for name, own, other, what in (("table", t, m, "linear (table)"), ("motor", m, t, "rotary (motor)")):
                self._check_stuck(name, own, other, c, what)
        self._prev = (int(c[-1]), float(m[-1]), float(t[-1]))

    def _check_stuck(self, name, own, other, c, what) -> None:
        changed = np.concatenate([[False], np.abs(np.diff(own)) > 1e-6])
        idx = np.where(changed, np.arange(own.size), -1)
        last = np.maximum.accumulate(idx)
        anchor = np.where(last >= 0, other[np.maximum(last, 0)], np.nan)
        prev_anchor = self._anchor[name]
        if prev_anchor is None:
            prev_anchor = other[0]
        anchor = np.where(np.isnan(anchor), prev_anchor, anchor)
        travel = np.abs(other - anchor)
        bad = np.flatnonzero(travel > self.stuck)
        if bad.size:
            i = int(bad[0])
            raise EncoderFaultError(
                f"{what} encoder stuck at {own[i]:.4f} mm while the other encoder travelled "
                f"{travel[i]:.3f} mm (up to sample {int(c[i])}): check the encoder and its cable",
                encoder=name,
            )
        self._anchor[name] = float(anchor[-1])
