"""Circles and lines: the contour error of the nominal model and of the candidates.

A run's commanded path (rebuilt from its circle/line fields) is simulated with
``core.sim.simulate`` on the candidate axis models; the compared quantity is the
contour error (radial deviation for circles, perpendicular deviation for lines) of
the measured table positions minus that of the simulated ones, sample by sample.
Fits use the per-axis tracking error (table measured minus simulated, each axis), which
separates the axes and carries the same information.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from core.dataset import AxisSpec
from core.gap.data import Contour
from core.sim import AxisModel, Compliance, CyclicError, Effects, Friction, ServoDynamics, Thermal, simulate
from core.sim import BacklashProfile as SimProfile
from core.sim.programs import Program

ASSUMED_MASS_KG = 500.0  # to express a fitted natural frequency as a chain stiffness
ASSUMED_STIFFNESS_N_PER_UM = 200.0  # to express friction lost motion as a force (the simulator's default chain)
STATIC_TO_COULOMB_EXCESS = 4.0  # Coulomb = 4 (static - Coulomb): static = 1.25 Coulomb
MIN_LAG_S = 1e-3  # below: no lag (keeps the simulator's sub-step, lag/10, affordable)
MIN_DEAD_S = 4e-4


def models_for(axes: Mapping[str, AxisSpec], backlash_um: Mapping[str, float],
               effects: Mapping[str, Effects] | None = None) -> dict[str, AxisModel]:
    effects = effects or {}
    return {a: AxisModel.from_axis_spec(spec, max(0.0, float(backlash_um.get(a, 0.0))), effects=effects.get(a))
            for a, spec in axes.items()}  # fmt: skip


_CACHE: dict = {}
_CACHE_MAX = 4000


def _one_axis(prog: Program, i: int) -> Program:
    """Axis ``i`` of a program alone (the simulator's axes do not interact)."""
    return Program(
        kind=prog.kind, axes=(prog.axes[i],), feed_mm_min=prog.feed_mm_min, duration_s=prog.duration_s,
        record_from_s=prog.record_from_s, record_to_s=prog.record_to_s, initial_sides=(prog.initial_sides[i],),
        path=lambda t, _p=prog.path, _i=i: np.atleast_2d(_p(t))[_i : _i + 1], meta=prog.meta,
    )  # fmt: skip


def simulate_axis(c: Contour, axis: str, model: AxisModel) -> np.ndarray:
    """Simulated (noise-free) table position of one axis at the run's sample times (cached)."""
    key = (c.file, id(c), axis, model)
    hit = _CACHE.get(key)
    if hit is not None:
        return hit
    prog = _one_axis(c.program, c.axes.index(axis))
    tr = simulate({axis: model}, prog, temperature_c=c.temperature_c, rate_hz=c.rate_hz)
    out = np.interp(c.t_s, tr.time_s, tr.table_true_mm[axis])
    if len(_CACHE) > _CACHE_MAX:
        _CACHE.clear()
    _CACHE[key] = out
    return out


def simulate_table(c: Contour, models: Mapping[str, AxisModel]) -> dict[str, np.ndarray]:
    """Simulated (noise-free) table positions of each axis at the run's sample times."""
    return {a: simulate_axis(c, a, models[a]) for a in c.axes}


def contour_residual_um(c: Contour, sim: Mapping[str, np.ndarray]) -> np.ndarray:
    return c.deviation_um(c.table_mm) - c.deviation_um(sim)


def tracking_residual_um(c: Contour, sim: Mapping[str, np.ndarray], axes: Sequence[str] | None = None) -> np.ndarray:
    i = c.fit_idx
    return np.concatenate([(c.table_mm[a][i] - sim[a][i]) * 1e3 for a in (axes or c.axes)])


def fit_backlash_on_contours(contours: Sequence[Contour], axes: Mapping[str, AxisSpec], axis: str,
                             others_um: Mapping[str, float]) -> float:
    """Constant backlash of ``axis`` from train contours (bounded scalar fit of the tracking error)."""

    def cost(b):
        bl = dict(others_um)
        bl[axis] = b
        m = models_for(axes, bl)
        return sum(float(np.sum(tracking_residual_um(c, simulate_table(c, m), [axis]) ** 2))
                   for c in contours if axis in c.axes)  # fmt: skip

    sol = minimize_scalar(cost, bounds=(0.0, 1000.0), method="bounded", options={"xatol": 0.2, "maxiter": 25})
    return float(sol.x)


def servo_effect(lag_ms: float, dead_ms: float) -> ServoDynamics | None:
    lag = lag_ms * 1e-3 if lag_ms * 1e-3 >= MIN_LAG_S else 0.0
    dead = dead_ms * 1e-3 if dead_ms * 1e-3 >= MIN_DEAD_S else 0.0
    return ServoDynamics(velocity_lag_s=lag, dead_time_s=dead) if lag or dead else None


def fit_servo(contours: Sequence[Contour], axes: Mapping[str, AxisSpec], backlash_um: Mapping[str, float],
              base: Mapping[str, Effects] | None = None) -> tuple[dict[str, tuple[float, float]], float]:
    """Velocity lag and dead time (ms) per contour axis, fitted on the train contours, one
    axis at a time (the simulator's axes do not interact). Returns ({axis: (lag_ms,
    dead_ms)}, train RSS in µm^2 of the tracking error)."""
    names = sorted({a for c in contours for a in c.axes})
    params = {}
    rss = 0.0
    for a in names:
        fx0 = (base or {}).get(a) or Effects()
        mine = [c for c in contours if a in c.axes]

        def res(theta, a=a, fx0=fx0, mine=mine):
            fx = fx0.with_effect("servo_dynamics", servo_effect(theta[0], theta[1]))
            m = AxisModel.from_axis_spec(axes[a], max(0.0, float(backlash_um.get(a, 0.0))), effects=fx)
            return np.concatenate([(c.table_mm[a][c.fit_idx] - simulate_axis(c, a, m)[c.fit_idx]) * 1e3 for c in mine])

        starts = [np.array([lag, dead]) for lag in (0.0, 3.0, 8.0) for dead in (0.0, 1.0)]
        x0 = min(starts, key=lambda th: float(np.sum(res(th) ** 2)))
        x0 = np.clip(x0, [0.05, 0.05], [29.0, 5.0])
        sol = least_squares(res, x0, bounds=([0.0, 0.0], [30.0, 6.0]), diff_step=0.05, x_scale=[5.0, 1.0],
                            max_nfev=20)  # fmt: skip
        params[a] = (float(sol.x[0]), float(sol.x[1]))
        rss += float(2 * sol.cost)
    return params, rss


def friction_for_sim(b_incl_um: float, breakaway_um: float, vs: float, cv: float, coulomb_um: float) -> tuple[Effects, float]:
    """Simulator friction from lost motions at the assumed stiffness; the Coulomb part
    (coulomb_um per side) comes out of the backlash the round trips saw."""
    k = ASSUMED_STIFFNESS_N_PER_UM
    fr = Friction(coulomb_n=coulomb_um * k, static_n=(coulomb_um + breakaway_um) * k, stribeck_velocity_mm_s=vs,
                  viscous_n_s_per_mm=cv * k)  # fmt: skip
    return Effects(friction=fr), max(0.0, b_incl_um - 2 * coulomb_um)


def fit_coulomb_on_contours(contours: Sequence[Contour], axes: Mapping[str, AxisSpec], axis: str,
                            theta: Sequence[float]) -> float:
    """The Coulomb lost motion (µm per side) the round trips cannot separate from the
    backlash, fitted on the train contours (bounded scalar fit of the axis' tracking error)."""
    b_incl, ls, vs, cv = theta
    mine = [c for c in contours if axis in c.axes]

    def cost(lc):
        fx, b = friction_for_sim(b_incl, ls, vs, cv, lc)
        m = AxisModel.from_axis_spec(axes[axis], b, effects=fx)
        return sum(float(np.sum(((c.table_mm[axis] - simulate_axis(c, axis, m))[c.fit_idx] * 1e3) ** 2)) for c in mine)

    sol = minimize_scalar(cost, bounds=(0.0, max(0.45 * b_incl, 0.1)), method="bounded",
                          options={"xatol": 0.2, "maxiter": 14})  # fmt: skip
    return float(sol.x)


def effect_for_sim(effect: str, params: Mapping[str, float], info: Mapping, axis: AxisSpec) -> tuple[Effects, float | None]:
    """The simulator effect equivalent to a round-trip fit, and the backlash to use with it
    (None: keep the nominal backlash). Returns (Effects(), None) for effects without a
    contour counterpart (sampling skew: a table-only contour does not see it)."""
    v = list(params.values())
    if effect == "thermal":
        th = Thermal(lead_error_um_per_m=v[2], lead_growth_ppm_per_k=v[3], backlash_um_per_k=v[1],
                     fixed_end_mm=axis.travel_mm[0])  # fmt: skip
        return Effects(thermal=th), v[0]
    if effect == "backlash_profile":
        return Effects(backlash_profile=SimProfile(tuple(info["positions_mm"]), tuple(max(0.0, w) for w in v))), None
    if effect == "cyclic_error":
        per = info["periods_mm"]
        comps = []
        for i, p in enumerate(per):
            a, b = v[1 + 2 * i], v[2 + 2 * i]
            comps.append((p, math.hypot(a, b), math.degrees(math.atan2(b, a))))
        return Effects(cyclic_error=CyclicError.of(*comps)), v[0]
    if effect == "friction":
        return friction_for_sim(v[0], v[1], v[2], v[3], float(info.get("coulomb_um", 0.0)))
    if effect == "compliance":
        w = 2 * math.pi * v[1]
        m = ASSUMED_MASS_KG  # every force scales with it: any mass gives the same motion
        comp = Compliance(stiffness_n_per_um=w * w * m * 1e-6, table_mass_kg=m, damping_ratio=v[2],
                          guide_damping_n_s_per_mm=v[3] * m * 1e-3, guide_friction_n=v[4] * m * 1e-3)  # fmt: skip
        return Effects(compliance=comp), max(0.0, v[0] - 2e3 * v[4] / (w * w))
    return Effects(), None
