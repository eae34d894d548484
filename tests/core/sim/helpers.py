"""Shared measurements on simulated round trips (what a technician reads from them)."""

from __future__ import annotations

import numpy as np


def strokes(trace, axis: str, lo_mm: float, hi_mm: float):
    """Per stroke (out, back): motor position as table travel k_a x_m and the offset
    table - k_a x_m, at constant commanded speed inside [lo_mm, hi_mm]."""
    ka = trace.models[axis].transmission_mm_per_rev
    t = trace.time_s
    cmd = trace.command_mm[axis]
    v = np.gradient(cmd, t)
    vmax = np.abs(v).max()
    pos = ka * trace.motor_rev[axis]
    off = trace.table_mm[axis] - pos
    out = []
    for sign in (1.0, -1.0):
        m = (np.abs(v - sign * vmax) < 1e-6 * vmax) & (cmd > lo_mm) & (cmd < hi_mm)
        order = np.argsort(pos[m])
        out.append((pos[m][order], off[m][order]))
    return out


def apparent_backlash_um(trace, axis: str, lo_mm: float, hi_mm: float) -> float:
    """Mean of (table offset on the way back - on the way out) at equal motor positions."""
    (p_out, o_out), (p_back, o_back) = strokes(trace, axis, lo_mm, hi_mm)
    grid = np.linspace(max(p_out[0], p_back[0]), min(p_out[-1], p_back[-1]), 200)
    return float(np.mean(np.interp(grid, p_back, o_back) - np.interp(grid, p_out, o_out)) * 1e3)
