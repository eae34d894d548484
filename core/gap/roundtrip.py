"""Round-trip models of the table given the motor, nominal and with one effect each.

Every model predicts the table x(t) from the nut travel u(t) = k_a x_m(t) of one axis
(Eq. 5's play operator plus the effect) and a per-run offset (the motor encoder's
zero is arbitrary: fitted for every model alike, linearly, as the run's mean
residual). Parameters are fitted with ``scipy.optimize.least_squares`` on the train
runs only, in physical units (µm, ppm/K, ms). Friction forces are not identifiable
without the chain stiffness, so friction is fitted as lost motion (µm).

Servo dynamics act between the command and the motor and leave the table-given-motor
relation unchanged, so they have no round-trip model here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from core.gap.data import RoundTrip
from core.gap.play import play, play_friction, play_inertia

REFERENCE_C = 20.0
N_KNOTS = 5  # backlash profile b(u): piecewise linear on this many knots over the travel
N_PERIODS = 2  # cyclic error: components fitted
# Round trips barely tell guide friction from backlash (both widen the apparent backlash),
# yet it decides when a braking table floats across the backlash. A weak prior (µm-scale
# residual per e-fold) pulls an undetermined value to 2 % of the weight (0.02 g).
GUIDE_FRICTION_PRIOR_MM_S2 = 196.0
GUIDE_FRICTION_PRIOR_WEIGHT = 100.0


@dataclass(frozen=True)
class RTModel:
    """One candidate model of an axis' round trips.

    ``predict(theta, run) -> x (mm)``; ``theta`` in the units of ``names``; ``x0``,
    ``lower``/``upper`` the start and bounds of the fit; ``n_extra`` the parameters added to
    the nominal model (the backlash).
    """

    effect: str
    names: tuple[str, ...]
    x0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    predict: Callable[[np.ndarray, RoundTrip], np.ndarray]
    n_extra: int
    info: dict
    prior: Callable[[np.ndarray], np.ndarray] | None = None  # extra residuals (weak priors)


def _x0(run: RoundTrip, hb: float) -> float:
    return float(run.u_mm[0] - run.side0 * hb)


def _speed_mm_s(run: RoundTrip) -> np.ndarray:
    n = max(1, int(round(0.01 / run.dt_s)))
    u = run.u_mm
    if n > 1:
        k = np.ones(n) / n
        u = np.convolve(np.pad(u, (n // 2, n - 1 - n // 2), mode="edge"), k, mode="valid")
    return np.abs(np.gradient(u, run.t_s))


_SMOOTH: dict = {}


def smooth_u(run: RoundTrip, window_s: float = 0.016, velocity_window_s: float = 0.03) -> tuple[np.ndarray, np.ndarray]:
    """The nut travel (mm) and velocity (mm/s) with the motor encoder's noise averaged out
    (Savitzky-Golay, quadratic: accelerations stay unbiased). Cached per run."""
    key = id(run.u_mm)
    hit = _SMOOTH.get(key)
    if hit is not None and hit[0] is run.u_mm:
        return hit[1], hit[2]
    u = run.u_mm
    n = 2 * int(round(window_s / run.dt_s / 2)) + 1  # odd: centred, no time shift
    nv = 2 * int(round(velocity_window_s / run.dt_s / 2)) + 1
    us = savgol_filter(u, n, 2) if 5 <= n < u.size else u
    vs = savgol_filter(u, nv, 2, deriv=1, delta=run.dt_s) if 5 <= nv < u.size else np.gradient(u, run.t_s)
    if len(_SMOOTH) > 256:
        _SMOOTH.clear()
    _SMOOTH[key] = (run.u_mm, us, vs)
    return us, vs


def predict_nominal(theta, run: RoundTrip) -> np.ndarray:
    hb = 0.5e-3 * theta[0]
    return play(run.u_mm, np.full(run.u_mm.size, hb), _x0(run, hb))


def nominal_model(b0_um: float) -> RTModel:
    return RTModel("none", ("backlash_um",), np.array([b0_um]), np.array([0.0]), np.array([2000.0]),
                   predict_nominal, 0, {})  # fmt: skip


def thermal_model(b0_um: float) -> RTModel:
    def predict(theta, run):
        b20, beta, e0, alpha = theta
        dt = run.temperature_c - REFERENCE_C
        u = run.u_mm * (1.0 + (e0 + alpha * dt) * 1e-6)
        hb = max(0.0, 0.5e-3 * (b20 + beta * dt))
        return play(u, np.full(u.size, hb), _x0(run, hb))

    return RTModel(
        "thermal", ("backlash_20c_um", "backlash_um_per_k", "lead_error_um_per_m", "lead_growth_ppm_per_k"),
        np.array([b0_um, 0.0, 0.0, 0.0]), np.array([0.0, -20.0, -500.0, -40.0]),
        np.array([2000.0, 20.0, 500.0, 40.0]), predict, 3, {},
    )  # fmt: skip


def profile_model(b0_um: float, lo_mm: float, hi_mm: float) -> RTModel:
    knots = np.linspace(lo_mm, hi_mm, N_KNOTS)

    def predict(theta, run):
        hb = np.maximum(0.0, 0.5e-3 * np.interp(run.u_mm, knots, theta))
        return play(run.u_mm, hb, _x0(run, float(hb[0])))

    names = tuple(f"backlash_at_{k:.0f}mm_um" for k in knots)
    return RTModel("backlash_profile", names, np.full(N_KNOTS, b0_um), np.zeros(N_KNOTS),
                   np.full(N_KNOTS, 2000.0), predict, N_KNOTS - 1, {"positions_mm": knots.tolist()})  # fmt: skip


def cyclic_model(b0_um: float, periods_mm: Sequence[float]) -> RTModel:
    per = np.asarray(periods_mm, float)

    def predict(theta, run):
        u = run.u_mm
        for i, p in enumerate(per):
            arg = 2 * np.pi * u / p
            u = u + 1e-3 * (theta[1 + 2 * i] * np.sin(arg) + theta[2 + 2 * i] * np.cos(arg))
        hb = 0.5e-3 * theta[0]
        return play(u, np.full(u.size, hb), _x0(run, hb))

    names = ["backlash_um"]
    for p in per:
        names += [f"sin_{p:.3f}mm_um", f"cos_{p:.3f}mm_um"]
    k = 2 * per.size
    return RTModel("cyclic_error", tuple(names), np.r_[b0_um, np.zeros(k)], np.r_[0.0, np.full(k, -50.0)],
                   np.r_[2000.0, np.full(k, 50.0)], predict, k, {"periods_mm": per.tolist()})  # fmt: skip


def friction_model(b0_um: float) -> RTModel:
    def predict(theta, run):
        b, ls, vs, cv = theta
        v = _speed_mm_s(run)
        lost = 1e-3 * (ls * np.exp(-((v / vs) ** 2)) + cv * v)
        hb = 0.5e-3 * b
        return play_friction(run.u_mm, np.full(v.size, hb), lost, 1e-3 * ls, _x0(run, hb))

    return RTModel(
        "friction", ("backlash_incl_coulomb_um", "breakaway_lost_motion_um", "stribeck_velocity_mm_s",
                     "viscous_lost_motion_um_per_mm_s"),
        # bounds: Stribeck velocities of guideways 0.1-20 mm/s; viscous friction up to
        # 10 N s/mm on a chain of >= 100 N/µm is <= 0.1 µm per mm/s (0.3 allowed)
        np.array([b0_um, 1.0, 2.0, 0.0]), np.array([0.0, 0.0, 0.05, 0.0]), np.array([2000.0, 100.0, 20.0, 0.3]),
        predict, 3, {},
    )  # fmt: skip


def compliance_model(b0_um: float) -> RTModel:
    """The table as a mass on a spring-damper behind the nut, held by guide damping and
    Coulomb guide friction (per unit mass: no force is identifiable without the mass).
    Captures the lag proportional to acceleration (1/w^2), ringing after acceleration
    changes, and the table floating across the backlash when braking harder than the
    guides can hold it."""

    def predict(theta, run):
        b_app, fn, zeta, c_guide, mu = theta
        w = 2 * np.pi * fn
        # fitted as the apparent backlash (with the friction lost motion 2 mu / w^2 in it):
        # b and mu alone lie along a narrow valley the fit would crawl along
        hb = max(0.0, 0.5e-3 * b_app - mu / (w * w))
        nsub = max(1, int(math.ceil(run.dt_s * w / 0.05)))
        # the motor encoder's noise would shake the spring and break the table loose: smooth it
        us, vs = smooth_u(run)
        return play_inertia(us, vs, run.t_s, np.full(run.u_mm.size, hb), w * w, 2 * zeta * w, c_guide, mu, nsub,
                            _x0(run, hb))  # fmt: skip

    return RTModel(
        "compliance", ("apparent_backlash_um", "natural_frequency_hz", "damping_ratio", "guide_damping_per_s",
                       "guide_friction_mm_s2"),
        np.array([b0_um, 60.0, 0.3, 5.0, 300.0]), np.array([0.0, 3.0, 0.02, 0.0, 0.0]),
        np.array([2000.0, 300.0, 2.0, 200.0, 20000.0]), predict, 4, {},
        prior=lambda th: np.array([GUIDE_FRICTION_PRIOR_WEIGHT * math.log(max(th[4], 1.0) / GUIDE_FRICTION_PRIOR_MM_S2)]),
    )  # fmt: skip


def skew_model(b0_um: float) -> RTModel:
    def predict(theta, run):
        b, tau_ms = theta
        hb = 0.5e-3 * b
        p = play(run.u_mm, np.full(run.u_mm.size, hb), _x0(run, hb))
        return np.interp(run.t_s + 1e-3 * tau_ms, run.t_s, p)

    return RTModel("sampling_skew", ("backlash_um", "table_delay_ms"), np.array([b0_um, 0.0]),
                   np.array([0.0, -20.0]), np.array([2000.0, 20.0]), predict, 1, {})  # fmt: skip


def residual_um(pred: np.ndarray, run: RoundTrip, idx: np.ndarray | None = None) -> np.ndarray:
    """Measured minus predicted table (µm) with the run's offset removed (its mean)."""
    r = (run.x_mm - pred) * 1e3
    r = r[run.start :] if idx is None else r[idx]
    return r - r.mean()


