"""The thermal family: lead growth and backlash change with temperature, and a lead that
grows during a run as the axis warms up."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter

from core.dataset import AxisSpec
from core.gap.data import RoundTrip
from core.gap.families.base import NOT_IDENTIFIABLE, Family
from core.gap.roundtrip import ENVELOPE_WINDOW_S, REFERENCE_C
from core.gap.stages import Stage
from core.sim import Thermal

NAME = "thermal"
TEMPERATURE_NAMES = ("backlash_um_per_k", "lead_error_um_per_m", "lead_growth_ppm_per_k")
# the warm-up's laws: "time", the axis warms toward a steady state whatever it does (the
# table side, the scale's mounting, the ambient); "speed", the screw warms with the work
# the nut's friction does, i.e. with its speed, so a faster run grows more
WARMUP_LAWS = ("time", "speed")
WARMUP_NAMES = {"time": ("warmup_um_per_m", "warmup_tau_s", "warmup_shift_um"),
                "speed": ("warmup_um_per_m_per_m_min", "warmup_tau_s", "warmup_shift_um_per_m_min")}  # fmt: skip
# time constants searched, as multiples of the longest train run's duration: shorter than
# 5 % the warm-up is a step at the run's start (a per-run growth, the temperature form's);
# longer than 3x it is a straight drift whose size and time constant trade off
WARMUP_TAU_GRID = np.geomspace(0.05, 3.0, 13)
WARMUP_TAU_BOUNDS = (0.02, 10.0)  # the fit's bounds, same multiples
WARMUP_MAX = 300.0  # µm/m (µm/m per m/min for the speed law): bound of the growth and the bearing's shift
MM_S_PER_M_MIN = 1000.0 / 60.0


def _dt_c(run: RoundTrip) -> float:
    return run.temperature_c - REFERENCE_C


def thermal_stage(runs: Sequence[RoundTrip], axis: AxisSpec) -> Stage | None:
    """Lead growth with temperature about any bearing point (a bearing offset is a
    constant shift, absorbed by the per-run offset), a temperature-independent lead
    error, and a backlash that changes linearly with temperature. Not covered: a
    gradient along the screw (non-uniform heating), hysteresis between warming and
    cooling; a growth that changes during a run is the warm-up form's (below)."""
    temps = [r.temperature_c for r in runs]
    if max(temps) - min(temps) < 1.0:
        return None
    fixed = axis.travel_mm[0]

    def u_map(th, run, u):
        return fixed + (u - fixed) * (1.0 + (th[1] + th[2] * _dt_c(run)) * 1e-6)

    def width(th, run, u, hb):
        return hb + 0.5e-3 * th[0] * _dt_c(run)

    return Stage(NAME, TEMPERATURE_NAMES, np.zeros(3), np.array([-20.0, -500.0, -40.0]), np.array([20.0, 500.0, 40.0]),
                 u_map=u_map, width=width)  # fmt: skip


def _speed_m_min(run: RoundTrip) -> np.ndarray:
    """The nut's speed (m/min) over 10 ms, the heat source of the speed law, kept in the
    run's memo."""
    hit = run.memo.get("thermal_speed_m_min")
    if hit is None:
        hit = run.memo["thermal_speed_m_min"] = np.abs(_velocity_mm_s(run)) / MM_S_PER_M_MIN
    return hit


def warmup_heat(run: RoundTrip, law: str, tau_s: float) -> np.ndarray:
    """The warm-up's course over the run, per sample: "time", 1 - exp(-t/τ) (0 at the
    run's first sample, 1 when warm); "speed", the nut's speed through a first-order lag
    τ h' = |v| - h (m/min), from a cold screw (h = 0) at the first sample."""
    if law == "time":
        return -np.expm1(-(run.t_s - run.t_s[0]) / tau_s)
    a = math.exp(-run.dt_s / tau_s)
    return lfilter([1.0 - a], [1.0, -a], _speed_m_min(run))


def _velocity_mm_s(run: RoundTrip) -> np.ndarray:
    """The nut's velocity (mm/s) over 10 ms."""
    return np.gradient(uniform_filter1d(run.u_mm, max(1, int(round(0.01 / run.dt_s))), mode="nearest"), run.t_s)


