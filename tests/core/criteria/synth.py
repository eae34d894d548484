"""Exact synthetic round trips with a known b(x) and lead error, for the criteria tests.

Kinematics only (no loop dynamics): the nut follows a trapezoidal profile and the
table obeys the play operator of Eq. 5 with position-dependent width b(u) and lead
error e(u): feeding positively the table sits at max(x_turn, u + e(u) - b(u)/2),
negatively at min(x_turn, u + e(u) + b(u)/2), where x_turn is where it stopped.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from core.criteria.lead import lead_criteria


def trapezoid(distance_mm: float, feed_mm_s: float, accel_mm_s2: float | None, dt_s: float) -> np.ndarray:
    """Positions (mm, from 0) of a trapezoidal (or triangular) move sampled every dt_s."""
    if accel_mm_s2 is None:
        t_total = distance_mm / feed_mm_s
        t = np.arange(0.0, t_total, dt_s)
        return np.append(feed_mm_s * t, distance_mm)
    t_acc = feed_mm_s / accel_mm_s2
    d_acc = 0.5 * accel_mm_s2 * t_acc**2
    if 2 * d_acc > distance_mm:
        t_acc = np.sqrt(distance_mm / accel_mm_s2)
        d_acc, feed_mm_s = distance_mm / 2, accel_mm_s2 * t_acc
    t_flat = (distance_mm - 2 * d_acc) / feed_mm_s
    t_total = 2 * t_acc + t_flat
    t = np.arange(0.0, t_total, dt_s)
    x = np.where(
        t < t_acc,
        0.5 * accel_mm_s2 * t**2,
        np.where(
            t < t_acc + t_flat,
            d_acc + feed_mm_s * (t - t_acc),
            distance_mm - 0.5 * accel_mm_s2 * np.clip(t_total - t, 0, None) ** 2,
        ),
    )
    return np.append(x, distance_mm)


@dataclass
class Synthetic:
    time_s: np.ndarray
    motor_rev: np.ndarray
    table_mm: np.ndarray


def round_trip(
    *,
    start_mm: float,
    end_mm: float,
    feed_mm_min: float,
    backlash_um: Callable[[np.ndarray], np.ndarray],
    lead_error_um: Callable[[np.ndarray], np.ndarray],
    rate_hz: float = 1000.0,
    accel_mm_s2: float | None = 500.0,
    dwell_s: float = 0.5,
    cycles: int = 1,
    table_noise_um: float = 0.3,
    motor_noise_um: float = 0.0,
    transmission_mm_per_rev: float = 6.857,
    motor_zero_rev: float = 17.3,
    start_side: str = "negative",
    rng: np.random.Generator | None = None,
) -> Synthetic:
    rng = rng or np.random.default_rng(0)
    dt = 1.0 / rate_hz
    move = trapezoid(end_mm - start_mm, feed_mm_min / 60.0, accel_mm_s2, dt)
    dwell = np.zeros(int(round(dwell_s * rate_hz)))
    pieces, dirs = [np.full(dwell.size, start_mm)], [np.zeros(dwell.size)]
    for _ in range(cycles):
        for sign, seg in ((1, start_mm + move), (-1, end_mm - move)):
            pieces += [seg[1:], np.full(dwell.size, seg[-1])]
            dirs += [np.full(seg.size - 1, sign), np.full(dwell.size, sign)]
    u = np.concatenate(pieces)
    direction = np.concatenate(dirs)
    b_mm = backlash_um(u) * 1e-3
    e_mm = lead_error_um(u) * 1e-3
    table = np.empty_like(u)
    x_turn = u[0] + e_mm[0] + (b_mm[0] / 2 if start_side == "negative" else -b_mm[0] / 2)
    bounds = np.flatnonzero(np.diff(direction)) + 1
    for a, b in zip(np.concatenate(([0], bounds)), np.concatenate((bounds, [u.size]))):
        d = direction[a]
        if d > 0:
            table[a:b] = np.maximum(x_turn, u[a:b] + e_mm[a:b] - b_mm[a:b] / 2)
        elif d < 0:
            table[a:b] = np.minimum(x_turn, u[a:b] + e_mm[a:b] + b_mm[a:b] / 2)
        else:
            table[a:b] = x_turn
        x_turn = table[b - 1]
    table = table + rng.normal(0.0, table_noise_um * 1e-3, u.size)
    u_meas = u + rng.normal(0.0, motor_noise_um * 1e-3, u.size) if motor_noise_um else u
    t = np.arange(u.size) * dt
    return Synthetic(t, u_meas / transmission_mm_per_rev + motor_zero_rev, table)


def true_criteria(start_mm, end_mm, backlash_um, lead_error_um, screw_lead_mm=16.0, step_mm=0.01):
    """The criteria of the noiseless analytic curves on a fine grid."""
    x = np.arange(start_mm, end_mm + step_mm / 2, step_mm)
    b = backlash_um(x)
    e = lead_error_um(x)
    pos = lead_criteria(x, (e - b / 2) * 1e-3, direction="positive", screw_lead_mm=screw_lead_mm)
    neg = lead_criteria(x, (e + b / 2) * 1e-3, direction="negative", screw_lead_mm=screw_lead_mm)
    return float(b.mean()), pos, neg
