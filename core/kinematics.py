"""Feed-drive kinematics: the transmission ratio k_a and travel conversions.

k_a is the table travel per motor revolution (mm/rev). For the paper's Y axis
(Table 1) a two-stage gearbox 24/31, 31/56 drives a 16 mm lead screw:
k_a = 16 * (24/31) * (31/56) = 6.857 mm/rev.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from core.errors import InputError, require_positive


def transmission_mm_per_rev(screw_lead_mm: float, gear_teeth: Sequence[int] = ()) -> float:
    """k_a from the screw lead and gear teeth given as (driver, driven) pairs in order.

    ``gear_teeth`` is flat: (z1, z2, z3, z4, ...) where z1 drives z2, z3 drives z4.
    An empty sequence means the motor drives the screw directly.
    """
    lead = require_positive("screw_lead_mm", screw_lead_mm)
    teeth = list(gear_teeth)
    if len(teeth) % 2:
        raise InputError(f"gear_teeth must come in (driver, driven) pairs, got {len(teeth)} values")
    ratio = 1.0
    for i in range(0, len(teeth), 2):
        z_drive = require_positive(f"gear_teeth[{i}]", teeth[i])
        z_driven = require_positive(f"gear_teeth[{i + 1}]", teeth[i + 1])
        ratio *= z_drive / z_driven
    return lead * ratio


def nominal_travel_mm(motor_rev: np.ndarray | float, transmission: float) -> np.ndarray:
    """Nominal table travel l_0 = k_a x_m (mm) for motor position(s) in revolutions."""
    return np.asarray(motor_rev, dtype=float) * require_positive("transmission_mm_per_rev", transmission)


def motor_rev_for_travel(travel_mm: np.ndarray | float, transmission: float) -> np.ndarray:
    """Motor revolutions that give a nominal table travel (inverse of :func:`nominal_travel_mm`)."""
    return np.asarray(travel_mm, dtype=float) / require_positive("transmission_mm_per_rev", transmission)
