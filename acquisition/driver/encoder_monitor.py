"""Online plausibility of the motor and table encoders during a round trip."""

from __future__ import annotations

import numpy as np

from acquisition.errors import EncoderFaultError
from acquisition.types import RoundTripProgram
from core.criteria.outliers import OutlierSettings, encoder_outliers


class EncoderMonitor:
    """Online plausibility of the two encoders (vectorised per block).

    *Glitches*: single samples and short bursts off both their neighbours, by the rule
    the analysis applies to files (:func:`core.criteria.outliers.encoder_outliers`):
    dropped before the checks below, counted in ``outliers``, and a fault only past
    ``outliers.max_fraction`` of the programmed samples. The last few samples of a
    block are judged with the next one (the rule looks at both neighbours);
    :meth:`finish` judges the rest.
    *Jumping*: a step between consecutive samples larger than twice the programmed
    speed allows, plus ``jump_margin_mm``. *Stuck*: one encoder does not change while
    the other travels more than ``stuck_travel_mm`` (well beyond any backlash).
    """

    def __init__(self, program: RoundTripProgram, transmission_mm_per_rev: float, servo_rate_hz: float, *,
                 jump_margin_mm: float, stuck_travel_mm: float, outliers: OutlierSettings = OutlierSettings()):
        self.v_mm_s = program.speed_mm_s
        self.k_a = transmission_mm_per_rev
        self.rate = servo_rate_hz
        self.margin = jump_margin_mm
        self.stuck = stuck_travel_mm
        self.outlier_settings = outliers
        self.outliers = 0  # glitch samples dropped so far
        self.seen = 0  # samples judged so far
        self._expected = max(1.0, program.duration_s * servo_rate_hz)
        self._prev: tuple[int, float, float] | None = None  # counter, motor mm, table mm
        self._anchor = {"table": None, "motor": None}  # other encoder's position at last change
        empty = np.zeros(0)
        self._held = (np.zeros(0, dtype=np.int64), empty, empty)  # not yet judged: c, motor mm, table mm
        self._context = (np.zeros(0, dtype=np.int64), empty, empty)  # last judged samples (c, motor, table)

    def check(self, counter: np.ndarray, motor_rev: np.ndarray, table_mm: np.ndarray, skew_s: float = 0.0,
              clock_s: float = 0.0) -> None:
        """``skew_s``: worst-case time between the motor and table readings (unlatched modes);
        ``clock_s``: bound on the error of the counter as a clock, in seconds (polled modes)."""
        self._judge(np.asarray(counter), np.asarray(motor_rev, dtype=float) * self.k_a,
                    np.asarray(table_mm, dtype=float), skew_s, clock_s, final=False)

    def finish(self, skew_s: float = 0.0, clock_s: float = 0.0) -> None:
        """Judge the samples held back for their right-hand neighbours (end of the trace)."""
        self._judge(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0), skew_s, clock_s, final=True)

    def _judge(self, counter, motor_mm, table_mm, skew_s, clock_s, *, final: bool) -> None:
        hc, hm, ht = self._held
        c = np.concatenate([hc, counter])
        m = np.concatenate([hm, motor_mm])
        t = np.concatenate([ht, table_mm])
        if c.size == 0:
            return
        half = self.outlier_settings.window_samples // 2
        ready = c.size if final else max(0, c.size - half)
        cc, cm, ct = self._context
        # the counter is the clock: polled modes skip servo cycles irregularly
        bad = encoder_outliers(np.concatenate([cm, m]), np.concatenate([ct, t]), self.outlier_settings,
                               time_s=np.concatenate([cc, c]).astype(float),
                               sampling_bound_um=self.v_mm_s * skew_s * 1e3,
                               clock_uncertainty_s=clock_s * self.rate if self.rate > 0 else 0.0)
        bad = bad[cm.size : cm.size + ready]
        self.outliers += int(np.count_nonzero(bad))
        self.seen += ready
        if self.outliers > self.outlier_settings.max_fraction * max(self._expected, self.seen):
            raise EncoderFaultError(
                f"{self.outliers} glitch samples on the encoders in {self.seen} "
                f"(> max_fraction {self.outlier_settings.max_fraction * 100:g} % of the round trip): "
                "check the scales, reading heads and cables",
                encoder="both",
            )
        keep = ~bad
        jc, jm, jt = c[:ready][keep], m[:ready][keep], t[:ready][keep]
        self._held = (c[ready:], m[ready:], t[ready:])
        self._context = (np.concatenate([cc, jc])[-2 * half :], np.concatenate([cm, jm])[-2 * half :],
                         np.concatenate([ct, jt])[-2 * half :])
        if jc.size:
            self._check_motion(jc, jm, jt, skew_s)

    def _check_motion(self, counter: np.ndarray, motor_mm: np.ndarray, table_mm: np.ndarray, skew_s: float) -> None:
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
