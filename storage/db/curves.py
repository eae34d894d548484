"""Compact curves: float32 little-endian values on a uniform position grid."""

from __future__ import annotations

import numpy as np

from core.errors import InputError


def pack(position_mm: np.ndarray, values: np.ndarray) -> tuple[float, float, int, bytes]:
    """(start_mm, step_mm, n, bytes) of a curve; the grid must be uniform (it is: core
    reduces every round trip on ``start + step * arange(n)``)."""
    x = np.asarray(position_mm, dtype=float)
    v = np.asarray(values, dtype=float)
    if x.shape != v.shape or x.ndim != 1 or x.size < 1:
        raise InputError(f"curve: position_mm and values must be 1-D of equal length, got {x.shape} and {v.shape}")
    step = float((x[-1] - x[0]) / (x.size - 1)) if x.size > 1 else 0.0
    if x.size > 2 and np.max(np.abs(np.diff(x) - step)) > 1e-6 * max(abs(step), 1.0):
        raise InputError("curve: position_mm must be a uniform grid")
    return float(x[0]), step, int(x.size), v.astype("<f4").tobytes()


def unpack(start_mm: float, step_mm: float, n: int, blob: bytes) -> tuple[np.ndarray, np.ndarray]:
    values = np.frombuffer(blob, dtype="<f4").astype(float)
    if values.size != n:
        raise InputError(f"curve: stored {values.size} values, expected {n}")
    return start_mm + step_mm * np.arange(n), values