def fit(model: RTModel, runs: Sequence[RoundTrip], starts: Sequence[np.ndarray] = (),
        n_starts: int = 1) -> tuple[np.ndarray, float]:
    """Least-squares fit on ``runs``; returns (theta, train RSS in µm^2). ``starts`` are
    extra start points: the ``n_starts`` cheapest of them and ``model.x0`` (one evaluation
    each) start trust-region fits; the best fit wins."""

    def res(theta):
        parts = [residual_um(model.predict(theta, r), r, r.fit_idx) for r in runs]
        if model.prior is not None:
            parts.append(model.prior(theta))
        return np.concatenate(parts)

    cands = [np.clip(x0, model.lower + 1e-9, model.upper - 1e-9) for x0 in [model.x0, *starts]]
    if len(cands) > 1:
        costs = [float(np.sum(res(th) ** 2)) for th in cands]
        cands = [cands[i] for i in np.argsort(costs)[:n_starts]]
    best = None
    for x0 in cands:
        sol = least_squares(res, x0, bounds=(model.lower, model.upper), x_scale="jac", method="trf",
                            max_nfev=25 * (len(x0) + 1))  # fmt: skip
        if best is None or sol.cost < best.cost:
            best = sol
    return best.x, float(2 * best.cost)


def estimate_backlash_um(runs: Sequence[RoundTrip]) -> float:
    """Start value: the median table-minus-nut difference between the two directions."""
    vals = []
    for r in runs:
        v = np.gradient(r.u_mm, r.t_s)
        vmax = np.percentile(np.abs(v), 95)
        d = (r.x_mm - r.u_mm) * 1e3
        pos, neg = d[v > 0.5 * vmax], d[v < -0.5 * vmax]
        if pos.size and neg.size:
            vals.append(np.median(neg) - np.median(pos))
    return float(max(np.median(vals), 0.0)) if vals else 10.0


