"""Encoder scaling: the single place where raw encoder counts become revolutions and millimetres.

Both wire formats (the Modbus register map and the CANopen objects) carry the two
positions as signed 32-bit counts; the drivers decode them here and nowhere else.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import require_positive

I32_MIN = -(2**31)
I32_MAX = 2**31 - 1


@dataclass(frozen=True)
class EncoderScale:
    """Counts per motor revolution (rotary encoder) and nanometres per table count (linear encoder)."""

    counts_per_rev: int = 131072
    table_nm_per_count: float = 10.0

    def __post_init__(self) -> None:
        require_positive("counts_per_rev", self.counts_per_rev)
        require_positive("table_nm_per_count", self.table_nm_per_count)

    def motor_rev(self, counts) -> np.ndarray:
        """Motor position in revolutions from i32 counts."""
        return np.asarray(counts, dtype=np.float64) / float(self.counts_per_rev)

    def table_mm(self, counts) -> np.ndarray:
        """Table position in mm from i32 counts."""
        return np.asarray(counts, dtype=np.float64) * (self.table_nm_per_count * 1e-6)

    def motor_counts(self, motor_rev) -> np.ndarray:
        """Inverse of :meth:`motor_rev` (used by the simulated controllers), saturated to i32."""
        c = np.rint(np.asarray(motor_rev, dtype=np.float64) * self.counts_per_rev)
        return np.clip(c, I32_MIN, I32_MAX).astype(np.int64)

    def table_counts(self, table_mm) -> np.ndarray:
        """Inverse of :meth:`table_mm` (used by the simulated controllers), saturated to i32."""
        c = np.rint(np.asarray(table_mm, dtype=np.float64) / (self.table_nm_per_count * 1e-6))
        return np.clip(c, I32_MIN, I32_MAX).astype(np.int64)

    @property
    def table_resolution_mm(self) -> float:
        return self.table_nm_per_count * 1e-6
