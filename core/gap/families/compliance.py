"""The compliance family: the table as a mass behind an elastic chain."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from core.dataset import AxisSpec
from core.gap.families.base import ASSUMED_MASS_KG, FRICTION_CHAIN_MIN_MM_S2, Family
from core.gap.stages import Stage
from core.sim import Compliance

NAME = "compliance"
GUIDE_FRICTION_PRIOR_MM_S2 = 196.0
GUIDE_FRICTION_PRIOR_WEIGHT = 100.0
# Weight of the penalty that keeps the compliance form's fitted damping above the floor at
# which the position loop, closed on the table through that chain, is stable
# (:func:`loop_damping_floor`; the friction chain has none, see its docstring), in µm of
# residual per unit relative shortfall of the damping ratio.
LOOP_STABILITY_WEIGHT = 1e4


def loop_damping_floor(gain_per_s: float, omega: float, guide_per_s: float) -> float:
    """The smallest chain damping ratio at which the position loop, closed on the table
    through the chain, is stable: per unit table mass, with an ideal velocity loop and the
    nut in contact, ``x'' = w^2 (u - x) + 2 zeta w (u' - x') - g x'`` and ``u' = K (c - x)``
    give ``s^3 + (2 zeta w + g) s^2 + (w^2 + 2 zeta w K) s + K w^2``, stable (Routh-Hurwitz)
    when ``(2 zeta w + g)(w^2 + 2 zeta w K) > K w^2``, about ``zeta > (K - g) / (2 w)``.
    A machine that makes parts has a stable loop (it may still hunt through its backlash, a
    bounded cycle); the round trips, driven by the recorded motor, cannot tell, and a chain
    fitted below this floor makes the closed-loop contour simulation grow without bound
    (a 32.6 Hz chain at zeta 0.02 without guide damping does so at K 32/s)."""
    k, w, g = gain_per_s, omega, guide_per_s
    if k <= 0.0 or g >= k:
        return 0.0
    # K z^2 + (w^2 + g K) z + (g - K) w^2 = 0 for z = 2 zeta w
    b = w * w + g * k
    z = (-b + math.sqrt(b * b - 4.0 * k * (g - k) * w * w)) / (2.0 * k)
    return max(0.0, z / (2.0 * w))


def _stability_penalty(gain_per_s: float | None, fn: float, zeta: float, guide_per_s: float) -> float:
    if not gain_per_s:
        return 0.0
    floor = loop_damping_floor(gain_per_s, 2 * math.pi * fn, guide_per_s)
    return LOOP_STABILITY_WEIGHT * max(0.0, floor - zeta) / floor if floor > 0.0 else 0.0


def compliance_stage(gain_per_s: float | None = None) -> Stage:
    """The table as a mass on a spring-damper behind the nut, held by guide damping and
    Coulomb guide friction (per unit mass): lag proportional to acceleration, ringing
    after acceleration changes, the table floating across the backlash when braking. A
    two-mass chain (motor and table inertias) shows the same first mode; driven by the
    recorded motor, the motor inertia's share is in the record. A chain that hunts with
    the loop closed on the table is matched by its envelope above 20 Hz (fitted and scored
    on :func:`core.gap.roundtrip.residual_env_um`), not its phase. Not covered: a second
    resonance, stiffness that changes along the travel, a hunting cycle whose amplitude
    depends on the loop (the recorded motor carries it, the model does not close it).
    The damping is held above the floor at which the position loop, closed on the table
    through this chain, is stable (a penalty, :func:`loop_damping_floor`).

    The fit: the train cost of a table that rattles across the backlash is rough at small
    parameter steps (each rattle is an event), so at scipy's default finite-difference
    step (~1e-8) the gradients read 1e8-1e10 and the trust region stops on its start
    point after two evaluations. It steps by 1 % (``diff_step``), from 16 starts of
    frequency, damping and guide friction, each with the nominal backlash, twice and four
    times it (a table that floats across the gap makes the nominal fit take the
    clearance for smaller than it is: 22 µm for 101 µm on one such chain); the two
    cheapest are refined, at most 12 evaluations each (``max_nfev``; the Jacobian's not
    counted).
    Fitted on top of a base (a second effect), every start begins with the base's fitted
    values (the backlash not multiplied), only the cheapest start is refined, and at
    scipy's default step (``core.gap.diagnose._Diagnosis.fit_candidate``: a 1 % step over
    a base's parameters doubles the diagnosis' time)."""
    return Stage(
        NAME, ("natural_frequency_hz", "damping_ratio", "guide_damping_per_s", "guide_friction_mm_s2"),
        np.array([60.0, 0.3, 5.0, 300.0]), np.array([3.0, 0.02, 0.0, 0.0]),
        np.array([300.0, 2.0, 200.0, FRICTION_CHAIN_MIN_MM_S2]),
        kernel="compliant_chain",
        prior=lambda th: np.array([GUIDE_FRICTION_PRIOR_WEIGHT * math.log(max(th[3], 1.0) / GUIDE_FRICTION_PRIOR_MM_S2),
                                   _stability_penalty(gain_per_s, th[0], th[1], th[2])]),
        starts=tuple(np.array([fn, z, g, mu]) for fn in (15.0, 30.0, 60.0, 120.0) for z in (0.12, 0.3)
                     for g, mu in ((2.0, 100.0), (10.0, 450.0))),
        backlash_factors=(1.0, 2.0, 4.0), diff_step=0.01, max_nfev=12,
    )  # fmt: skip



def sim_piece(p: Mapping[str, float], info: Mapping, axis: AxisSpec, b_um: float) -> tuple[object | None, float]:
    w = 2 * math.pi * p["natural_frequency_hz"]
    m = ASSUMED_MASS_KG  # every force scales with it: any mass gives the same motion
    mu = p["guide_friction_mm_s2"]
    comp = Compliance(stiffness_n_per_um=w * w * m * 1e-6, table_mass_kg=m, damping_ratio=p["damping_ratio"],
                      guide_damping_n_s_per_mm=p["guide_damping_per_s"] * m * 1e-3,
                      guide_friction_n=mu * m * 1e-3)  # fmt: skip
    return comp, 2e3 * mu / (w * w)


def derived(params: Mapping[str, float], b_um: float) -> dict[str, float]:
    w2 = (2 * math.pi * params["natural_frequency_hz"]) ** 2
    return {"m_over_k_ms2": 1e6 / w2, "clearance_um": max(0.0, b_um - 2e3 * params["guide_friction_mm_s2"] / w2)}


# a compliant chain whose loop is closed through it hunts: a self-excited cycle a stroke
# falls into or not, in one direction only
FAMILY = Family(NAME, compliance_stage.__doc__, lambda runs, axis, resid: compliance_stage(axis.position_gain_per_s),
                sim_piece=sim_piece, derived=derived, shown_by=("hunting",))  # fmt: skip
