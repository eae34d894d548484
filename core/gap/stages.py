"""The round-trip model's shared machinery: a family's :class:`Stage` and their composition.

A stage is one effect family's part of a composed round-trip model (table given motor):
a map of the nut travel, of the backlash half-width, a dynamic kernel that replaces the
play operator, or a map of the recorded table. :func:`compose` builds one model from the
nominal backlash and any stages (at most one kernel); :func:`stage_starts` gives its
start points. The families (:mod:`core.gap.families`) make the stages.

Kernels (``Stage.kernel``):

* ``"lost_motion"``: the play operator with a speed-dependent lost motion and a
  break-away threshold, parameters (break-away lost motion µm, Stribeck velocity mm/s,
  viscous lost motion µm per mm/s) and, in the form that differs by direction, a fourth,
  the direction asymmetry a (the break-away and Stribeck parts times 1 + a moving in +,
  1 - a in -);
* ``"presliding"``: the play operator with Dahl pre-sliding friction on a stiff chain,
  parameters (Coulomb lost motion µm, pre-sliding length µm); ``backlash_um`` is the
  apparent backlash (the gap plus the Coulomb lost motion);
* ``"friction_chain"``: the table as a mass behind the nut's spring-damper, held by
  Coulomb and static friction, parameters (frequency Hz, damping ratio, Coulomb and static
  excess per unit mass mm/s², stick band mm/s), with a fixed guide damping
  (``GUIDE_DAMPING_PER_S``) and the nut's start place chosen per run (:func:`_free_start`);
* ``"compliant_chain"``: the same mass-spring-damper with guide damping and Coulomb guide
  friction, parameters (frequency Hz, damping ratio, guide damping 1/s, guide friction
  per unit mass mm/s²).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from core.gap.data import RoundTrip
from core.gap.play import play, play_dahl, play_friction, play_inertia
from core.gap.roundtrip import (ENVELOPE_WINDOW_S, TRAIN_ENVELOPE_WINDOWS_S, RTModel, residual_env_um, residual_um,
                                run_choices)

# a family's form that extends another of its forms is kept over it where it cuts that
# form's train RSS by at least this share (as an effect is named where it cuts the gap by
# the decision's min_reduction, 0.25 by default)
NESTED_MIN_CUT = 0.25
GUIDE_DAMPING_PER_S = 1.0  # friction on a chain: a light oil-film damping of the table (1/s)
# kernels of a chain's dynamics: fitted and scored on round trips by envelope above 20 Hz
# (roundtrip.residual_env_um), as a stick-slipping or hunting chain's phase is not reproducible
ENVELOPE_KERNELS = ("friction_chain", "compliant_chain")
# Savitzky-Golay windows (order 2) of the motor record driving a chain kernel, so the
# motor encoder's noise, differentiated, does not drive the chain. 16 ms keeps 99 % of
# 25 Hz but cuts above ~60 Hz, where the chains ring: a rattle the motor record carries
# is then not started in the model (a known limit, docs/gap-diagnosis.md §8).
SMOOTH_POSITION_S = 0.016
SMOOTH_VELOCITY_S = 0.03


@dataclass(frozen=True)
class Stage:
    """One effect's part of a composed round-trip model (parameters without axis prefix)."""

    effect: str
    names: tuple[str, ...]
    x0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    info: dict = field(default_factory=dict)
    u_map: Callable | None = None  # (theta, run, u) -> u
    width: Callable | None = None  # (theta, run, u, hb) -> hb   (mm)
    kernel: str | None = None  # "lost_motion" | "presliding" | "friction_chain" | "compliant_chain"
    out_map: Callable | None = None  # (theta, run, x) -> x
    prior: Callable | None = None  # theta -> extra residuals
    starts: tuple[np.ndarray, ...] = ()
    # starts derived from the fitted values of the family's forms fitted before it
    derive_starts: Callable | None = None  # (values by name) -> tuple of starts
    max_nfev: int | None = None  # cap on the fit's evaluations (a costly kernel)
    # the fit's relative finite-difference step (None: scipy's default, ~1e-8), for a
    # kernel whose cost is rough at small steps
    diff_step: float | None = None
    # start values of the backlash, as factors of the nominal one (a stage that changes
    # what the nominal fit takes for backlash)
    backlash_factors: tuple[float, ...] = (1.0,)
    # the families whose forms this form contains (it reduces to them at some parameter
    # values): the decision names it over them only where the held-out runs tell the two
    # apart and its own parameters are identifiable (core.gap.select, parsimony)
    contains: tuple[str, ...] = ()
    # the form of the same family this one extends by more parameters (its ``info["form"]``):
    # fitted from that form's values and kept over it only where it cuts that form's train
    # RSS by NESTED_MIN_CUT (core.gap.diagnose), so that an extra parameter the train runs
    # hardly need is never taken, however little the BIC charges for it
    extends: str | None = None


