"""The friction family: friction in the feed chain, as lost motion of a stiff chain or on a
compliant one, refitted on the contours where the round trips took it."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from core.dataset import AxisSpec
from core.gap import contour as ct
from core.gap import roundtrip as rt
from core.gap.families.base import ASSUMED_MASS_KG, ASSUMED_STIFFNESS_N_PER_UM, FRICTION_CHAIN_MIN_MM_S2, Family
from core.gap.stages import GUIDE_DAMPING_PER_S, Stage
from core.sim import AxisModel, Compliance, Friction

NAME = "friction"
PRESLIDING_MIN_UM = 0.5  # the contours' pre-sliding friction form: shorter is the Karnopp form
CHAIN_CT_NAMES = ("chain_frequency_hz", "coulomb_per_mass_mm_s2", "static_excess_per_mass_mm_s2")


def friction_stage() -> Stage:
    """Friction as lost motion of a stiff chain: a break-away threshold (stick until the
    chain's stretch exceeds it, then slip: Karnopp-type static friction), a Stribeck part
    decaying with speed, a viscous part. The Coulomb part of the lost motion is
    inseparable from the backlash on round trips (it is in ``backlash_um``). On contours
    the Coulomb part and the static excess are refitted on the assumed chain, with and
    without pre-sliding (LuGre, a pre-sliding length of 0.5 µm or more; see
    :func:`stiff_on_contours`). Not covered: the chain's own
    dynamics (see :func:`friction_chain_stage`), pre-sliding on round trips (see
    :func:`friction_presliding_stage`), position-dependent friction."""
    return Stage(
        NAME, ("breakaway_lost_motion_um", "stribeck_velocity_mm_s", "viscous_lost_motion_um_per_mm_s"),
        np.array([1.0, 2.0, 0.0]), np.array([0.0, 0.05, 0.0]), np.array([100.0, 20.0, 0.3]), kernel="lost_motion",
        starts=tuple(np.array([ls, vs, cv]) for ls in (1.0, 4.0, 12.0) for vs in (0.5, 3.0) for cv in (0.01, 0.05)),
        info={"form": "lost_motion"},
    )  # fmt: skip


def friction_directional_stage() -> Stage:
    """Friction that differs by direction, on a stiff chain: the lost-motion form with a
    direction asymmetry a, its break-away and Stribeck parts times 1 + a moving in + and
    1 - a in - (the viscous part the same both ways): a wiper or a seal that drags one
    way, a guide preloaded on one side, a table on an incline. Fitted from the
    lost-motion form's values and kept over it only where it cuts that form's train
    misfit by a quarter (``Stage.extends``). A Coulomb level that differs by direction
    is the lost motion of the two directions' mean plus an offset of the table while it
    moves, (F- - F+) / 2k, which the per-run offset takes: what is seen of the asymmetry
    is in the break-away and the Stribeck part (and on contours the same a, on the
    twin's friction). Not covered: a viscous part that differs by direction, on a
    compliant chain or with pre-sliding."""
    base = friction_stage()
    return Stage(
        NAME, base.names + ("direction_asymmetry",), np.append(base.x0, 0.0), np.append(base.lower, -0.9),
        np.append(base.upper, 0.9), kernel="lost_motion", starts=(), info={"form": "lost_motion_directional"},
        derive_starts=_directional_starts, extends="lost_motion",
    )  # fmt: skip


def _directional_starts(prev: Mapping[str, float]) -> tuple[np.ndarray, ...]:
    """Starts from the fitted lost-motion form, the asymmetry either way."""
    if "breakaway_lost_motion_um" not in prev:
        return ()
    p = [prev["breakaway_lost_motion_um"], prev["stribeck_velocity_mm_s"], prev["viscous_lost_motion_um_per_mm_s"]]
    return tuple(np.array(p + [a]) for a in (0.3, -0.3))


def friction_presliding_stage() -> Stage:
    """Friction on a stiff chain with pre-sliding (Dahl): the friction builds over the
    table's travel, df/dx = (1 - f sgn(dx)) / l_p (f the friction over its Coulomb level,
    l_p the pre-sliding length F_c / sigma_0), and the chain's stretch, a Coulomb lost
    motion L_c = 2 F_c / k from one flank's sliding to the other's, balances it (a massless
    table, :func:`core.gap.play.play_dahl`). Where the nut leaves a flank at a reversal the
    chain unloads and the table springs back, while the nut crosses the gap, by
    l_p ln(1 + |f|) (0.69 l_p after steady sliding); on the other flank it moves while the
    friction builds. That is the reversal-phase gap a Coulomb lost motion of a few µm on a
    stiff chain leaves, which neither Karnopp's sticking (the lost motion is then a step,
    inside the apparent backlash) nor a latch skew (a gap that scales with the speed on
    both strokes) follows. ``backlash_um`` is the apparent backlash, gap plus L_c; as
    l_p -> 0 the form is the nominal model. On contours it is the twin's LuGre friction on
    the assumed chain (:func:`sim_piece`), refitted there as the lost-motion form is
    (:func:`stiff_on_contours`). Not covered: a static friction above the Coulomb level,
    a speed-dependent (Stribeck, viscous) part (the lost-motion form has them), the chain's
    own dynamics."""
    return Stage(
        NAME, ("lost_motion_um", "presliding_length_um"), np.array([4.0, 4.0]), np.array([0.0, 0.05]),
        np.array([100.0, 100.0]), kernel="presliding",
        starts=tuple(np.array([lc, lp]) for lc in (2.0, 8.0, 25.0) for lp in (1.0, 4.0, 15.0)),
        info={"form": "presliding"}, diff_step=1e-4,
    )  # fmt: skip


def friction_chain_stage() -> Stage:
    """Friction on a compliant chain (per unit table mass): the table is a mass behind
    the nut's spring-damper, held by Coulomb friction and a static friction above it
    (Karnopp): it sticks until the chain's stretch breaks it away, then slips and rings
    at the chain's frequency; below a critical speed it stick-slips throughout, and with
    the position loop closed on the table scale it hunts about a target (on contours this
    is scored by its envelope, see :mod:`core.gap.contour`). Dahl/LuGre pre-sliding
    (friction building over a few µm) is taken as its Coulomb limit, which the chain's
    own compliance smooths at these stiffnesses. A light guide damping (an oil film,
    ``GUIDE_DAMPING_PER_S``) is fixed. The Coulomb stretch F_c/k is part of the apparent
    backlash (``backlash_um``). Not covered: friction that changes along the travel, a
    second chain resonance, the mass itself (only ratios to it are identifiable), the phase
    of a stick-slip or hunting cycle over seconds (it is fitted and scored on round trips
    by its envelope above 20 Hz, :func:`core.gap.roundtrip.residual_env_um`). The Coulomb part is at
    least ``FRICTION_CHAIN_MIN_MM_S2`` (0.05 g): a chain held by less is a compliant chain
    with its normal rolling-guide friction (the compliance family), which this form would
    otherwise also fit, by its static part, better than compliance's own form (a hunting
    two-mass chain). Its damping is not held above the position loop's linear stability
    floor (:func:`core.gap.families.compliance.loop_damping_floor`, which the compliance
    form keeps): Coulomb and static friction bound a chain's oscillation, so a linearly
    unstable loop with them is a bounded hunting cycle, which this form is meant to
    follow, and a floor would keep it from a Karnopp chain that hunts. It contains
    compliance's form: with no static excess and its Coulomb part at the boundary it is
    a compliant chain with guide friction, so it is named over compliance only where the
    held-out runs tell the two apart and its own parameters are identifiable
    (``Stage.contains``)."""
    return Stage(
        NAME, ("chain_frequency_hz", "chain_damping_ratio", "coulomb_per_mass_mm_s2", "static_excess_per_mass_mm_s2",
                     "stick_band_mm_s"),
        np.array([40.0, 0.1, 1000.0, 1000.0, 0.3]), np.array([5.0, 0.01, FRICTION_CHAIN_MIN_MM_S2, 0.0, 0.0]),
        np.array([200.0, 1.0, 20000.0, 40000.0, 5.0]), kernel="friction_chain",
        starts=tuple(np.array([fn, 0.1, mu, ex * mu, 0.5]) for fn in (25.0, 80.0) for mu in (600.0, 2000.0)
                     for ex in (0.5, 2.0)),
        info={"form": "chain"}, derive_starts=_chain_starts_from_lost_motion, max_nfev=40, contains=("compliance",),
    )  # fmt: skip


def _chain_starts_from_lost_motion(prev: Mapping[str, float]) -> tuple[np.ndarray, ...]:
    """Chain starts from a fitted lost-motion form: its break-away lost motion L_s is the
    static excess's stretch, (mu_s - mu_c) / w^2; the Coulomb stretch is inside its backlash."""
    ls = prev.get("breakaway_lost_motion_um")
    if ls is None:
        return ()
    out = []
    for fn in (40.0, 100.0):
        w2 = (2 * np.pi * fn) ** 2
        for mu in (600.0, 2000.0):
            out.append(np.array([fn, 0.1, mu, max(1e-3 * ls * w2, 10.0), 0.5]))
    return tuple(out)


