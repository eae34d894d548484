"""The effect families of the gap diagnosis, one module each, as complete plugins.

Each module defines one :class:`~core.gap.families.base.Family` (``FAMILY``): its
documented forms, its round-trip stage factory, its contour piece through the twin
(:mod:`core.sim`), its derived parameters, its identifiability, the observations that
show it, and, where it has one, its refit or fit on contours. ``REGISTRY`` holds them by
name and is keyed by the single effect list, :data:`core.sim.CATEGORIES`; the diagnosis,
the decision and the report reach a family only through it.
"""

from __future__ import annotations

from core.gap.families import (
    backlash_profile,
    compliance,
    cyclic_error,
    friction,
    sampling_skew,
    servo_dynamics,
    thermal,
)
from core.gap.families.base import ContourFit, Family
from core.sim import CATEGORIES

REGISTRY: dict[str, Family] = {m.FAMILY.name: m.FAMILY for m in (friction, compliance, thermal, backlash_profile,
                                                                 cyclic_error, servo_dynamics, sampling_skew)}
if tuple(sorted(REGISTRY)) != tuple(sorted(CATEGORIES)):  # one effect list: the twin's
    raise ImportError(f"gap families {sorted(REGISTRY)} differ from core.sim.CATEGORIES {sorted(CATEGORIES)}")
EFFECTS: tuple[str, ...] = tuple(CATEGORIES)

__all__ = ["EFFECTS", "REGISTRY", "ContourFit", "Family"]