def residual_periods_mm(runs: Sequence[RoundTrip], resid: Sequence[np.ndarray], lead_mm: float, ka_mm: float,
                        n: int = N_PERIODS) -> tuple[list[float], dict]:
    """The ``n`` strongest periods of the residual versus position (least-squares
    periodogram over 0.5-60 mm on the moving samples), each snapped to the screw lead,
    k_a or one of their first four harmonics when within 2 %."""
    us, rs = [], []
    for run, r in zip(runs, resid):
        i = run.fit_idx
        v = np.gradient(run.u_mm, run.t_s)[i]
        moving = np.abs(v) > 0.3 * np.percentile(np.abs(v), 95)
        for sgn in (1, -1):
            m = moving & (np.sign(v) == sgn)
            if m.sum() > 20:
                us.append(run.u_mm[i][m])
                rs.append(r[m] - r[m].mean())
    if not us:
        return [lead_mm, ka_mm][:n], {}
    u = np.concatenate(us)
    y = np.concatenate(rs)
    span = float(np.ptp(u))
    periods = np.geomspace(0.5, min(60.0, max(span / 3, 1.0)), 1500)
    k = 2 * np.pi / periods[:, None]
    s, c = np.sin(k * u), np.cos(k * u)
    power = ((s @ y) ** 2 / np.maximum((s * s).sum(1), 1e-12) + (c @ y) ** 2 / np.maximum((c * c).sum(1), 1e-12))
    known = [lead_mm / h for h in (1, 2, 3, 4)] + [ka_mm / h for h in (1, 2, 3, 4)]
    chosen: list[float] = []
    order = np.argsort(-power)
    for j in order:
        p = float(periods[j])
        if any(abs(p - q) / q < 0.08 for q in chosen):
            continue
        snap = min(known, key=lambda q: abs(p - q) / q)
        if abs(p - snap) / snap < 0.02:
            p = snap
        chosen.append(p)
        if len(chosen) == n:
            break
    top = float(periods[order[0]])
    return chosen, {"dominant_period_mm": top, "power": float(power[order[0]] / max(power.mean(), 1e-30))}


def rms(x: np.ndarray) -> float:
    return float(math.sqrt(np.mean(np.square(x)))) if x.size else float("nan")