def sim_piece(p: Mapping[str, float], info: Mapping, axis: AxisSpec, b_um: float) -> tuple[object | None, float]:
    if info.get("form") == "chain":
        w = 2 * math.pi * p["chain_frequency_hz"]
        m = ASSUMED_MASS_KG  # every force scales with it: any mass gives the same motion
        mu, ex = p["coulomb_per_mass_mm_s2"], p["static_excess_per_mass_mm_s2"]
        comp = Compliance(stiffness_n_per_um=w * w * m * 1e-6, table_mass_kg=m, damping_ratio=p["chain_damping_ratio"],
                          guide_damping_n_s_per_mm=GUIDE_DAMPING_PER_S * m * 1e-3)  # fmt: skip
        # the round trips' stick band too: one parameter set for both
        fr = Friction(coulomb_n=mu * m * 1e-3, static_n=(mu + ex) * m * 1e-3, stribeck_velocity_mm_s=0.1,
                      stick_band_mm_s=p.get("stick_band_mm_s", 0.0))  # fmt: skip
        return [("compliance", comp), ("friction", fr)], 2e3 * mu / (w * w)
    k = ASSUMED_STIFFNESS_N_PER_UM
    if info.get("form") == "presliding":  # LuGre on the assumed chain: F_c = k L_c / 2, sigma_0 = F_c / l_p
        coulomb_um = min(0.5 * p["lost_motion_um"], 0.45 * b_um)
        fr = Friction(coulomb_n=max(coulomb_um * k, 1e-6), model="lugre",
                      bristle_stiffness_n_per_um=max(coulomb_um * k, 1e-6) / max(p["presliding_length_um"], 0.05))
        return fr, 2 * coulomb_um
    coulomb_um = min(4.0 * p["breakaway_lost_motion_um"], 0.45 * b_um)  # static = 1.25 Coulomb assumed
    fr = Friction(coulomb_n=coulomb_um * k, static_n=(coulomb_um + p["breakaway_lost_motion_um"]) * k,
                  stribeck_velocity_mm_s=p["stribeck_velocity_mm_s"],
                  viscous_n_s_per_mm=p["viscous_lost_motion_um_per_mm_s"] * k,
                  direction_asymmetry=p.get("direction_asymmetry", 0.0))  # fmt: skip
    return fr, 2 * coulomb_um


