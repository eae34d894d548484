"""The plant's CNC interpolator: set-points on a 1 ms IPO grid for round trips and circles.

Moves follow a trapezoidal path-speed profile (programmed feed and acceleration), then a
moving-average filter of ``jerk_time_s`` over the set-points, the FIR jerk limitation many
CNCs apply (it turns each acceleration step into a ramp of that length, keeping
end points and dwells exact). Circles are one path: a feed-in arc of ``lead_in_deg`` before
the data arc (from rest; 0 means starting at rest on the data arc), the 360 deg data arc
and a lead-out of ``lead_out_deg`` (to rest), with one trapezoidal ramp along the whole arc.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InputError

from .drive import IPO_DT_S


def _trapezoid(length_mm: float, feed_mm_s: float, acc_mm_s2: float) -> np.ndarray:
    """Distance travelled on the IPO grid for a rest-to-rest move of ``length_mm`` (>= 0)."""
    if length_mm <= 0:
        return np.zeros(1)
    v = min(feed_mm_s, np.sqrt(length_mm * acc_mm_s2))
    t_a = v / acc_mm_s2
    d_a = 0.5 * acc_mm_s2 * t_a**2
    t_c = (length_mm - 2 * d_a) / v
    t_end = 2 * t_a + t_c
    t = np.arange(int(np.ceil(t_end / IPO_DT_S)) + 1) * IPO_DT_S
    s = np.where(
        t < t_a,
        0.5 * acc_mm_s2 * t**2,
        np.where(t < t_a + t_c, d_a + v * (t - t_a), length_mm - 0.5 * acc_mm_s2 * np.clip(t_end - t, 0, None) ** 2),
    )
    s[-1] = length_mm
    return np.minimum(s, length_mm)


def _smooth(path: np.ndarray, jerk_time_s: float) -> np.ndarray:
    n = max(1, int(round(jerk_time_s / IPO_DT_S)))
    if n == 1:
        return path
    pad = np.concatenate([np.full(n, path[0]), path, np.full(n, path[-1])])
    kernel = np.ones(n) / n
    out = np.convolve(pad, kernel, mode="same")
    return out[n:-n]


def _dwell(value: float, dwell_s: float) -> np.ndarray:
    return np.full(int(round(dwell_s / IPO_DT_S)), value)


@dataclass(frozen=True)
class Program:
    """Set-points per axis on the IPO grid (same length), starting at t = 0."""

    command_mm: dict[str, np.ndarray]

    @property
    def duration_s(self) -> float:
        return (len(next(iter(self.command_mm.values()))) - 1) * IPO_DT_S


def round_trip_program(axis: str, start_mm: float, end_mm: float, feed_mm_min: float, acc_mm_s2: float,
                       dwell_s: float, jerk_time_s: float) -> Program:  # fmt: skip
    """Rest 0.5 s at ``start_mm``, move to ``end_mm``, dwell, move back, rest 1 s."""
    if not feed_mm_min > 0 or not acc_mm_s2 > 0:
        raise InputError(f"feed_mm_min (={feed_mm_min}) and acc_mm_s2 (={acc_mm_s2}) must be > 0")
    d = end_mm - start_mm
    s = _trapezoid(abs(d), feed_mm_min / 60.0, acc_mm_s2)
    out = start_mm + np.sign(d) * s
    back = end_mm - np.sign(d) * s
    path = np.concatenate([_dwell(start_mm, 0.5), out, _dwell(end_mm, dwell_s), back, _dwell(start_mm, 1.0)])
    return Program({axis: _smooth(path, jerk_time_s)})


def circle_program(axes: tuple[str, str], radius_mm: float, centre_mm: tuple[float, float], feed_mm_min: float,
                   acc_mm_s2: float, direction: str, start_angle_deg: float, sweep_deg: float,
                   lead_in_deg: float, lead_out_deg: float, jerk_time_s: float) -> tuple[Program, float]:  # fmt: skip
    """A circle with feed-in and lead-out arcs; also returns the time the data arc starts."""
    if direction not in ("cw", "ccw"):
        raise InputError(f"direction (={direction!r}) must be 'cw' or 'ccw'")
    sgn = 1.0 if direction == "ccw" else -1.0
    total_deg = lead_in_deg + sweep_deg + lead_out_deg
    length = np.deg2rad(total_deg) * radius_mm
    s = _smooth(np.concatenate([_dwell(0.0, 0.3), _trapezoid(length, feed_mm_min / 60.0, acc_mm_s2),
                                _dwell(length, 0.5)]), jerk_time_s)  # fmt: skip
    theta = np.deg2rad(start_angle_deg - sgn * lead_in_deg) + sgn * s / radius_mm
    a, b = axes
    prog = Program({a: centre_mm[0] + radius_mm * np.cos(theta), b: centre_mm[1] + radius_mm * np.sin(theta)})
    s_data = np.deg2rad(lead_in_deg) * radius_mm
    t_data = float(np.argmax(s >= s_data - 1e-12) * IPO_DT_S)
    return prog, t_data