def _side(run: RoundTrip) -> np.ndarray:
    """+1 / -1 per sample: the direction of the last motion (the flank the nut drives)."""
    v = _velocity_mm_s(run)
    moving = np.abs(v) > 0.1 * max(float(np.max(np.abs(v))), 1e-12)
    idx = np.where(moving, np.arange(v.size), 0)
    np.maximum.accumulate(idx, out=idx)
    s = np.sign(v[idx])
    if not moving[0]:
        s[idx == 0] = run.side0  # before the first motion: the flank it starts on
    return s


def warmup_starts(runs: Sequence[RoundTrip], axis: AxisSpec, resid: Sequence[np.ndarray],
                  law: str) -> list[np.ndarray]:
    """Start values (growth, τ s, bearing shift) of the warm-up form where the reference
    model's train residuals show one, best first; [] where they do not.

    For each τ of a grid (WARMUP_TAU_GRID), the residuals are regressed on the warm-up's
    growth and shift, h(t) (x - x_0) and h(t), beside each run's own offset, lead (a slope
    in x: a growth that holds over the run, the temperature form's), flank (a backlash
    of its own) and velocity (a reading latched late or early, a lag). What is left is a
    lead that changes within a run. It is seen where, at
    the best τ, n ln(RSS_0/RSS_1) > 3 ln n with n one sample per 50 ms of the runs (the
    residuals of a run are correlated over the envelope window, not independent per
    sample)."""
    fixed = axis.travel_mm[0]
    longest_s = max(float(r.t_s[-1] - r.t_s[0]) for r in runs)
    n_eff = sum(float(r.t_s[-1] - r.t_s[0]) for r in runs) / ENVELOPE_WINDOW_S
    if n_eff < 10:
        return []
    proj = []  # per run: the basis of its own columns, its residual outside it
    rss0 = 0.0
    for run, r in zip(runs, resid):
        idx = run.fit_idx
        own = np.column_stack([np.ones(idx.size), (run.u_mm[idx] - fixed) * 1e-3, _side(run)[idx],
                               _velocity_mm_s(run)[idx]])
        q, _ = np.linalg.qr(own)
        rp = r - q @ (q.T @ r)
        proj.append((q, rp))
        rss0 += float(rp @ rp)
    if rss0 <= 0:
        return []
    fits = []
    for tau in WARMUP_TAU_GRID * longest_s:
        cols, rs = [], []
        for run, (q, rp) in zip(runs, proj):
            idx = run.fit_idx
            h = warmup_heat(run, law, tau)[idx]
            w = np.column_stack([h * (run.u_mm[idx] - fixed) * 1e-3, h])
            cols.append(w - q @ (q.T @ w))
            rs.append(rp)
        a, y = np.vstack(cols), np.concatenate(rs)
        coef = np.linalg.lstsq(a, y, rcond=None)[0]
        rss1 = float(np.sum((y - a @ coef) ** 2))
        fits.append((rss1, tau, coef))
    fits.sort(key=lambda f: f[0])
    if not n_eff * math.log(rss0 / max(fits[0][0], 1e-12)) > 3 * math.log(n_eff):
        return []
    starts = []
    for rss1, tau, coef in fits:  # the best τ, then the best at least a factor 2 from it
        if all(abs(math.log(tau / s[1])) >= math.log(2.0) for s in starts):
            starts.append(np.array([*np.clip(coef[:1], -WARMUP_MAX, WARMUP_MAX), tau,
                                    *np.clip(coef[1:], -WARMUP_MAX, WARMUP_MAX)]))  # fmt: skip
        if len(starts) == 2:
            break
    return starts


