"""The interface of an effect family (:class:`Family`) and what the families share.

A family is a set of physical forms of one effect (:data:`core.sim.CATEGORIES`), a
complete plugin of the gap diagnosis: the diagnosis (:mod:`core.gap.diagnose`) reaches a
family only through :data:`core.gap.families.REGISTRY` and these hooks.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

NOT_IDENTIFIABLE = "not identifiable"
ASSUMED_MASS_KG = 500.0  # to express a fitted natural frequency as a chain stiffness
ASSUMED_STIFFNESS_N_PER_UM = 200.0  # to express friction lost motion as a force
# Coulomb friction per unit mass that separates a friction effect from a compliant chain's
# own guide friction: 0.05 g. Rolling guides with their seals run at 0.002-0.05 g (part of
# a healthy chain, the compliance family); sliding guides, or rolling ones run dry, seized
# or over-preloaded, at 0.05-0.2 g and more, with stick-slip (the friction family).
FRICTION_CHAIN_MIN_MM_S2 = 0.05 * 9810.0


def no_piece(params: Mapping[str, float], info: Mapping, axis, b_um: float) -> tuple[object | None, float]:
    return None, 0.0


def no_derived(params: Mapping[str, float], b_um: float) -> dict[str, float]:
    return {}


@dataclass(frozen=True)
class ContourFit:
    """A family fitted on the train contours alone (it leaves the round trips' table given
    the motor unchanged): its parameters, their bounds, the fit and the twin's effect."""

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    # (diagnosis, backlash by axis µm, the other effects by axis) -> {axis: FitResult}
    fit: Callable
    piece: Callable  # (values by name) -> the twin's effect
    gain: str | None = None  # the parameter that is the axis' effective position gain, if any


@dataclass(frozen=True)
class Family:
    """One effect family.

    ``forms``: the physics its forms cover and do not cover. ``stage``: (train round trips
    of an axis, the axis' spec, the reference model's train residuals) -> a
    :class:`core.gap.stages.Stage`, a tuple of alternative forms (each fitted, the best
    taken), or None where the round trips cannot show it (``no_stage_reason`` says why);
    ``stage`` None: the family is fitted on contours only (``contour_fit``).
    ``sim_piece``: (fitted round-trip parameters without axis prefix, the stage's info,
    the axis' spec, the round trips' backlash µm) -> (the twin's effect, or a list of
    (effect name, effect) pairs, or None; the backlash it accounts for itself, µm).
    ``derived``: (fitted values of the axis' composed model, its backlash µm) -> derived
    parameters by name. ``identifiable``: (diagnosis, fitted candidate whose last effect is
    this family) -> (whether its parameters are identifiable, a note or None).
    ``shown_by``: the observations (:data:`core.gap.evidence.KINDS`) this family's physics
    produces, evidence for it. ``contour_refit``: (diagnosis, axis, the axis' round-trip
    fit, effects by axis, backlash by axis) -> (the twin's effects it sets by name, the
    backlash it accounts for µm, its contour parameters by name): the family's parameters
    refitted on the train contours of an axis whose round trips took it."""

    name: str
    forms: str
    stage: Callable | None
    sim_piece: Callable = no_piece
    derived: Callable = no_derived
    shown_by: tuple[str, ...] = ()
    identifiable: Callable | None = None
    no_stage_reason: str = "the train round trips cannot show it"
    contour_refit: Callable | None = None
    contour_fit: ContourFit | None = None