def derived(params: Mapping[str, float], b_um: float) -> dict[str, float]:
    if "chain_frequency_hz" in params:
        w2 = (2 * math.pi * params["chain_frequency_hz"]) ** 2
        return {"coulomb_lost_motion_um": 2e3 * params["coulomb_per_mass_mm_s2"] / w2,
                "breakaway_excess_um": 1e3 * params["static_excess_per_mass_mm_s2"] / w2}  # fmt: skip
    if "presliding_length_um" in params:  # the spring-back at a reversal after steady sliding
        return {"reversal_spring_back_um": math.log(2.0) * params["presliding_length_um"]}
    return {"static_excess_n_at_200n_per_um": params["breakaway_lost_motion_um"] * ASSUMED_STIFFNESS_N_PER_UM}


# ---- the refit on contours ----------------------------------------------------------


def refit_on_contours(d, a: str, af, pieces: dict, bl: dict):
    """Friction of axis ``a`` refitted on the train contours: the chain form's refit when
    the round trips took it and the contours carry fast motion, else the stiff form's
    (Karnopp or pre-sliding) and, with fast motion, the same friction on a chain, the
    better kept. Returns (the effects it sets by name, the backlash it accounts for in
    µm, its parameters)."""
    b_rt = float(af.fit.theta[0])
    if not d.ct_shows.get(a, True):  # nothing on the train contours to refit on
        return {"friction": pieces[a].friction, "compliance": pieces[a].compliance}, b_rt - bl[a], {}
    fast = d.fast_motion.get(a, False)
    if fast and any(st.kernel == "friction_chain" for st in af.stages):
        fx, b_sim, th = chain_on_contours(d, a, pieces, b_rt, dict(zip(af.model.names, af.fit.theta)))
        return ({"compliance": fx.compliance, "friction": fx.friction}, b_rt - b_sim,
                {f"contour_{n}": float(v) for n, v in zip(CHAIN_CT_NAMES, th)})  # fmt: skip
    fr, b_sim = stiff_on_contours(d, a, pieces, bl, b_rt)
    stiff = pieces[a].with_effect("friction", fr)
    if fast:  # the same friction on a chain of its own frequency (the assumed chain as the start)
        k, m = ASSUMED_STIFFNESS_N_PER_UM, ASSUMED_MASS_KG
        start = {"chain_frequency_hz": math.sqrt(k * 1e6 / m) / (2 * math.pi), "chain_damping_ratio": 0.2,
                 "coulomb_per_mass_mm_s2": max(fr.coulomb_n / m * 1e3, 1.2 * FRICTION_CHAIN_MIN_MM_S2),
                 "static_excess_per_mass_mm_s2": max((fr.static_n - fr.coulomb_n) / m * 1e3, 50.0)}  # fmt: skip
        fx_c, b_c, th = chain_on_contours(d, a, pieces, b_rt, start)
        if axis_envelope_cost(d, a, fx_c, b_c) < axis_envelope_cost(d, a, stiff, b_sim):
            return ({"compliance": fx_c.compliance, "friction": fx_c.friction}, b_rt - b_c,
                    {f"contour_{n}": float(v) for n, v in zip(CHAIN_CT_NAMES, th)})  # fmt: skip
    params = {"coulomb_lost_motion_um": fr.coulomb_n / ASSUMED_STIFFNESS_N_PER_UM,
              "static_to_coulomb": fr.static_n / max(fr.coulomb_n, 1e-9)}  # fmt: skip
    if fr.model == "lugre":  # the pre-sliding form was kept
        params["presliding_um"] = fr.coulomb_n / fr.bristle_stiffness_n_per_um
    return {"friction": fr}, b_rt - b_sim, params


