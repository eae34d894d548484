"""Downsampling a long series for the screen: min/max per bucket.

A year of one-minute measurements is 525,600 points; a chart is ~1000 pixels wide.
Keeping, in each of ``max_points // 2`` equal-count buckets, the point with the
smallest and the one with the largest value shows every excursion (an alert-level
peak is never averaged away) at a cost that does not grow with history on the wire
or in the renderer.
"""

from __future__ import annotations

import numpy as np

from core.errors import InputError


def minmax_indices(values, max_points: int) -> np.ndarray:
    """Sorted indices of at most ``max_points`` points of ``values`` (in series order):
    the first and last point and, per bucket, the minimum and the maximum. NaNs are
    never chosen over a number in their bucket. All indices when there are few enough."""
    if int(max_points) != max_points or max_points < 4:
        raise InputError(f"max_points (={max_points!r}) must be an integer >= 4")
    y = np.asarray(values, dtype=float)
    n = y.size
    if n <= max_points:
        return np.arange(n)
    buckets = (max_points - 2) // 2
    edges = np.linspace(1, n - 1, buckets + 1).astype(np.int64)  # the first and last points are kept apart
    lo = np.where(np.isnan(y), np.inf, y)
    hi = np.where(np.isnan(y), -np.inf, y)
    picks = [0, n - 1]
    for a, b in zip(edges[:-1], edges[1:]):
        if b > a:
            picks.append(a + int(np.argmin(lo[a:b])))
            picks.append(a + int(np.argmax(hi[a:b])))
    return np.unique(np.asarray(picks, dtype=np.int64))
