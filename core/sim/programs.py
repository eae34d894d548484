"""NC programs for the simulator: commanded position per axis as a function of time.

A :class:`Program` gives ``command_mm(t)`` (vectorised), the time window to record,
each axis' natural initial engagement and the metadata a dataset run needs. Paths
are interpolated analytically (the CNC interpolator is ideal); the engine samples
them on its internal grid.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from core.errors import InputError, require_finite, require_positive

DEFAULT_ACCELERATION_MM_S2 = 500.0


@dataclass(frozen=True)
class Program:
    """A commanded motion of one or two axes.

    ``initial_sides`` is each axis' natural initial engagement (``"positive"`` = the
    nut last pushed in + direction); an :class:`~core.sim.axis.AxisModel` with
    initial_side ``"auto"`` uses it. ``meta`` holds the dataset RunSpec fields
    (acceleration_mm_s2, radius_mm, ...). Samples are recorded for
    record_from_s <= t <= record_to_s.
    """

    kind: str
    axes: tuple[str, ...]
    feed_mm_min: float
    duration_s: float
    record_from_s: float
    record_to_s: float
    initial_sides: tuple[str, ...]
    path: Callable[[np.ndarray], np.ndarray] = field(repr=False, compare=False)
    meta: Mapping = field(default_factory=dict)

    def command_mm(self, t_s) -> dict[str, np.ndarray]:
        """Commanded position (mm) of each axis at times ``t_s`` (s)."""
        pos = self.positions(np.asarray(t_s, dtype=float))
        return {a: pos[i] for i, a in enumerate(self.axes)}

    def positions(self, t_s: np.ndarray) -> np.ndarray:
        """Commanded positions as an array (n_axes, len(t_s)); t is clipped to the program."""
        t = np.clip(np.asarray(t_s, dtype=float), 0.0, self.duration_s)
        return np.atleast_2d(self.path(t))


def _profile(length_mm: float, v_mm_s: float, a_mm_s2: float | None):
    """Trapezoidal distance profile: (duration_s, s(t)) from rest to rest over length_mm.

    a_mm_s2 None or inf: the velocity jumps to v at the start and to 0 at the end.
    """
    if a_mm_s2 is None or math.isinf(a_mm_s2):
        dur = length_mm / v_mm_s

        def s_jump(t):
            return np.clip(v_mm_s * t, 0.0, length_mm)

        return dur, s_jump
    a = a_mm_s2
    v = min(v_mm_s, math.sqrt(a * length_mm))  # triangular profile on short moves
    t_acc = v / a
    t_const = (length_mm - v * t_acc) / v
    dur = 2 * t_acc + t_const

    def s_trap(t):
        t = np.clip(t, 0.0, dur)
        up = 0.5 * a * np.minimum(t, t_acc) ** 2
        mid = v * np.clip(t - t_acc, 0.0, t_const)
        td = np.clip(t - t_acc - t_const, 0.0, t_acc)
        down = v * td - 0.5 * a * td**2
        return up + mid + down

    return dur, s_trap


def _time_at(s_fn, dur: float, target_mm: float) -> float:
    """Time at which a monotone profile reaches target_mm (bisection, 1e-12 s)."""
    lo, hi = 0.0, dur
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if s_fn(np.array(mid)) < target_mm:
            lo = mid
        else:
            hi = mid
    return hi


def _acceleration(value: float | None) -> float | None:
    if value is None or math.isinf(value):
        return None
    return require_positive("acceleration_mm_s2", value)


def _side(sign: float) -> str:
    return "positive" if sign >= 0 else "negative"


def round_trip(
    start_mm: float,
    end_mm: float,
    feed_mm_min: float,
    acceleration_mm_s2: float | None = DEFAULT_ACCELERATION_MM_S2,
    dwell_s: float = 1.0,
    *,
    axis: str = "y",
) -> Program:
    """One axis out from start_mm to end_mm and back, trapezoidal velocity, dwelling
    dwell_s before, between and after the strokes. acceleration None/inf: no ramp.
    The axis starts directly engaged for the first stroke.
    """
    a0 = require_finite("start_mm", start_mm)
    a1 = require_finite("end_mm", end_mm)
    if a1 == a0:
        raise InputError(f"end_mm (={end_mm}) must differ from start_mm (={start_mm})")
    v = require_positive("feed_mm_min", feed_mm_min) / 60.0
    acc = _acceleration(acceleration_mm_s2)
    dwell = float(dwell_s)
    if not (math.isfinite(dwell) and dwell >= 0):
        raise InputError(f"dwell_s (={dwell_s}) must be >= 0")
    length = abs(a1 - a0)
    sgn = 1.0 if a1 > a0 else -1.0
    t_move, s_fn = _profile(length, v, acc)
    t_out = dwell
    t_back = 2 * dwell + t_move
    duration = 3 * dwell + 2 * t_move

    def path(t):
        out = s_fn(t - t_out)
        back = s_fn(t - t_back)
        return a0 + sgn * (out - back)

    return Program(
        kind="round_trip",
        axes=(axis.lower(),),
        feed_mm_min=float(feed_mm_min),
        duration_s=duration,
        record_from_s=0.0,
        record_to_s=duration,
        initial_sides=(_side(sgn),),
        path=path,
        meta={"acceleration_mm_s2": acc, "start_mm": (a0,), "end_mm": a1, "dwell_s": dwell},
    )


def circle(
    radius_mm: float,
    centre_mm: tuple[float, float] = (0.0, 0.0),
    feed_mm_min: float = 1000.0,
    direction: str = "ccw",
    start_angle_deg: float = -90.0,
    sweep_deg: float = 360.0,
    *,
    axes: tuple[str, str] = ("x", "y"),
    lead_in_deg: float | None = None,
    lead_out_deg: float | None = None,
    settle_s: float = 1.0,
    acceleration_mm_s2: float | None = None,
) -> Program:
    """A circle of two axes, recorded over the data arc start_angle_deg .. + sweep_deg.

    Angles are from the + first-axis direction, counter-clockwise positive; ``cw``
    runs them backwards. The machine starts at rest on the circle lead_in_deg before
    the data arc (default: the arc run in settle_s plus the acceleration ramp, so
    the proportional loop's start-up lag has decayed, e^-K settle_s) and continues
    lead_out_deg past it (default: the same). lead_in_deg=0 starts on the data arc.
    acceleration None: the feed is commanded from the first instant.
    """
    r = require_positive("radius_mm", radius_mm)
    v = require_positive("feed_mm_min", feed_mm_min) / 60.0
    if direction not in ("cw", "ccw"):
        raise InputError(f"direction (={direction!r}) must be 'cw' or 'ccw'")
    th0 = require_finite("start_angle_deg", start_angle_deg)
    sweep = require_positive("sweep_deg", sweep_deg)
    cx, cy = (require_finite("centre_mm", c) for c in centre_mm)
    acc = _acceleration(acceleration_mm_s2)
    settle = float(settle_s)
    ramp_mm = 0.0 if acc is None else v * v / (2 * acc)
    auto_deg = math.degrees((ramp_mm + v * settle) / r)
    lead_in = auto_deg if lead_in_deg is None else float(lead_in_deg)
    lead_out = auto_deg if lead_out_deg is None else float(lead_out_deg)
    if not (lead_in >= 0 and lead_out >= 0):
        raise InputError(f"lead_in_deg (={lead_in_deg}) and lead_out_deg (={lead_out_deg}) must be >= 0")
    d = 1.0 if direction == "ccw" else -1.0
    total_mm = r * math.radians(lead_in + sweep + lead_out)
    duration, s_fn = _profile(total_mm, v, acc)
    theta_first = math.radians(th0) - d * math.radians(lead_in)

    def path(t):
        th = theta_first + d * s_fn(t) / r
        return np.stack([cx + r * np.cos(th), cy + r * np.sin(th)])

    rec0 = _time_at(s_fn, duration, r * math.radians(lead_in)) if lead_in > 0 else 0.0
    rec1 = _time_at(s_fn, duration, r * math.radians(lead_in + sweep))
    # Natural engagement: each axis pushed in the direction it first moves (the sign of
    # its velocity, or of its acceleration where it starts at a quadrant point).
    vx, vy = -math.sin(theta_first) * d, math.cos(theta_first) * d
    ax_, ay_ = -math.cos(theta_first), -math.sin(theta_first)
    sides = (
        _side(vx if abs(vx) > 1e-12 else ax_),
        _side(vy if abs(vy) > 1e-12 else ay_),
    )
    return Program(
        kind="circle",
        axes=tuple(a.lower() for a in axes),
        feed_mm_min=float(feed_mm_min),
        duration_s=duration,
        record_from_s=rec0,
        record_to_s=rec1,
        initial_sides=sides,
        path=path,
        meta={
            "radius_mm": r,
            "centre_mm": (cx, cy),
            "direction": direction,
            "start_angle_deg": th0,
            "sweep_deg": sweep,
            "acceleration_mm_s2": acc,
            "lead_in_deg": lead_in,
            "lead_out_deg": lead_out,
        },
    )


def line(
    angle_deg: float,
    length_mm: float,
    feed_mm_min: float,
    start_mm: tuple[float, float] = (0.0, 0.0),
    *,
    axes: tuple[str, str] = ("x", "y"),
    settle_s: float = 1.0,
) -> Program:
    """A straight line at angle_deg to the first axis, the paper's Eq. 7 setting: both
    axes start at feed without acceleration, the first (X) axis reversely engaged and
    the second (Y) directly engaged. Recorded from the start to settle_s after the end.
    """
    th = math.radians(require_finite("angle_deg", angle_deg))
    length = require_positive("length_mm", length_mm)
    v = require_positive("feed_mm_min", feed_mm_min) / 60.0
    x0, y0 = (require_finite("start_mm", c) for c in start_mm)
    c, s = math.cos(th), math.sin(th)
    t_move = length / v
    duration = t_move + max(float(settle_s), 0.0)

    def path(t):
        dist = np.clip(v * t, 0.0, length)
        return np.stack([x0 + c * dist, y0 + s * dist])

    sides = (_side(-c if abs(c) > 1e-12 else 1.0), _side(s if abs(s) > 1e-12 else 1.0))
    return Program(
        kind="line",
        axes=tuple(a.lower() for a in axes),
        feed_mm_min=float(feed_mm_min),
        duration_s=duration,
        record_from_s=0.0,
        record_to_s=duration,
        initial_sides=sides,
        path=path,
        meta={"angle_deg": math.degrees(th), "length_mm": length, "start_mm": (x0, y0)},
    )