def axis_envelope_cost(d, a: str, fx, b_um: float) -> float:
    """Envelope-scored tracking RSS of axis ``a`` on the train contours for effects ``fx``."""
    m = AxisModel.from_axis_spec(d.axes[a], max(0.0, b_um), effects=fx)
    return sum(float(np.sum(ct.tracking_envelope_residual_um(c, {a: d.memo.axis(c, a, m)}, [a]) ** 2))
               for c in d.train_ct if a in c.axes)  # fmt: skip


def chain_on_contours(d, a: str, pieces: dict, b_rt_um: float, vals: Mapping[str, float]):
    """Friction on a compliant chain on contours: the chain frequency, Coulomb and static
    friction (per unit mass) refitted on the train contours of axis ``a``, starting from
    the round trips' values, scored by :func:`core.gap.contour.envelope_residual_um` (a
    table that stick-slips or hunts with the loop closed on it is matched by the
    amplitude and frequency of that motion, not its phase). Returns (Effects, backlash
    for the twin, fitted (f_n, mu_c, mu_s - mu_c))."""
    mine = [c for c in d.train_ct if a in c.axes]
    spec = d.axes[a]
    info = {"form": "chain"}
    zeta = vals["chain_damping_ratio"]
    band = vals.get("stick_band_mm_s", 0.0)  # the round trips' (none from the lost-motion form)

    def make(th):
        p = {"chain_frequency_hz": th[0], "chain_damping_ratio": zeta, "coulomb_per_mass_mm_s2": th[1],
             "static_excess_per_mass_mm_s2": th[2], "stick_band_mm_s": band}  # fmt: skip
        piece, b_share = sim_piece(p, info, spec, b_rt_um)
        fx = pieces[a]
        for name, pc in piece:
            fx = fx.with_effect(name, pc)
        return fx, max(0.0, b_rt_um - b_share)

    def res(th):
        fx, b = make(th)
        m = AxisModel.from_axis_spec(spec, b, effects=fx)
        sims = d.in_threads([lambda c=c: d.memo.axis(c, a, m) for c in mine])
        return np.concatenate([ct.tracking_envelope_residual_um(c, {a: sim}, [a], stacked=True)
                               for c, sim in zip(mine, sims)])  # fmt: skip

    x0 = np.array([vals["chain_frequency_hz"], vals["coulomb_per_mass_mm_s2"], vals["static_excess_per_mass_mm_s2"]])
    starts = [x0 * np.array([fm, 1.0, em]) for fm in (1.0, 2.0) for em in (1.0, 3.0, 6.0)]
    lo, hi = np.array([5.0, FRICTION_CHAIN_MIN_MM_S2, 0.0]), np.array([300.0, 20000.0, 40000.0])
    r = rt.fit_ls(res, starts, lo, hi, n_starts=1, max_nfev=12, diff_step=0.05)
    fx, b = make(r.theta)
    return fx, b, r.theta


