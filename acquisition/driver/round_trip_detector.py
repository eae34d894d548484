"""Find one round trip in a stream of samples that mebm did not command (passive mode).

On a production machine the CNC runs the round-trip program; mebm only listens. The
:class:`RoundTripDetector` is fed blocks of samples as they arrive (``t_s``, ``motor_rev``,
``table_mm`` and, when the controller has one, a ``running`` flag) and returns the samples
of the first whole round trip it sees, with a little rest before and after, so the core's
analysis runs on them as on an actively commanded run. Pure numpy and Python: no I/O, no
clock of its own (every time-out is measured in the samples' own ``t_s``), so the result
does not depend on how the stream was cut into blocks.

Two ways to find it:

- **Positions only** (no flag configured). The axis is *at rest* while it stays within
  ``rest_band_mm`` of where the rest began for at least ``rest_s``. A round trip leaves a
  rest at position A (the *start*), goes at least ``min_stroke_mm`` one way (the
  *reversal* is the farthest point, once the axis has come back from it by more than
  ``return_tolerance_mm``), comes back to within ``return_tolerance_mm`` of A and rests
  there again for ``rest_s`` (the *end*). A stop at the reversal (dwell) is allowed. Every
  rest is a possible start, so a positioning move before the round trip (of any length,
  ending in a rest) is passed over. A second reversal (a motion that goes out again
  before it has come to rest) disqualifies the start before it: machining motion is not a
  round trip.
- **Running flag** (``use_flag=True``, a "program running" bit of the controller). The
  round trip is the stretch where the flag is set, after it was first seen clear (a
  program already running when listening began is not taken halfway), plus
  ``flag_margin_s`` before and after. Its stroke must reach ``min_stroke_mm`` and the axis
  must end within ``return_tolerance_mm`` of where it started, or the round trip is
  reported incomplete.

Time-outs: no round trip *started* (left rest, or flag raised) within ``start_timeout_s``
of the first sample: :class:`~acquisition.errors.NoRoundTripSeen`; a round trip that
takes longer than ``max_duration_s`` from leaving rest to coming back to rest:
:class:`~acquisition.errors.RoundTripTooLong`; a round trip that reversed but came to rest
somewhere else (or whose stream ended first, :meth:`RoundTripDetector.finish`):
:class:`~acquisition.errors.IncompleteRoundTrip`. A stroke that came back but stopped
short of the minimum is not an error: it was not the round trip (a jog), listening goes on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from acquisition.errors import IncompleteRoundTrip, NoRoundTripSeen, RoundTripTooLong
from core.errors import InputError, require_positive


@dataclass(frozen=True)
class DetectorSettings:
    """How a passive round trip is recognised; see the module's docstring for each rule.

    ``pre_roll_s``: rest kept before the start (at most the rest that was there; default
    ``rest_s``). The rest after the end is the ``rest_s`` that proved it.
    """

    start_timeout_s: float = 600.0
    max_duration_s: float = 120.0
    rest_band_mm: float = 0.005
    rest_s: float = 0.1
    min_stroke_mm: float = 10.0
    return_tolerance_mm: float = 1.0
    pre_roll_s: float | None = None
    flag_margin_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("start_timeout_s", "max_duration_s", "rest_band_mm", "rest_s", "min_stroke_mm",
                     "return_tolerance_mm"):
            require_positive(name, getattr(self, name))
        if self.pre_roll_s is not None and not (math.isfinite(self.pre_roll_s) and self.pre_roll_s >= 0):
            raise InputError(f"pre_roll_s (={self.pre_roll_s}) must be >= 0")
        if not (math.isfinite(self.flag_margin_s) and self.flag_margin_s >= 0):
            raise InputError(f"flag_margin_s (={self.flag_margin_s}) must be >= 0")
        if self.return_tolerance_mm < self.rest_band_mm:
            raise InputError(f"return_tolerance_mm (={self.return_tolerance_mm}) must be >= rest_band_mm "
                             f"(={self.rest_band_mm})")
        if self.min_stroke_mm <= 2 * self.return_tolerance_mm:
            raise InputError(f"min_stroke_mm (={self.min_stroke_mm}) must exceed twice return_tolerance_mm "
                             f"(={self.return_tolerance_mm}): a stroke must be told from the way back")

    @property
    def pre_roll(self) -> float:
        return self.rest_s if self.pre_roll_s is None else self.pre_roll_s


@dataclass(frozen=True)
class DetectedRoundTrip:
    """The samples of one round trip and where it started, reversed and ended.

    Indices are into the arrays (``start_index``: first sample off the rest, or with the flag
    set; ``reversal_index``: the farthest sample; ``end_index``: first sample of the rest that
    ended it, or the last with the flag set).
    ``feed_mm_min`` is the observed cruise speed; ``found_by`` is ``"positions"`` or
    ``"flag"``.
    """

    t_s: np.ndarray
    motor_rev: np.ndarray
    table_mm: np.ndarray
    start_index: int
    reversal_index: int
    end_index: int
    start_mm: float
    reversal_mm: float
    end_mm: float
    feed_mm_min: float
    dwell_s: float
    found_by: str
    running: np.ndarray | None = None  # the flag fed with the samples (all False if none was)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def stroke_mm(self) -> float:
        return abs(self.reversal_mm - self.start_mm)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[self.end_index] - self.t_s[self.start_index])


class _Start:
    """A rest the round trip may have started from, followed sample by sample."""

    __slots__ = ("ref", "rest_i", "rest_t", "leave_i", "leave_t", "sign", "ext", "ext_i", "back", "near")

    def __init__(self, ref: float, rest_i: int, rest_t: float):
        self.ref, self.rest_i, self.rest_t = ref, rest_i, rest_t
        self.leave_i: int | None = None
        self.leave_t = math.nan
        self.sign = 0.0
        self.ext = 0.0  # farthest excursion so far, in the direction of leaving (mm)
        self.ext_i = -1
        self.back = False  # reversed: coming back
        self.near = math.inf  # closest excursion since the reversal


class RoundTripDetector:
    """Streaming detector of one round trip; feed it blocks, it returns the round trip once.

    ``feed`` returns ``None`` until the round trip is whole, then a
    :class:`DetectedRoundTrip` (later calls raise). It raises
    :class:`~acquisition.errors.NoRoundTripSeen`, :class:`~acquisition.errors.RoundTripTooLong`
    or :class:`~acquisition.errors.IncompleteRoundTrip` as soon as the samples prove it.
    """

    def __init__(self, settings: DetectorSettings = DetectorSettings(), *, use_flag: bool = False):
        self.settings = settings
        self.use_flag = bool(use_flag)
        self._chunks: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []  # (i0, t, m, x, flag)
        self._n = 0  # samples fed so far (global index of the next one)
        self._t0 = math.nan
        self._t_last = -math.inf
        self.done = False
        # positions: the current run of samples within the band of its first sample
        self._run_ref = math.nan
        self._run_i = 0
        self._run_t = math.nan
        self._run_rest = False
        self._starts: list[_Start] = []
        self._problem: Exception | None = None  # the last near miss, reported at the time-out
        # flag
        self._flag_seen_low = False
        self._rise_i: int | None = None
        self._rise_t = math.nan
        self._fall_i: int | None = None
        self._fall_t = math.nan

    # -- state, for the driver's messages ----------------------------------------------------
    @property
    def phase(self) -> str:
        """``waiting`` (no start yet), ``moving`` (a round trip may be under way) or ``done``."""
        if self.done:
            return "done"
        if self.use_flag:
            return "moving" if self._rise_i is not None else "waiting"
        return "moving" if self._in_progress() else "waiting"

    @property
    def samples_seen(self) -> int:
        return self._n

    def _in_progress(self) -> bool:
        return any(s.leave_i is not None for s in self._starts)

    # -- feeding -----------------------------------------------------------------------------
    def feed(self, t_s, motor_rev, table_mm, running=None, *, run_start: bool = False) -> DetectedRoundTrip | None:
        """Take the next samples (1-D arrays of one length, ``t_s`` increasing).

        ``run_start``: the first of these samples is the first of the controller's program
        run (the wire read it from the start of the controller's own trace), so a flag
        already set when listening began is taken from there, not waited out."""
        if self.done:
            raise InputError("this detector has already returned its round trip: make a new one for the next")
        t = np.asarray(t_s, dtype=float).ravel()
        m = np.asarray(motor_rev, dtype=float).ravel()
        x = np.asarray(table_mm, dtype=float).ravel()
        if not (t.shape == m.shape == x.shape):
            raise InputError(f"t_s, motor_rev and table_mm must have one length (got {t.size}, {m.size}, {x.size})")
        if self.use_flag and running is None:
            raise InputError("this detector follows the running flag: pass running= with every block")
        if running is not None:
            f = np.asarray(running, dtype=bool).ravel()
            if f.shape != t.shape:
                raise InputError(f"running must have the length of t_s (got {f.size}, {t.size})")
        else:
            f = np.zeros(t.shape, dtype=bool)
        if t.size == 0:
            return None
        for name, a in (("t_s", t), ("motor_rev", m), ("table_mm", x)):
            bad = ~np.isfinite(a)
            if bad.any():
                raise InputError(f"{name} is NaN or inf at sample {self._n + int(np.argmax(bad))}")
        if t[0] <= self._t_last or (t.size > 1 and np.any(np.diff(t) <= 0)):
            raise InputError(f"t_s must increase from sample to sample (near sample {self._n})")
        i0 = self._n
        self._chunks.append((i0, t, m, x, f))
        self._n += t.size
        if math.isnan(self._t0):
            self._t0 = float(t[0])
        self._t_last = float(t[-1])
        if self.use_flag and run_start and not self._flag_seen_low and bool(f[0]):
            self._flag_seen_low = True  # the run is whole from its first sample
        found = self._scan_flag(i0, t, x, f) if self.use_flag else self._scan_positions(i0, t, x)
        if found is not None:
            self.done = True
            self._chunks = []
            return found
        self._trim()
        return None

    def finish(self) -> None:
        """The stream has ended without a whole round trip: raise what that means."""
        if self.done:
            return
        if self.use_flag and self._rise_i is not None:
            raise IncompleteRoundTrip(
                f"the running flag rose {self._t_last - self._rise_t:.1f} s before the stream ended and "
                "did not fall: the round trip did not finish while mebm listened")
        if not self.use_flag:
            started = [s for s in self._starts if s.leave_i is not None and s.ext >= self.settings.min_stroke_mm]
            if started:
                s = started[0]
                raise IncompleteRoundTrip(
                    f"a stroke left rest at {s.ref:.3f} mm and reached {s.ref + s.sign * s.ext:.3f} mm, "
                    f"but the stream ended {self._t_last - s.leave_t:.1f} s later before it came back to rest")
        raise self._timed_out()

    # -- positions ---------------------------------------------------------------------------
    def _scan_positions(self, i0: int, t: np.ndarray, x: np.ndarray) -> DetectedRoundTrip | None:
        cfg = self.settings
        band = cfg.rest_band_mm
        n = t.size
        j = 0
        if math.isnan(self._run_ref):
            self._run_ref, self._run_i, self._run_t = float(x[0]), i0, float(t[0])
            j = 1
        tl, xl = t.tolist(), x.tolist()
        while j < n:
            # fast path: resting at the only start there is; skip to the first sample off the band
            if self._run_rest and len(self._starts) == 1 and self._starts[0].leave_i is None:
                off = np.flatnonzero(np.abs(x[j:] - self._run_ref) > band)
                k = j + int(off[0]) if off.size else n
                if k > j:
                    late = np.flatnonzero(t[j:k] - self._t0 > cfg.start_timeout_s)
                    if late.size:
                        self._t_last = float(t[j + int(late[0])])
                        raise self._timed_out()
                    j = k
                    continue
            found = self._step(i0 + j, tl[j], xl[j])
            if found is not None:
                return found
            j += 1
        return None

    def _step(self, i: int, t: float, x: float) -> DetectedRoundTrip | None:
        cfg = self.settings
        band, tol = cfg.rest_band_mm, cfg.return_tolerance_mm
        # the rest run: samples within the band of the run's first sample
        rest_now = False
        if abs(x - self._run_ref) > band:
            self._run_ref, self._run_i, self._run_t, self._run_rest = x, i, t, False
        elif not self._run_rest and t - self._run_t >= cfg.rest_s:
            self._run_rest = rest_now = True
        # every possible start follows the sample
        keep: list[_Start] = []
        for s in self._starts:
            d = x - s.ref
            if s.leave_i is None:
                if abs(d) > band:
                    s.leave_i, s.leave_t, s.sign = i, t, (1.0 if d > 0 else -1.0)
                    s.ext, s.ext_i = abs(d), i
                keep.append(s)
                continue
            e = s.sign * d
            if not s.back:
                if e > s.ext:
                    s.ext, s.ext_i = e, i
                elif e < s.ext - tol:
                    # the reversal (a jog, if short of the minimum stroke: passed over at its rest)
                    s.back, s.near = True, e
            else:
                if e < s.near:
                    s.near = e
                elif e > s.near + tol:
                    # out again before resting: a second reversal; not a round trip from here
                    continue
            if t - s.leave_t > cfg.max_duration_s:
                if s.ext >= cfg.min_stroke_mm and self._run_rest:
                    self._note(IncompleteRoundTrip(
                        f"a stroke left rest at {s.ref:.3f} mm, reached {s.ref + s.sign * s.ext:.3f} mm and "
                        f"was resting at {self._run_ref:.3f} mm {cfg.max_duration_s:g} s later "
                        "(max_duration_s), not back at its start: the round trip was cut short"))
                elif s.ext >= cfg.min_stroke_mm:
                    self._note(RoundTripTooLong(
                        f"a stroke left rest at {s.ref:.3f} mm and had not come back to rest "
                        f"{cfg.max_duration_s:g} s later (max_duration_s): feed hold, or a program slower "
                        "than configured?"))
                continue
            keep.append(s)
        self._starts = keep
        if rest_now:
            found = self._at_rest(i, t)
            if found is not None:
                return found
        if t - self._t0 > cfg.start_timeout_s and not self._in_progress():
            self._t_last = t
            raise self._timed_out()
        return None

    def _at_rest(self, i: int, t: float) -> DetectedRoundTrip | None:
        """The axis has rested for ``rest_s`` at ``_run_ref`` (since ``_run_i``): an end, or a new start."""
        cfg = self.settings
        p = self._run_ref
        keep: list[_Start] = []
        for s in self._starts:
            if s.leave_i is None:
                continue  # cannot happen: a new rest needs a new run, which left the old one
            if s.back and s.ext >= cfg.min_stroke_mm and abs(p - s.ref) <= cfg.return_tolerance_mm:
                return self._cut_positions(s, i)
            if not s.back and s.ext >= cfg.min_stroke_mm:
                keep.append(s)  # a dwell at the far end: the way back may follow
                continue
            if s.back and s.ext >= cfg.min_stroke_mm:
                self._note(IncompleteRoundTrip(
                    f"a stroke left rest at {s.ref:.3f} mm, reversed at {s.ref + s.sign * s.ext:.3f} mm "
                    f"and came to rest at {p:.3f} mm, not back at its start (return_tolerance_mm "
                    f"{cfg.return_tolerance_mm:g}): the round trip was cut short"))
        keep.append(_Start(p, self._run_i, self._run_t))
        self._starts = keep
        return None

    def _cut_positions(self, s: _Start, end_i: int) -> DetectedRoundTrip:
        t, m, x, f = self._arrays()
        base = self._chunks[0][0]
        t_leave = s.leave_t
        lo = max(s.rest_i, base + int(np.searchsorted(t, t_leave - self.settings.pre_roll, side="left")))
        a, b = lo - base, end_i - base + 1
        t, m, x, f = t[a:b], m[a:b], x[a:b], f[a:b]
        start, rev, end = s.leave_i - lo, s.ext_i - lo, self._run_i - lo
        return self._result(t, m, x, start, rev, end, s.ref, "positions", f)

    # -- running flag ------------------------------------------------------------------------
    def _scan_flag(self, i0: int, t: np.ndarray, x: np.ndarray, f: np.ndarray) -> DetectedRoundTrip | None:
        cfg = self.settings
        j = 0
        n = t.size
        while j < n:
            if not self._flag_seen_low:
                low = np.flatnonzero(~f[j:])
                if not low.size:
                    self._check_start_timeout(t[-1])
                    return None
                j += int(low[0])
                self._flag_seen_low = True
            if self._rise_i is None:
                up = np.flatnonzero(f[j:])
                k = j + int(up[0]) if up.size else n
                late = np.flatnonzero(t[j:k] - self._t0 > cfg.start_timeout_s)
                if late.size:
                    self._t_last = float(t[j + int(late[0])])
                    raise self._no_round_trip()
                if not up.size:
                    return None
                self._rise_i, self._rise_t = i0 + k, float(t[k])
                j = k
            if self._fall_i is None:
                down = np.flatnonzero(~f[j:])
                k = j + int(down[0]) if down.size else n
                over = np.flatnonzero(t[j:k] - self._rise_t > cfg.max_duration_s)
                if over.size:
                    raise RoundTripTooLong(
                        f"the running flag has been set for more than {cfg.max_duration_s:g} s "
                        "(max_duration_s): the round trip is too long, or the flag is not the round trip's")
                if not down.size:
                    return None
                self._fall_i, self._fall_t = i0 + k, float(t[k])
                j = k
            # the margin after the fall
            if t[-1] >= self._fall_t + cfg.flag_margin_s:
                return self._cut_flag()
            return None
        return None

    def _check_start_timeout(self, t_last: float) -> None:
        if t_last - self._t0 > self.settings.start_timeout_s:
            raise self._no_round_trip()

    def _cut_flag(self) -> DetectedRoundTrip:
        cfg = self.settings
        t, m, x, f = self._arrays()
        base = self._chunks[0][0]
        r, fl = self._rise_i - base, self._fall_i - base
        # the round trip proper is r .. fl-1 (the samples with the flag set), plus the margins
        lo = int(np.searchsorted(t, self._rise_t - cfg.flag_margin_s, side="left")) if cfg.flag_margin_s > 0 else r
        hi = int(np.searchsorted(t, self._fall_t + cfg.flag_margin_s, side="right")) if cfg.flag_margin_s > 0 else fl
        t, m, x, f = t[lo:hi], m[lo:hi], x[lo:hi], f[lo:hi]
        start, end = r - lo, fl - 1 - lo
        ref = float(x[start])
        d = x[start : end + 1] - ref
        rev = start + int(np.argmax(np.abs(d)))
        stroke = abs(float(x[rev]) - ref)
        if stroke < cfg.min_stroke_mm:
            raise IncompleteRoundTrip(
                f"the running flag was set for {self._fall_t - self._rise_t:.1f} s but the table moved only "
                f"{stroke:.3f} mm from {ref:.3f} mm (min_stroke_mm {cfg.min_stroke_mm:g}): not the round trip")
        back = abs(float(x[end]) - ref)
        if back > cfg.return_tolerance_mm:
            raise IncompleteRoundTrip(
                f"the round trip started at {ref:.3f} mm, reversed at {float(x[rev]):.3f} mm and the flag fell "
                f"with the table at {float(x[end]):.3f} mm, {back:.3f} mm from its start (return_tolerance_mm "
                f"{cfg.return_tolerance_mm:g}): the round trip was cut short")
        return self._result(t, m, x, start, rev, end, ref, "flag", f)

    # -- shared ------------------------------------------------------------------------------
    def _note(self, problem: Exception) -> None:
        """Remember a near miss; the first one is reported if no round trip follows."""
        if self._problem is None:
            self._problem = problem

    def _timed_out(self) -> Exception:
        """The error that ends listening: the first near miss (a round trip cut short or too
        long) if there was one, which tells the technician more than "none seen"."""
        return self._problem if self._problem is not None else self._no_round_trip()

    def _no_round_trip(self) -> NoRoundTripSeen:
        cfg = self.settings
        what = "the running flag never rose" if self.use_flag else "the axis never left rest for a stroke and came back"
        return NoRoundTripSeen(
            f"no round trip seen within {cfg.start_timeout_s:g} s ({what}; {self._n} samples over "
            f"{max(self._t_last - self._t0, 0.0):.1f} s): start the round-trip program at the CNC, or "
            "check the axis and the detection settings", waited_s=cfg.start_timeout_s)

    def _arrays(self):
        return tuple(np.concatenate([c[k] for c in self._chunks]) for k in range(1, 5))

    def _trim(self) -> None:
        """Drop chunks no start can reach back to (waiting at rest for hours keeps ``pre_roll_s``)."""
        cfg = self.settings
        if self.use_flag:
            if self._rise_i is not None:
                return
            keep_t = self._t_last - cfg.flag_margin_s
        else:
            keep_t = self._t_last - cfg.pre_roll - cfg.rest_s
            for s in self._starts:
                if s.leave_i is not None:
                    keep_t = min(keep_t, s.leave_t - cfg.pre_roll)
        while len(self._chunks) > 1 and float(self._chunks[0][1][-1]) < keep_t:
            self._chunks.pop(0)

    def _result(self, t, m, x, start, rev, end, ref, found_by, running) -> DetectedRoundTrip:
        return DetectedRoundTrip(
            t_s=t, motor_rev=m, table_mm=x, start_index=int(start), reversal_index=int(rev), end_index=int(end),
            start_mm=float(ref), reversal_mm=float(x[rev]), end_mm=float(x[end]),
            feed_mm_min=_cruise_feed_mm_min(t[start : end + 1], x[start : end + 1]),
            dwell_s=_dwell_s(t, x, rev, self.settings.rest_band_mm), found_by=found_by, running=running)


def _cruise_feed_mm_min(t: np.ndarray, x: np.ndarray) -> float:
    """The cruise speed of the strokes (mm/min): the median speed where it is above half its peak,
    from differences over ~10 ms so encoder noise does not count."""
    if t.size < 3:
        return float("nan")
    dt_med = float(np.median(np.diff(t)))
    k = max(1, int(round(0.01 / dt_med))) if dt_med > 0 else 1
    k = min(k, t.size - 1)
    v = np.abs(x[k:] - x[:-k]) / (t[k:] - t[:-k])
    fast = v[v >= 0.5 * v.max()] if v.size and v.max() > 0 else v
    return float(np.median(fast) * 60.0) if fast.size else float("nan")


def _dwell_s(t: np.ndarray, x: np.ndarray, rev: int, band: float) -> float:
    """How long the table stayed within the rest band of the reversal point."""
    near = np.abs(x - x[rev]) <= band
    lo = rev
    while lo > 0 and near[lo - 1]:
        lo -= 1
    hi = rev
    while hi < x.size - 1 and near[hi + 1]:
        hi += 1
    return float(t[hi] - t[lo])


__all__ = ["DetectedRoundTrip", "DetectorSettings", "RoundTripDetector"]
