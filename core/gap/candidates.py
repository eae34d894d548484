"""The candidate effects of the gap diagnosis, by name: the families' registry and the
round-trip machinery under the names the diagnosis' callers import.

Each family is a set of physical forms, not one equation, and lives in its own module of
:mod:`core.gap.families` (its forms, round-trip stage, contour piece, derived parameters,
identifiability, observations and contour refit); :mod:`core.gap.stages` holds what
they share (:class:`Stage`, :func:`compose`, :func:`stage_starts`). ``REGISTRY`` is keyed
by the single effect list, :data:`core.sim.CATEGORIES`. docs/gap-diagnosis.md lists each
family's forms with the benchmark figures.
"""

from __future__ import annotations

from collections.abc import Mapping

from core.dataset import AxisSpec
from core.gap.families import EFFECTS, REGISTRY, ContourFit, Family
from core.gap.families.backlash_profile import (N_KNOTS, PROFILE_KNOT_SPACING_MM, PROFILE_MAX_KNOTS,
                                                PROFILE_SMOOTHNESS_WEIGHT, profile_knots, profile_stage)
from core.gap.families.base import (ASSUMED_MASS_KG, ASSUMED_STIFFNESS_N_PER_UM, FRICTION_CHAIN_MIN_MM_S2,
                                    NOT_IDENTIFIABLE)
from core.gap.families.compliance import (GUIDE_FRICTION_PRIOR_MM_S2, GUIDE_FRICTION_PRIOR_WEIGHT,
                                          LOOP_STABILITY_WEIGHT, compliance_stage, loop_damping_floor)
from core.gap.families.cyclic_error import N_PERIODS, cyclic_stage
from core.gap.families.friction import friction_chain_stage, friction_stage
from core.gap.families.sampling_skew import skew_stage
from core.gap.families.servo_dynamics import SERVO_FORMS, SERVO_LOWER, SERVO_NAMES, SERVO_UPPER, fit_servo, servo_piece
from core.gap.families.thermal import thermal_stage
from core.gap.stages import (ENVELOPE_KERNELS, FREE_START_KERNELS, GUIDE_DAMPING_PER_S, SMOOTH_POSITION_S,
                             SMOOTH_VELOCITY_S, Stage, compose, smooth_u, stage_starts, train_residuals)

__all__ = [
    "ASSUMED_MASS_KG", "ASSUMED_STIFFNESS_N_PER_UM", "EFFECTS", "ENVELOPE_KERNELS", "FREE_START_KERNELS",
    "FRICTION_CHAIN_MIN_MM_S2", "GUIDE_DAMPING_PER_S", "GUIDE_FRICTION_PRIOR_MM_S2", "GUIDE_FRICTION_PRIOR_WEIGHT",
    "LOOP_STABILITY_WEIGHT", "NOT_IDENTIFIABLE", "N_KNOTS", "N_PERIODS", "PROFILE_KNOT_SPACING_MM",
    "PROFILE_MAX_KNOTS", "PROFILE_SMOOTHNESS_WEIGHT", "REGISTRY", "SERVO_FORMS", "SERVO_LOWER", "SERVO_NAMES",
    "SERVO_UPPER", "SMOOTH_POSITION_S", "SMOOTH_VELOCITY_S", "ContourFit", "Family", "Stage", "compliance_stage",
    "compose", "cyclic_stage", "derived", "fit_servo", "friction_chain_stage", "friction_stage", "loop_damping_floor",
    "profile_knots", "profile_stage", "servo_piece", "sim_piece", "skew_stage", "smooth_u", "stage_starts",
    "thermal_stage", "train_residuals",
]  # fmt: skip


def sim_piece(effect: str, params: Mapping[str, float], info: Mapping, axis: AxisSpec,
              b_um: float) -> tuple[object | None, float]:
    """The twin's effect for fitted round-trip parameters of ``effect`` (names without the
    axis prefix), and how much of the round-trip backlash it accounts for itself (µm):
    the family's :attr:`Family.sim_piece`."""
    fam = REGISTRY.get(effect)
    return fam.sim_piece(params, info, axis, b_um) if fam is not None else (None, 0.0)


def derived(effect: str, params: Mapping[str, float], b_um: float) -> dict[str, float]:
    """Parameters derived from a fit, in the units an engineer asks for: the family's
    :attr:`Family.derived`."""
    fam = REGISTRY.get(effect)
    return fam.derived(params, b_um) if fam is not None else {}