# ---- composition ------------------------------------------------------------------


def _speed_mm_s(run: RoundTrip) -> np.ndarray:
    n = max(1, int(round(0.01 / run.dt_s)))
    u = run.u_mm
    if n > 1:
        k = np.ones(n) / n
        u = np.convolve(np.pad(u, (n // 2, n - 1 - n // 2), mode="edge"), k, mode="valid")
    return np.abs(np.gradient(u, run.t_s))


def smooth_u(run: RoundTrip, memo: dict) -> tuple[np.ndarray, np.ndarray]:
    """Nut travel and velocity with the motor encoder noise averaged out (Savitzky-Golay),
    kept in the diagnosis' memo."""
    key = ("smooth", run.file)
    hit = memo.get(key)
    if hit is not None:
        return hit
    u = run.u_mm
    n = 2 * int(round(SMOOTH_POSITION_S / run.dt_s / 2)) + 1
    nv = 2 * int(round(SMOOTH_VELOCITY_S / run.dt_s / 2)) + 1
    us = savgol_filter(u, n, 2) if 5 <= n < u.size else u
    vs = savgol_filter(u, nv, 2, deriv=1, delta=run.dt_s) if 5 <= nv < u.size else np.gradient(u, run.t_s)
    memo[key] = (us, vs)
    return us, vs


def compose(stages: Sequence[Stage], b0_um: float, memo: dict) -> RTModel:
    """One round-trip model: the nominal backlash plus ``stages`` (at most one kernel)."""
    kernels = [s for s in stages if s.kernel]
    if len(kernels) > 1:
        raise ValueError(f"stages {[s.effect for s in kernels]} both replace the play kernel")
    cuts = np.cumsum([1] + [len(s.names) for s in stages])
    names = ("backlash_um",) + tuple(n for s in stages for n in s.names)

    def parts(theta):
        return [theta[cuts[i] : cuts[i + 1]] for i in range(len(stages))]

    def predict(theta, run):
        ths = parts(theta)
        u = run.u_mm
        for st, th in zip(stages, ths):
            if st.u_map is not None:
                u = st.u_map(th, run, u)
        hb = np.full(u.size, 0.5e-3 * (theta[0] + run.wear_um))  # the run's wear: part of the nominal model
        for st, th in zip(stages, ths):
            if st.width is not None:
                hb = st.width(th, run, u, hb)
        hb = np.maximum(hb, 0.0)
        kern = next(((st, th) for st, th in zip(stages, ths) if st.kernel), None)
        if kern is None:
            x = play(u, hb, run.start_table_mm(float(hb[0])))
        elif kern[0].kernel == "lost_motion":
            ls, vs, cv = kern[1][:3]
            v = _speed_mm_s(run)
            stribeck = ls * np.exp(-((v / vs) ** 2))
            x0 = run.start_table_mm(float(hb[0]))
            if len(kern[1]) == 3:
                x = play_friction(u, hb, 1e-3 * (stribeck + cv * v), 1e-3 * ls, x0)
            else:  # friction that differs by direction: its levels times 1 + a in +, 1 - a in -
                a = kern[1][3]
                x = play_friction(u, hb, 1e-3 * ((1 + a) * stribeck + cv * v), 1e-3 * (1 + a) * ls, x0,
                                  1e-3 * ((1 - a) * stribeck + cv * v), 1e-3 * (1 - a) * ls)  # fmt: skip
        elif kern[0].kernel == "presliding":
            lc, lp = kern[1]
            hbc = np.maximum(0.0, hb - 0.5e-3 * lc)  # backlash_um is the apparent one
            x = play_dahl(u, hbc, 0.5e-3 * lc, 1e-3 * lp, run.start_table_mm(float(hb[0])))
        else:
            if kern[0].kernel == "friction_chain":
                fn, zeta, mu, ex, v_band = kern[1]
                c_guide, mu_s = GUIDE_DAMPING_PER_S, mu + ex
            else:
                fn, zeta, c_guide, mu = kern[1]
                mu_s = v_band = 0.0
            w = 2 * np.pi * fn
            hbc = np.maximum(0.0, hb - mu / (w * w))  # backlash_um is the apparent one
            # sub-steps: omega h <= 0.05 (0.1 for the friction chain, fitted from many starts)
            nsub = max(1, int(math.ceil(run.dt_s * w / (0.1 if kern[0].kernel == "friction_chain" else 0.05))))
            us, vs_ = smooth_u(run, memo)
            if u is not run.u_mm:
                us = us + (u - run.u_mm)
            def sim(x0):
                return play_inertia(us, vs_, run.t_s, hbc, w * w, 2 * zeta * w, c_guide, mu, nsub,
                                    x0, mu_s, v_band)  # fmt: skip

            x = (_free_start(sim, run, float(hbc[0])) if kern[0].kernel in FREE_START_KERNELS
                 else sim(run.start_table_mm(float(hbc[0]))))
        for st, th in zip(stages, ths):
            if st.out_map is not None:
                x = st.out_map(th, run, x)
        return x

    priors = [(i, s.prior) for i, s in enumerate(stages) if s.prior is not None]

    def prior(theta):
        ths = parts(theta)
        return np.concatenate([p(ths[i]) for i, p in priors])

    return RTModel(
        "+".join(s.effect for s in stages) or "none", names,
        np.r_[b0_um, *[s.x0 for s in stages]] if stages else np.array([b0_um]),
        np.r_[0.0, *[s.lower for s in stages]] if stages else np.array([0.0]),
        np.r_[2000.0, *[s.upper for s in stages]] if stages else np.array([2000.0]),
        predict, int(sum(len(s.names) for s in stages)), {s.effect: s.info for s in stages},
        prior=prior if priors else None, envelope=any(s.kernel in ENVELOPE_KERNELS for s in stages),
        train_windows_s=(TRAIN_ENVELOPE_WINDOWS_S if any(s.kernel == "compliant_chain" for s in stages)
                         else (ENVELOPE_WINDOW_S,)),
        run_choices=any(s.kernel in FREE_START_KERNELS for s in stages),
    )  # fmt: skip


FREE_START_KERNELS = ("friction_chain",)


def _free_start(sim: Callable[[float], np.ndarray], run: RoundTrip, half_gap_mm: float) -> np.ndarray:
    """A chain model's table from the best of three places of the nut in its gap at the
    first sample: the measured rest place (:meth:`RoundTrip.start_table_mm`) and either
    flank. Chosen per run on the run's own envelope residual, as the run's offset is: the
    place is not observed to the micrometre (the medians put it several µm off on a
    stroke that stick-slips one way), and a Karnopp chain is bistable in it (a
    micrometre of start decides between stick-slip and sliding through a whole
    stroke). The choice is a :class:`core.gap.roundtrip.RunChoices` one: recorded where
    the fit asks, and held (one simulation) while it takes its Jacobian."""
    u0 = float(run.u_mm[0])
    starts = [run.start_table_mm(half_gap_mm)]
    for x0 in (u0 - half_gap_mm, u0 + half_gap_mm):
        if all(abs(x0 - s) > 1e-6 for s in starts):
            starts.append(x0)
    choices = run_choices()
    held = None if choices is None else choices.held.get(id(run))
    if held is not None and held < len(starts):
        x = sim(starts[held])
        if np.all(np.isfinite(x)):
            return x
    best, best_i, best_cost = None, None, math.inf
    for i, x0 in enumerate(starts):
        x = sim(x0)
        if not np.all(np.isfinite(x)):
            continue
        cost = float(np.sum(residual_env_um(x, run) ** 2))
        if cost < best_cost:
            best, best_i, best_cost = x, i, cost
    if choices is not None and best_i is not None:
        choices.made[id(run)] = best_i
    return best if best is not None else x  # every start diverged: a bad fit, not simulated again


def stage_starts(stages: Sequence[Stage], base_theta: np.ndarray) -> list[np.ndarray]:
    """Start points of a composed fit: the base's fitted values, each stage's own starts."""
    out = []
    for k, st in enumerate(stages):
        for f in st.backlash_factors:
            for s0 in st.starts:
                th = [base_theta * np.r_[f, np.ones(base_theta.size - 1)]]
                for j, other in enumerate(stages):
                    th.append(s0 if j == k else other.x0)
                out.append(np.concatenate(th))
    return out



def train_residuals(model: RTModel, theta: np.ndarray, runs: Sequence[RoundTrip]) -> list[np.ndarray]:
    return [residual_um(model.predict(theta, r), r, r.fit_idx) for r in runs]
