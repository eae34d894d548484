"""The candidate effects of the gap diagnosis: one registered strategy per effect.

Each strategy is a *family* of physical forms, not one equation. It owns:

* its round-trip stage (how it changes the table given the motor): a map of the nut
  travel (lead, cyclic), of the backlash half-width (thermal, profile), a dynamic
  kernel (friction, compliance) or a map of the recorded table (skew). Stages compose,
  so a second effect is fitted on top of the first in one model;
* its start points, bounds and derived parameters;
* its contour form: the twin (:mod:`core.sim`) effect that carries the fitted
  parameters onto circles and lines, driven by the recorded command.

``REGISTRY`` is keyed by the single effect list, :data:`core.sim.CATEGORIES`.
``servo_dynamics`` has no round-trip stage (it acts between the command and the motor
and leaves the table-given-motor relation unchanged); it is fitted on the contours,
with a linearised start from the lag of the table behind the command.

Forms covered and not covered are listed per strategy (``forms``); docs/gap-diagnosis.md
repeats them with the benchmark figures.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from core.dataset import AxisSpec
from core.gap.data import RoundTrip
from core.gap.play import play, play_friction, play_inertia
from core.gap.roundtrip import (ENVELOPE_WINDOW_S, REFERENCE_C, TRAIN_ENVELOPE_WINDOWS_S, RTModel, residual_env_um,
                                residual_periods_mm, residual_um)
from core.sim import (
    CATEGORIES,
    BacklashProfile,
    Compliance,
    CyclicError,
    Friction,
    SamplingSkew,
    ServoDynamics,
    Thermal,
)

N_KNOTS = 7  # backlash profile: knots over the characterised travel, at least
PROFILE_KNOT_SPACING_MM = 40.0  # ... and at most this far apart (up to PROFILE_MAX_KNOTS)
PROFILE_MAX_KNOTS = 31
N_PERIODS = 2  # cyclic error: components
ASSUMED_MASS_KG = 500.0  # to express a fitted natural frequency as a chain stiffness
ASSUMED_STIFFNESS_N_PER_UM = 200.0  # to express friction lost motion as a force
GUIDE_FRICTION_PRIOR_MM_S2 = 196.0
GUIDE_FRICTION_PRIOR_WEIGHT = 100.0
GUIDE_DAMPING_PER_S = 1.0  # friction on a chain: a light oil-film damping of the table (1/s)
# kernels of a chain's dynamics: fitted and scored on round trips by envelope above 20 Hz
# (roundtrip.residual_env_um), as a stick-slipping or hunting chain's phase is not reproducible
ENVELOPE_KERNELS = ("friction_chain", "compliance")
PROFILE_SMOOTHNESS_WEIGHT = 0.05  # µm of residual per µm of second difference between knots
# Coulomb friction per unit mass that separates a friction effect from a compliant chain's
# own guide friction: 0.05 g. Rolling guides with their seals run at 0.002-0.05 g (part of
# a healthy chain, the compliance family); sliding guides, or rolling ones run dry, seized
# or over-preloaded, at 0.05-0.2 g and more, with stick-slip (the friction family).
FRICTION_CHAIN_MIN_MM_S2 = 0.05 * 9810.0
# Weight of the penalty that keeps the compliance form's fitted damping above the floor at
# which the position loop, closed on the table through that chain, is stable
# (:func:`loop_damping_floor`; the friction chain has none, see its docstring), in µm of
# residual per unit relative shortfall of the damping ratio.
LOOP_STABILITY_WEIGHT = 1e4
# Savitzky-Golay windows (order 2) of the motor record driving a chain kernel. 16 ms keeps
# 99 % of 25 Hz but cuts above ~60 Hz, where the chains ring: a rattle the motor record
# carries is then not started in the model (seed 4172, JSON index 22, true parameters:
# 18.4 µm test gap at 16/30 ms, 1.2 µm at 5/9 ms). Lighter windows did not name more of
# the tuning cases (33 -> 33 of 50; docs/gap-diagnosis.md, "A hunting chain").
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
    kernel: str | None = None  # "friction" | "friction_chain" | "compliance"
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


# ---- round-trip stages ------------------------------------------------------------


def _dt_c(run: RoundTrip) -> float:
    return run.temperature_c - REFERENCE_C


def thermal_stage(runs: Sequence[RoundTrip], axis: AxisSpec) -> Stage | None:
    """Lead growth with temperature about any bearing point (a bearing offset is a
    constant shift, absorbed by the per-run offset), a temperature-independent lead
    error, and a backlash that changes linearly with temperature. Not covered: a
    gradient along the screw (non-uniform heating), hysteresis between warming and
    cooling."""
    temps = [r.temperature_c for r in runs]
    if max(temps) - min(temps) < 1.0:
        return None
    fixed = axis.travel_mm[0]

    def u_map(th, run, u):
        return fixed + (u - fixed) * (1.0 + (th[1] + th[2] * _dt_c(run)) * 1e-6)

    def width(th, run, u, hb):
        return hb + 0.5e-3 * th[0] * _dt_c(run)

    return Stage("thermal", ("backlash_um_per_k", "lead_error_um_per_m", "lead_growth_ppm_per_k"),
                 np.zeros(3), np.array([-20.0, -500.0, -40.0]), np.array([20.0, 500.0, 40.0]),
                 u_map=u_map, width=width)  # fmt: skip


def profile_knots(lo_mm: float, hi_mm: float) -> np.ndarray:
    """Knots of the backlash profile over the characterised travel [lo, hi]: at most
    PROFILE_KNOT_SPACING_MM apart, N_KNOTS to PROFILE_MAX_KNOTS of them."""
    n = int(np.clip(math.ceil((hi_mm - lo_mm) / PROFILE_KNOT_SPACING_MM) + 1, N_KNOTS, PROFILE_MAX_KNOTS))
    return np.linspace(lo_mm, hi_mm, n)


def profile_stage(runs: Sequence[RoundTrip], axis: AxisSpec) -> Stage:
    """Backlash width along the travel, piecewise linear on knots at most 40 mm apart
    (7 to 31 over the characterised travel) with a weak smoothness prior: one or several
    wear bumps down to about 50 mm wide (a nut's length: a screw wears where the nut
    works), a ramp. Seven knots (travel / 6 apart) miss the narrow
    bumps of the independent plant. Test gaps left by the candidate on the tuning data, seeds
    (``default_rng([s, 0])``), 7 knots -> knots 40 mm apart: independent 3302, 3303,
    3305: 8.5 -> 4.1, 9.2 -> 0.8, 4.0 -> 0.5 µm (of 13.3, 5.6, 9.6); twin 3101-3105: 0.96
    -> 0.54, 0.69 -> 0.63, 1.62 -> 0.55, 0.65 -> 0.57, 0.58 -> 0.41 µm. (30 mm did better
    on some independent seeds and worse on twin 3102 and 3104; the result depends on where
    the knots fall, not monotonically on their number.) Not covered: features shorter than
    the knot spacing, a width that differs between directions, the travel no train round
    trip crossed (the profile is flat beyond it)."""
    lo = min(float(np.min(r.u_mm)) for r in runs)
    hi = max(float(np.max(r.u_mm)) for r in runs)
    knots = profile_knots(lo, hi)
    n = knots.size

    def width(th, run, u, hb):
        return hb + 0.5e-3 * np.interp(u, knots, np.r_[0.0, th])

    def prior(th):
        return PROFILE_SMOOTHNESS_WEIGHT * np.diff(np.r_[0.0, th], 2)

    names = tuple(f"backlash_change_at_{k:.0f}mm_um" for k in knots[1:])
    return Stage("backlash_profile", names, np.zeros(n - 1), np.full(n - 1, -500.0),
                 np.full(n - 1, 1000.0), info={"positions_mm": knots.tolist()}, width=width,
                 prior=prior)  # fmt: skip


def cyclic_stage(periods_mm: Sequence[float]) -> Stage:
    """Periodic transmission error u + sum a_i sin(2 pi u / p_i + phi_i) at the strongest
    periods of the residual (0.5-60 mm, found freely: screw lead, k_a, a gear or belt
    stage, their harmonics). Not covered: periods longer than a third of the stroke,
    amplitudes that change along the travel."""
    per = np.asarray(periods_mm, float)

    def u_map(th, run, u):
        out = u
        for i, p in enumerate(per):
            arg = 2 * np.pi * u / p
            out = out + 1e-3 * (th[2 * i] * np.sin(arg) + th[2 * i + 1] * np.cos(arg))
        return out

    names: list[str] = []
    for p in per:
        names += [f"sin_{p:.3f}mm_um", f"cos_{p:.3f}mm_um"]
    # amplitude bound: 50 µm, and a slope of the error (2 pi A / p) below 0.2, so the
    # nut never nearly stops (the twin refuses 0.5)
    lim = np.repeat(np.minimum(50.0, 0.2 * per * 1e3 / (2 * np.pi) / math.sqrt(2)), 2)
    return Stage("cyclic_error", tuple(names), np.zeros(2 * per.size), -lim, lim,
                 info={"periods_mm": per.tolist()}, u_map=u_map)  # fmt: skip


def friction_stage() -> Stage:
    """Friction as lost motion of a stiff chain: a break-away threshold (stick until the
    chain's stretch exceeds it, then slip: Karnopp-type static friction), a Stribeck part
    decaying with speed, a viscous part. The Coulomb part of the lost motion is
    inseparable from the backlash on round trips (it is in ``backlash_um``). On contours
    the Coulomb part and the static excess are refitted on the assumed chain, with and
    without pre-sliding (LuGre, a pre-sliding length of 0.5 µm or more; see
    ``core.gap.diagnose._Diagnosis._friction_on_contours``). Not covered: the chain's own
    dynamics (see :func:`friction_chain_stage`), pre-sliding on round trips (they do not
    show it), position-dependent friction."""
    return Stage(
        "friction", ("breakaway_lost_motion_um", "stribeck_velocity_mm_s", "viscous_lost_motion_um_per_mm_s"),
        np.array([1.0, 2.0, 0.0]), np.array([0.0, 0.05, 0.0]), np.array([100.0, 20.0, 0.3]), kernel="friction",
        starts=tuple(np.array([ls, vs, cv]) for ls in (1.0, 4.0, 12.0) for vs in (0.5, 3.0) for cv in (0.01, 0.05)),
        info={"form": "lost_motion"},
    )  # fmt: skip


def loop_damping_floor(gain_per_s: float, omega: float, guide_per_s: float) -> float:
    """The smallest chain damping ratio at which the position loop, closed on the table
    through the chain, is stable: per unit table mass, with an ideal velocity loop and the
    nut in contact, ``x'' = w^2 (u - x) + 2 zeta w (u' - x') - g x'`` and ``u' = K (c - x)``
    give ``s^3 + (2 zeta w + g) s^2 + (w^2 + 2 zeta w K) s + K w^2``, stable (Routh-Hurwitz)
    when ``(2 zeta w + g)(w^2 + 2 zeta w K) > K w^2``, about ``zeta > (K - g) / (2 w)``.
    A machine that makes parts has a stable loop (it may still hunt through its backlash, a
    bounded cycle); the round trips, driven by the recorded motor, cannot tell, and a chain
    fitted below this floor makes the closed-loop contour simulation grow without bound
    (independent 9401 case 27: 32.6 Hz at zeta 0.02, no guide damping, K 32/s)."""
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
    otherwise also fit, by its static part, better than compliance's own form (seen on
    the independent plant's two-mass chains, seeds 3202 and 3204). Its damping is
    not held above the position loop's linear stability floor (:func:`loop_damping_floor`,
    which the compliance form keeps): Coulomb and static friction bound a chain's
    oscillation, so a linearly unstable loop with them is a bounded hunting cycle, and the
    floor cost the plant-form test's Karnopp dataset its whole cut (14.97 -> 15.32 µm)."""
    return Stage(
        "friction", ("chain_frequency_hz", "chain_damping_ratio", "coulomb_per_mass_mm_s2", "static_excess_per_mass_mm_s2",
                     "stick_band_mm_s"),
        np.array([40.0, 0.1, 1000.0, 1000.0, 0.3]), np.array([5.0, 0.01, FRICTION_CHAIN_MIN_MM_S2, 0.0, 0.0]),
        np.array([200.0, 1.0, 20000.0, 40000.0, 5.0]), kernel="friction_chain",
        starts=tuple(np.array([fn, 0.1, mu, ex * mu, 0.5]) for fn in (25.0, 80.0) for mu in (600.0, 2000.0)
                     for ex in (0.5, 2.0)),
        info={"form": "chain"}, derive_starts=_chain_starts_from_lost_motion, max_nfev=40,
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
    parameter steps (each rattle is an event), so scipy's default finite-difference step
    (~1e-8) saw gradients of 1e8-1e10 and the trust region stopped after two evaluations,
    on its start point: on the independent plant's two-mass chains every fit ended
    exactly on one of its six starts (seeds 8647 case 47, 9401 case 33; on this form's
    own output the default step does move, and the 1 % step is not better there). It
    now steps by 1 % (``diff_step``), from 16 starts of frequency, damping and guide friction, each
    with the nominal backlash, twice and four times it (a table that floats across the
    gap makes the nominal fit take the clearance for smaller than it is: 22 µm where the
    compliance fit finds 101 µm on 9401 case 33); the two cheapest are refined, at most
    12 evaluations each (``max_nfev``; the Jacobian's not counted). Fitted on top of a
    base (a second effect), every start begins with the base's fitted values (the
    backlash not multiplied), only the cheapest start is refined, and at scipy's default
    step (``core.gap.diagnose._Diagnosis.fit_candidate``: a 1 % step over a base's
    parameters doubled the diagnosis' time). Test gaps of the candidate, before ->
    after, on the independent plant (tuning: seeds 8647, 9401, 7919 of earlier
    evaluations and 3202-3406, all ``default_rng([s, i])``): see docs/gap-diagnosis.md."""
    return Stage(
        "compliance", ("natural_frequency_hz", "damping_ratio", "guide_damping_per_s", "guide_friction_mm_s2"),
        np.array([60.0, 0.3, 5.0, 300.0]), np.array([3.0, 0.02, 0.0, 0.0]),
        np.array([300.0, 2.0, 200.0, FRICTION_CHAIN_MIN_MM_S2]),
        kernel="compliance",
        prior=lambda th: np.array([GUIDE_FRICTION_PRIOR_WEIGHT * math.log(max(th[3], 1.0) / GUIDE_FRICTION_PRIOR_MM_S2),
                                   _stability_penalty(gain_per_s, th[0], th[1], th[2])]),
        starts=tuple(np.array([fn, z, g, mu]) for fn in (15.0, 30.0, 60.0, 120.0) for z in (0.12, 0.3)
                     for g, mu in ((2.0, 100.0), (10.0, 450.0))),
        backlash_factors=(1.0, 2.0, 4.0), diff_step=0.01, max_nfev=12,
    )  # fmt: skip


def skew_stage() -> Stage:
    """The table encoder latched later (or earlier) than the motor: a delay that may
    drift linearly over a run (clock drift, a changing bus load). Not covered: random
    jitter (it shows as noise), a delay that jumps mid-run."""

    def out_map(th, run, x):
        t = run.t_s
        span = max(float(t[-1] - t[0]), 1e-9)
        tau = 1e-3 * (th[0] + th[1] * ((t - t[0]) / span - 0.5))
        return np.interp(t + tau, t, x)

    return Stage("sampling_skew", ("table_delay_ms", "delay_drift_ms"), np.zeros(2), np.array([-20.0, -20.0]),
                 np.array([20.0, 20.0]), out_map=out_map,
                 starts=tuple(np.array([tau, 0.0]) for tau in (-6.0, -3.0, -1.0, 1.0, 3.0, 6.0)))  # fmt: skip


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
        hb = np.full(u.size, 0.5e-3 * theta[0])
        for st, th in zip(stages, ths):
            if st.width is not None:
                hb = st.width(th, run, u, hb)
        hb = np.maximum(hb, 0.0)
        kern = next(((st, th) for st, th in zip(stages, ths) if st.kernel), None)
        if kern is None:
            x = play(u, hb, run.start_table_mm(float(hb[0])))
        elif kern[0].kernel == "friction":
            ls, vs, cv = kern[1]
            v = _speed_mm_s(run)
            lost = 1e-3 * (ls * np.exp(-((v / vs) ** 2)) + cv * v)
            x = play_friction(u, hb, lost, 1e-3 * ls, run.start_table_mm(float(hb[0])))
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
        train_windows_s=(TRAIN_ENVELOPE_WINDOWS_S if any(s.kernel == "compliance" for s in stages)
                         else (ENVELOPE_WINDOW_S,)),
    )  # fmt: skip


FREE_START_KERNELS = ("friction_chain",)


def _free_start(sim: Callable[[float], np.ndarray], run: RoundTrip, half_gap_mm: float) -> np.ndarray:
    """A chain model's table from the best of three places of the nut in its gap at the
    first sample: the measured rest place (:meth:`RoundTrip.start_table_mm`) and either
    flank. Chosen per run on the run's own envelope residual, as the run's offset is: the
    place is not observed to the micrometre (the medians put it several µm off on a
    stroke that stick-slips one way), and a Karnopp chain is bistable in it (stick-slip
    or sliding through a whole stroke, flipping with a micrometre of start: seed
    4234, case 41)."""
    u0 = float(run.u_mm[0])
    starts = [run.start_table_mm(half_gap_mm)]
    for x0 in (u0 - half_gap_mm, u0 + half_gap_mm):
        if all(abs(x0 - s) > 1e-6 for s in starts):
            starts.append(x0)
    best, best_cost = None, math.inf
    for x0 in starts:
        x = sim(x0)
        if not np.all(np.isfinite(x)):
            continue
        cost = float(np.sum(residual_env_um(x, run) ** 2))
        if cost < best_cost:
            best, best_cost = x, cost
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


# ---- contour forms ----------------------------------------------------------------


def sim_piece(effect: str, params: Mapping[str, float], info: Mapping, axis: AxisSpec,
              b_um: float) -> tuple[object | None, float]:
    """The twin's effect for fitted round-trip parameters of ``effect`` (names without the
    axis prefix), and how much of the round-trip backlash it accounts for itself (µm)."""
    p = params
    if effect == "thermal":
        return Thermal(lead_error_um_per_m=p["lead_error_um_per_m"], lead_growth_ppm_per_k=p["lead_growth_ppm_per_k"],
                       backlash_um_per_k=p["backlash_um_per_k"], fixed_end_mm=axis.travel_mm[0]), 0.0  # fmt: skip
    if effect == "backlash_profile":
        pos = info["positions_mm"]
        deltas = [0.0] + [p[k] for k in p if k.startswith("backlash_change_at_")]
        return BacklashProfile(tuple(pos), tuple(max(0.0, b_um + d) for d in deltas)), 0.0
    if effect == "cyclic_error":
        comps = []
        for per in info["periods_mm"]:
            a, b = p[f"sin_{per:.3f}mm_um"], p[f"cos_{per:.3f}mm_um"]
            if math.hypot(a, b) > 0:
                comps.append((per, math.hypot(a, b), math.degrees(math.atan2(b, a))))
        return (CyclicError.of(*comps) if comps else None), 0.0
    if effect == "friction" and info.get("form") == "chain":
        w = 2 * math.pi * p["chain_frequency_hz"]
        m = ASSUMED_MASS_KG  # every force scales with it: any mass gives the same motion
        mu, ex = p["coulomb_per_mass_mm_s2"], p["static_excess_per_mass_mm_s2"]
        comp = Compliance(stiffness_n_per_um=w * w * m * 1e-6, table_mass_kg=m, damping_ratio=p["chain_damping_ratio"],
                          guide_damping_n_s_per_mm=GUIDE_DAMPING_PER_S * m * 1e-3)  # fmt: skip
        # the round trips' stick band too: one parameter set for both
        fr = Friction(coulomb_n=mu * m * 1e-3, static_n=(mu + ex) * m * 1e-3, stribeck_velocity_mm_s=0.1,
                      stick_band_mm_s=p.get("stick_band_mm_s", 0.0))  # fmt: skip
        return [("compliance", comp), ("friction", fr)], 2e3 * mu / (w * w)
    if effect == "friction":
        k = ASSUMED_STIFFNESS_N_PER_UM
        coulomb_um = min(4.0 * p["breakaway_lost_motion_um"], 0.45 * b_um)  # static = 1.25 Coulomb assumed
        fr = Friction(coulomb_n=coulomb_um * k, static_n=(coulomb_um + p["breakaway_lost_motion_um"]) * k,
                      stribeck_velocity_mm_s=p["stribeck_velocity_mm_s"],
                      viscous_n_s_per_mm=p["viscous_lost_motion_um_per_mm_s"] * k)  # fmt: skip
        return fr, 2 * coulomb_um
    if effect == "compliance":
        w = 2 * math.pi * p["natural_frequency_hz"]
        m = ASSUMED_MASS_KG  # every force scales with it: any mass gives the same motion
        mu = p["guide_friction_mm_s2"]
        comp = Compliance(stiffness_n_per_um=w * w * m * 1e-6, table_mass_kg=m, damping_ratio=p["damping_ratio"],
                          guide_damping_n_s_per_mm=p["guide_damping_per_s"] * m * 1e-3,
                          guide_friction_n=mu * m * 1e-3)  # fmt: skip
        return comp, 2e3 * mu / (w * w)
    if effect == "sampling_skew":  # on contours the mean delay (a drift within a run is left out)
        return SamplingSkew(table_delay_s=1e-3 * p["table_delay_ms"]), 0.0
    return None, 0.0


def derived(effect: str, params: Mapping[str, float], b_um: float) -> dict[str, float]:
    """Parameters derived from a fit, in the units an engineer asks for."""
    if effect == "compliance":
        w2 = (2 * math.pi * params["natural_frequency_hz"]) ** 2
        return {"m_over_k_ms2": 1e6 / w2, "clearance_um": max(0.0, b_um - 2e3 * params["guide_friction_mm_s2"] / w2)}
    if effect == "friction" and "chain_frequency_hz" in params:
        w2 = (2 * math.pi * params["chain_frequency_hz"]) ** 2
        return {"coulomb_lost_motion_um": 2e3 * params["coulomb_per_mass_mm_s2"] / w2,
                "breakaway_excess_um": 1e3 * params["static_excess_per_mass_mm_s2"] / w2}  # fmt: skip
    if effect == "friction":
        return {"static_excess_n_at_200n_per_um": params["breakaway_lost_motion_um"] * ASSUMED_STIFFNESS_N_PER_UM}
    return {}


def servo_piece(params: Mapping[str, float]) -> ServoDynamics:
    return ServoDynamics(velocity_lag_s=1e-3 * params["velocity_lag_ms"], dead_time_s=1e-3 * params["dead_time_ms"],
                         feedforward=params["feedforward"], feedback_delay_s=1e-3 * params["feedback_delay_ms"])  # fmt: skip


SERVO_NAMES = ("position_gain_per_s", "feedforward", "velocity_lag_ms", "dead_time_ms", "feedback_delay_ms")
SERVO_LOWER = np.array([2.0, 0.0, 0.0, 0.0, 0.0])
SERVO_UPPER = np.array([120.0, 1.2, 20.0, 6.0, 6.0])
SERVO_FORMS = (
    "servo_dynamics: effective position gain on both sides of the configured K, velocity feed-forward "
    "fraction, a first-order velocity-loop lag, dead time in the forward and in the feedback path "
    "(interpolated, continuous). Not covered: a resonant velocity loop (it is approximated by the lag), "
    "acceleration feed-forward, friction compensation pulses."
)


@dataclass(frozen=True)
class Strategy:
    """One effect family: its round-trip stage factory and its documentation."""

    effect: str
    forms: str
    stage: Callable | None  # (runs, axis_spec, residuals) -> Stage | tuple of alternative forms | None; None: contour-only
    # the observations (core.gap.evidence.KINDS) this family's physics produces: evidence for it
    shown_by: tuple[str, ...] = ()


def _cyclic_factory(runs, axis, resid):
    periods, _ = residual_periods_mm(runs, resid, axis.screw_lead_mm, axis.transmission_mm_per_rev, N_PERIODS)
    return cyclic_stage(periods)


REGISTRY: dict[str, Strategy] = {
    # static friction above the Coulomb level holds a table at rest and lets it jump; below
    # its critical speed it sticks and slips out and back alike
    "friction": Strategy("friction", f"{friction_stage.__doc__}\n{friction_chain_stage.__doc__}",
                         lambda runs, axis, resid: (friction_stage(), friction_chain_stage()),
                         shown_by=("breakaway", "stick_slip")),
    # a compliant chain whose loop is closed through it hunts: a self-excited cycle a stroke
    # falls into or not, in one direction only
    "compliance": Strategy("compliance", compliance_stage.__doc__,
                           lambda runs, axis, resid: compliance_stage(axis.position_gain_per_s),
                           shown_by=("hunting",)),
    "thermal": Strategy("thermal", thermal_stage.__doc__, lambda runs, axis, resid: thermal_stage(runs, axis)),
    "backlash_profile": Strategy("backlash_profile", profile_stage.__doc__,
                                 lambda runs, axis, resid: profile_stage(runs, axis)),  # fmt: skip
    "cyclic_error": Strategy("cyclic_error", cyclic_stage.__doc__, _cyclic_factory),
    "servo_dynamics": Strategy("servo_dynamics", SERVO_FORMS, None),
    "sampling_skew": Strategy("sampling_skew", skew_stage.__doc__, lambda runs, axis, resid: skew_stage()),
}
if tuple(sorted(REGISTRY)) != tuple(sorted(CATEGORIES)):  # one effect list: the twin's
    raise ImportError(f"gap candidates {sorted(REGISTRY)} differ from core.sim.CATEGORIES {sorted(CATEGORIES)}")
EFFECTS: tuple[str, ...] = tuple(CATEGORIES)


def train_residuals(model: RTModel, theta: np.ndarray, runs: Sequence[RoundTrip]) -> list[np.ndarray]:
    return [residual_um(model.predict(theta, r), r, r.fit_idx) for r in runs]
