"""Interpolated set-points: jerk-filtered trapezoidal moves on a fine time grid.

A move of length L (mm) at feed v (mm/s) with acceleration a (mm/s²) is a trapezoidal
velocity profile, smoothed by a moving average of length T_j (s), the FIR jerk filter of
a CNC interpolator: the smoothed move keeps its length and its peak jerk is a / T_j.
"""

from __future__ import annotations

import numpy as np


def trapezoid_velocity(length_mm: float, feed_mm_s: float, accel_mm_s2: float, dt_s: float) -> np.ndarray:
    """Velocity samples (mm/s) of a trapezoidal move of ``length_mm``, one per ``dt_s``."""
    v = min(feed_mm_s, np.sqrt(length_mm * accel_mm_s2))
    t_acc = v / accel_mm_s2
    t_flat = length_mm / v - t_acc
    t_end = 2 * t_acc + t_flat
    t = np.arange(int(np.ceil(t_end / dt_s)) + 1) * dt_s
    vel = np.minimum.reduce([accel_mm_s2 * t, np.full_like(t, v), accel_mm_s2 * (t_end - t)])
    vel = np.clip(vel, 0.0, None)
    return vel * (length_mm / (vel.sum() * dt_s))  # exact length on the grid


def jerk_filter(vel: np.ndarray, window_s: float, dt_s: float) -> np.ndarray:
    """Moving average over ``window_s`` (the interpolator's jerk filter), length kept."""
    n = max(1, int(round(window_s / dt_s)))
    padded = np.concatenate([vel, np.zeros(n)])
    c = np.cumsum(np.concatenate([[0.0], padded]))
    return (c[n:] - c[:-n]) / n


def path_profile(moves: list[tuple[float, float, float, float]], window_s: float, dt_s: float) -> np.ndarray:
    """Path coordinate s(t) (mm) of a sequence of (dwell_s, signed_length_mm, feed, accel).

    Each entry dwells first, then moves; the profile ends at rest after a jerk-filter window.
    """
    parts = []
    for dwell_s, length_mm, feed_mm_s, accel_mm_s2 in moves:
        parts.append(np.zeros(int(round(dwell_s / dt_s))))
        if length_mm != 0.0:
            parts.append(np.sign(length_mm) * trapezoid_velocity(abs(length_mm), feed_mm_s, accel_mm_s2, dt_s))
    vel = jerk_filter(np.concatenate(parts), window_s, dt_s)
    return np.concatenate([[0.0], np.cumsum(vel[:-1]) * dt_s])
