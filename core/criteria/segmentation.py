"""Split one axis' round trip into strokes and drop the reversal transients.

A stroke is a stretch where the motor moves one way. Its first part, from the
turning point until the table has followed, is the reversal transient: the motor
traverses the backlash while the table waits (Eq. 6). Those samples lie on
neither side of Eq. 5 and must not pollute the criteria, so each stroke keeps
only the samples after the table has moved ``engage_um`` from where it turned,
plus ``transient_margin_mm`` of motor travel for the chain to settle.

Everything here is vectorised: a 1,000,000-sample trace costs a few passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from core.errors import TraceError


@dataclass(frozen=True)
class SegmentationSettings:
    """Tuning of the stroke finder. Defaults suit feeds of 10-10,000 mm/min."""

    velocity_window_s: float = 0.02  # smoothing of the motor position before differentiating
    speed_threshold_fraction: float = 0.05  # moving = faster than this fraction of the peak speed
    min_stroke_fraction: float = 0.1  # strokes shorter than this fraction of the longest are jogs
    engage_um: float = 3.0  # table travel that shows the backlash has been traversed
    transient_margin_mm: float = 1.0  # further motor travel skipped after engagement


@dataclass(frozen=True)
class Stroke:
    """Sample indices of one stroke: ``turn`` (turning point), ``engaged`` (first kept
    sample), ``end`` (last kept sample, inclusive); ``direction`` is +1 or -1."""

    direction: int
    turn: int
    engaged: int
    end: int

    @property
    def name(self) -> str:
        return "positive" if self.direction > 0 else "negative"


def _runs(sign: np.ndarray) -> list[tuple[int, int, int]]:
    """Maximal runs of equal non-zero sign, as (sign, first, last) with zeros between
    runs of the same sign merged (a pause mid-stroke does not split it)."""
    nz = np.flatnonzero(sign)
    if nz.size == 0:
        return []
    s = sign[nz]
    cut = np.flatnonzero(np.diff(s)) + 1
    starts = np.concatenate(([0], cut))
    ends = np.concatenate((cut - 1, [nz.size - 1]))
    return [(int(s[a]), int(nz[a]), int(nz[b])) for a, b in zip(starts, ends)]


def find_strokes(
    time_s: np.ndarray,
    travel_mm: np.ndarray,
    table_mm: np.ndarray,
    settings: SegmentationSettings = SegmentationSettings(),
) -> list[Stroke]:
    """Strokes of a trace, given the nominal travel k_a x_m and the table position (mm)."""
    n = travel_mm.shape[0]
    stride = max(1, n // 20_000)  # a typical interval needs no median of a million
    dt = float(np.median(time_s[1::stride] - time_s[:-1:stride]))
    window = int(max(1, round(settings.velocity_window_s / dt)))
    smooth = uniform_filter1d(travel_mm, size=window, mode="nearest") if window > 1 else travel_mm
    # central differences (one-sided at the ends); np.gradient's non-uniform formula
    # costs five times as much for the same answer on a regularly sampled trace
    speed = np.empty(n)
    speed[1:-1] = (smooth[2:] - smooth[:-2]) / (time_s[2:] - time_s[:-2])
    speed[0] = (smooth[1] - smooth[0]) / (time_s[1] - time_s[0])
    speed[-1] = (smooth[-1] - smooth[-2]) / (time_s[-1] - time_s[-2])
    # The peak: the k-th largest speed, k three smoothing windows. Robust to a glitch (one
    # glitch raises about one window of samples) and, unlike a percentile, to a long dwell
    # in which the motion is only a small fraction of the samples.
    # (on every (window/4)-th sample: the speed is smoothed over a window, so the subsample
    # keeps the same peak and costs a fraction of a full partition)
    sub_stride = max(1, window // 4)
    sub = np.abs(speed[::sub_stride])
    k = min(sub.size, max(1, (3 * window + 1) // sub_stride))
    peak = float(np.partition(sub, sub.size - k)[sub.size - k])
    if not peak > 0:
        raise TraceError("the motor does not move (zero speed throughout)")
    threshold = settings.speed_threshold_fraction * peak
    sign = (speed > threshold).view(np.int8) - (speed < -threshold).view(np.int8)
    runs = _runs(sign)
    if not runs:
        raise TraceError("no stroke found: the motor never moves faster than the noise")
    lengths = [float(np.ptp(travel_mm[a : b + 1])) for _, a, b in runs]
    keep_len = settings.min_stroke_fraction * max(lengths)
    # Jogs are dropped, and a stroke never reaches across one: its turning point is sought
    # after the previous run of either sign and its end before the next, so a reversal
    # mid-stroke splits it and the piece after starts with its own reversal transient
    # (the table re-engaging), which the engagement test below finds and skips.
    strokes = []
    for k, ((s, a, b), length) in enumerate(zip(runs, lengths)):
        if length < keep_len:
            continue
        lo = runs[k - 1][2] if k else 0
        seg = travel_mm[lo : a + 1]
        turn = lo + int(np.argmin(seg) if s > 0 else np.argmax(seg))
        hi = runs[k + 1][1] if k + 1 < len(runs) else n - 1
        seg_end = travel_mm[b : hi + 1]
        end = b + int(np.argmax(seg_end) if s > 0 else np.argmin(seg_end))
        moved = s * (table_mm[turn : end + 1] - table_mm[turn])
        past = np.flatnonzero(moved > settings.engage_um * 1e-3)
        if past.size == 0:
            raise TraceError(
                f"the table never followed the motor on the {'positive' if s > 0 else 'negative'} "
                f"stroke starting at sample {turn} (a broken chain, or the wrong axis' encoder?)"
            )
        engaged = turn + int(past[0])
        moved_motor = s * (travel_mm[engaged : end + 1] - travel_mm[engaged])
        settled = np.flatnonzero(moved_motor >= settings.transient_margin_mm)
        if settled.size == 0:
            continue  # the whole stroke is transient: nothing usable
        strokes.append(Stroke(direction=s, turn=turn, engaged=engaged + int(settled[0]), end=end))
    return strokes