def warmup_stage(runs: Sequence[RoundTrip], axis: AxisSpec, law: str, starts: Sequence[np.ndarray]) -> Stage:
    """A lead that grows during a run as the axis warms up, first order, from the run's
    start: the reading is x + (g h(t) (x - x_0) 1e-3 + s h(t)) µm beyond the nut's travel
    x, x_0 the travel start. Law "time": h = 1 - exp(-t/τ), g the growth when warm (µm/m),
    the table side or the scale's mounting warming toward a steady state; law "speed": h
    the nut's speed through a first-order lag τ (m/min), g the growth per m/min of steady
    speed, the screw warming with the work of the nut's friction, so a faster run grows
    more. s is the growth's shift at x_0 (a bearing elsewhere than the travel start). On
    a rigid chain a scale that grows and a screw that grows read alike in the table given
    the motor: the laws, not the round trips, tell where the heat comes from, and the
    better law is taken. Each run starts cold (a warm-up carried over from one run into
    the next shows as the next run's growth, the temperature form's). Composed with the
    temperature form where the train round trips are 1 K apart or more, with a static
    lead error otherwise. Fitted only where the reference's residuals show a lead that
    changes within a run (:func:`warmup_starts`). Not covered: a heat source that moves
    with the nut (a gradient along the screw), cooling during a dwell faster than the
    warm-up, two time constants."""
    fixed = axis.travel_mm[0]
    longest_s = max(float(r.t_s[-1] - r.t_s[0]) for r in runs)
    temps = [r.temperature_c for r in runs]
    with_temperature = max(temps) - min(temps) >= 1.0
    names = (TEMPERATURE_NAMES if with_temperature else TEMPERATURE_NAMES[1:2]) + WARMUP_NAMES[law]
    k = len(names) - 3
    lo_t = np.array([-20.0, -500.0, -40.0] if with_temperature else [-500.0])
    lower = np.r_[lo_t, -WARMUP_MAX, WARMUP_TAU_BOUNDS[0] * longest_s, -WARMUP_MAX]
    upper = np.r_[-lo_t, WARMUP_MAX, WARMUP_TAU_BOUNDS[1] * longest_s, WARMUP_MAX]

    def u_map(th, run, u):
        lead = th[1] + th[2] * _dt_c(run) if with_temperature else th[0]
        h = warmup_heat(run, law, th[k + 1])
        return fixed + (u - fixed) * (1.0 + (lead + th[k] * h) * 1e-6) + 1e-3 * th[k + 2] * h

    def width(th, run, u, hb):
        return hb + 0.5e-3 * th[0] * _dt_c(run)

    full = [np.r_[np.zeros(k), s] for s in starts]
    return Stage(NAME, names, full[0], lower, upper, info={"law": law}, u_map=u_map,
                 width=width if with_temperature else None, starts=tuple(full[1:]))  # fmt: skip


def _factory(runs, axis, resid):
    temperature = thermal_stage(runs, axis)
    forms = [] if temperature is None else [temperature]
    for law in WARMUP_LAWS:
        starts = warmup_starts(runs, axis, resid, law)
        if starts:
            forms.append(warmup_stage(runs, axis, law, starts))
    if not forms:
        return None
    return forms[0] if len(forms) == 1 else tuple(forms)


def sim_piece(p: Mapping[str, float], info: Mapping, axis: AxisSpec, b_um: float) -> tuple[object | None, float]:
    """The twin's Thermal. The time law's warm-up goes with it (the twin puts it on the
    scale's reading, which reads alike on a rigid chain); the speed law's and the growth's
    shift at the travel start are not carried to contours."""
    warm = {}
    if info.get("law") == "time":
        warm = {"warmup_um_per_m": p["warmup_um_per_m"], "warmup_tau_s": p["warmup_tau_s"]}
    return Thermal(lead_error_um_per_m=p["lead_error_um_per_m"],
                   lead_growth_ppm_per_k=p.get("lead_growth_ppm_per_k", 0.0),
                   backlash_um_per_k=p.get("backlash_um_per_k", 0.0), fixed_end_mm=axis.travel_mm[0],
                   **warm), 0.0  # fmt: skip


def identifiable(d, f) -> tuple[bool, str | None]:
    """Not identifiable where no round-trip axis took it and a round-trip axis could not
    fit it (its train round trips at one temperature, without a warm-up within a run)."""
    if not any(a in f.rt_fits and NAME in f.rt_fits[a].effects for a in d.rt_axes):
        if any(NOT_IDENTIFIABLE in n for n in f.notes):
            return False, None
    return True, None


FAMILY = Family(NAME, f"{thermal_stage.__doc__}\n\n{warmup_stage.__doc__}", _factory, sim_piece=sim_piece,
                identifiable=identifiable,
                no_stage_reason="train round trips at one temperature, no warm-up within a run")  # fmt: skip