def stiff_on_contours(d, a: str, pieces: dict, bl: dict, b_rt_um: float):
    """Friction on contours, fitted on the train contours' tracking error of axis ``a``:
    the Coulomb lost motion (which round trips cannot separate from the backlash) and
    the static excess, on the assumed chain; the round trips' Stribeck velocity and
    viscous part are kept. Two forms, the one that fits the train contours better is
    kept:

    * Karnopp (stick until the static friction breaks, then the Stribeck curve), as
      the round trips' lost-motion form;
    * the same with **pre-sliding** (LuGre: the friction force builds over a
      pre-sliding length lp = F_c / sigma_0 of elastic micro-motion before gross
      sliding, as Dahl's and LuGre's bristles do). After a reversal of a contour the
      table creeps back through lp while the force turns over, instead of sticking and
      breaking away: on the twin's LuGre friction (lp 5-60 µm) the Karnopp form leaves
      the contours' gap about as it is (1.44 -> 1.36 µm on one) where the pre-sliding
      form with the true values leaves 0.40 µm. On round trips lp shows as
      the table's spring-back at a reversal where the chain is stiff
      (:func:`friction_presliding_stage`, whose lp starts this form when it was taken).

    Returns (Friction, backlash for the twin)."""
    base = pieces[a].friction
    k = ASSUMED_STIFFNESS_N_PER_UM
    mine = [c for c in d.train_ct if a in c.axes]
    spec = d.axes[a]

    def make(th):
        lc, ex = float(th[0]), float(th[1])
        pre = {} if len(th) < 3 else {"model": "lugre", "bristle_stiffness_n_per_um": lc * k / float(th[2])}
        fr = Friction(coulomb_n=lc * k, static_n=(lc + ex) * k, stribeck_velocity_mm_s=base.stribeck_velocity_mm_s,
                      viscous_n_s_per_mm=base.viscous_n_s_per_mm, direction_asymmetry=base.direction_asymmetry,
                      **pre)  # fmt: skip
        return fr, max(0.0, b_rt_um - 2 * lc)

    def res(th):
        fr, b = make(th)
        m = AxisModel.from_axis_spec(spec, b, effects=pieces[a].with_effect("friction", fr))
        sims = d.in_threads([lambda c=c: d.memo.axis(c, a, m) for c in mine])
        return np.concatenate([(c.table_mm[a][c.fit_idx] - sim[c.fit_idx]) * 1e3 for c, sim in zip(mine, sims)])

    hi = max(0.45 * b_rt_um, 0.2)
    x0 = np.array([base.coulomb_n / k, (base.static_n - base.coulomb_n) / k])
    starts = [x0, np.array([0.1 * hi, 2.0]), np.array([0.5 * hi, 0.3 * hi])]
    # pre-sliding: lp from PRESLIDING_MIN_UM (stiffer bristles are the Karnopp form) to the
    # apparent backlash; six starts spread over the Coulomb share and lp, the best pursued
    lp_hi = max(b_rt_um, 2 * PRESLIDING_MIN_UM)
    p_starts = [np.array([f_lc * hi, 2.0, min(f_lp * hi, 0.9 * lp_hi)]) for f_lc in (0.25, 0.6)
                for f_lp in (0.25, 0.6, 1.2)]  # fmt: skip
    if base.model == "lugre":  # the round trips' pre-sliding form: its Coulomb part and length
        p_starts.append(np.array([min(base.coulomb_n / k, 0.9 * hi), 0.0,
                                  min(max(base.coulomb_n / base.bristle_stiffness_n_per_um, PRESLIDING_MIN_UM),
                                      0.9 * lp_hi)]))  # fmt: skip
    # Coulomb friction of at least 2 % of the assumed table's weight: below, the twin's
    # table bounces across the backlash in a limit cycle (core.sim.Friction), which a fit
    # to slow train contours can pick and fast test contours then show
    lc_lo = min(0.02 * 9.81 * ASSUMED_MASS_KG / k, 0.5 * hi)
    # the two forms' fits are independent: side by side
    r, rp = d.in_threads([
        lambda: rt.fit_ls(res, starts, np.array([0.0, 0.0]), np.array([hi, 150.0]), n_starts=1, max_nfev=12,
                          diff_step=1e-2),
        lambda: rt.fit_ls(res, p_starts, np.array([lc_lo, 0.0, PRESLIDING_MIN_UM]), np.array([hi, 150.0, lp_hi]),
                          n_starts=1, max_nfev=15, diff_step=1e-2),
    ])  # fmt: skip
    # kept when it fits better with a pre-sliding length off its lower bound (at the bound
    # it is the Karnopp form, fitted above)
    presliding = rp.rss < r.rss and rp.theta[2] > 1.01 * PRESLIDING_MIN_UM
    return make(rp.theta if presliding else r.theta)


# static friction above the Coulomb level holds a table at rest and lets it jump; below
# its critical speed it sticks and slips out and back alike
# the form that differs by direction last: the chain's derived starts read the lost-motion
# form's values, its own too
FAMILY = Family(NAME, "\n".join(f.__doc__ for f in (friction_stage, friction_presliding_stage, friction_chain_stage,
                                                     friction_directional_stage)),
                lambda runs, axis, resid: (friction_stage(), friction_presliding_stage(), friction_chain_stage(),
                                           friction_directional_stage()),
                sim_piece=sim_piece,
                derived=derived, shown_by=("breakaway", "stick_slip"), contour_refit=refit_on_contours)  # fmt: skip
