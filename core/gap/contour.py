"""Circles and lines: the contour error of the nominal model and of the candidates.

A run's commanded path (the recorded command, or the program rebuilt from its
circle/line fields) is simulated with ``core.sim.simulate`` on the candidate axis
models; the compared quantity is the contour error (radial deviation for circles,
perpendicular deviation for lines) of the measured table positions minus that of the
simulated ones, sample by sample, on the data arc or segment only. Simulations are
kept in a :class:`SimMemo` that lives for one diagnosis.
Fits use the per-axis tracking error (table measured minus simulated, each axis), which
separates the axes and carries the same information.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.optimize import minimize_scalar

from core.dataset import AxisSpec
from core.gap.data import Contour
from core.gap.roundtrip import slow_and_envelope
from core.sim import AxisModel, Effects, simulate
from core.sim.programs import Program



def models_for(axes: Mapping[str, AxisSpec], backlash_um: Mapping[str, float],
               effects: Mapping[str, Effects] | None = None) -> dict[str, AxisModel]:
    effects = effects or {}
    return {a: AxisModel.from_axis_spec(spec, max(0.0, float(backlash_um.get(a, 0.0))), effects=effects.get(a))
            for a, spec in axes.items()}  # fmt: skip


SIM_STEP_S = 5e-4  # command grid of the diagnosis' simulations: chord error < 0.01 µm on R >= 10 mm at 3 m/min
# Integration steps per radian of a chain's (or pre-sliding bristles') natural frequency in
# the diagnosis' simulations; the twin's default is 20 (core.sim.engine.STEPS_PER_RADIAN).
# Measured on bench_gap's twin friction dataset (a train circle): against 20 steps,
# 10 moves the table by at most 0.0005 µm RMS (Karnopp, a 200 Hz chain, LuGre with a
# 0.5-2 µm pre-sliding length at 2-4 µm Coulomb lost motion) and 0.012 µm RMS (0.10 µm
# peak) for the stiffest bristles fitted (8 µm Coulomb over 0.5 µm), against noise floors
# of 0.2-1 µm, and halves the time of the pre-sliding simulations, which took half of a
# diagnosis (bench_gap's independent wear-bump dataset: 51 of 110 s on one thread).
SIM_STEPS_PER_RADIAN = 10.0


class SimMemo:
    """Simulations of one diagnosis, keyed by (run file, axis, axis model). Made anew for
    every diagnosis: two diagnoses never share one, whatever their file names."""

    def __init__(self) -> None:
        self._sims: dict = {}
        self.misc: dict = {}  # other per-diagnosis memos (smoothed round trips)
        self.n_simulations = 0

    def axis(self, c: Contour, axis: str, model: AxisModel) -> np.ndarray:
        """Simulated (noise-free) table position of one axis at the run's sample times."""

        def table(tr):
            skew = model.effects.sampling_skew
            tau = skew.table_delay_s if skew is not None else 0.0  # the table latched tau after the motor
            return np.interp(c.t_s + tau, tr.time_s, tr.table_true_mm[axis])

        return self._simulated((c.file, axis, model), c, axis, model, table)

    def motor_mm(self, c: Contour, axis: str, model: AxisModel) -> np.ndarray:
        """Simulated motor position of one axis (mm of table travel, k_a times its
        revolutions) at the run's sample times: what the loop asked of the drive."""

        def motor(tr):
            return np.interp(c.t_s, tr.time_s, model.transmission_mm_per_rev * tr.motor_true_rev[axis])

        return self._simulated(("motor", c.file, axis, model), c, axis, model, motor)

    def _simulated(self, key, c: Contour, axis: str, model: AxisModel, take) -> np.ndarray:
        hit = self._sims.get(key)
        if hit is not None:
            return hit
        prog = _one_axis(c.program, c.axes.index(axis), start_side(c.program, axis, model))
        tr = simulate({axis: model}, prog, temperature_c=c.temperature_c, rate_hz=c.rate_hz, step_s=SIM_STEP_S,
                      steps_per_radian=SIM_STEPS_PER_RADIAN)
        out = take(tr)
        self.n_simulations += 1
        self._sims[key] = out
        return out

    def table(self, c: Contour, models: Mapping[str, AxisModel]) -> dict[str, np.ndarray]:
        return {a: self.axis(c, a, models[a]) for a in c.axes}


def start_side(prog: Program, axis: str, model: AxisModel):
    """The initial side of ``axis`` in a simulation of ``model``: the program's, but for an
    axis that starts at rest and moves one way only, where the encoders put the nut
    (``meta["rest_one_way_mm"]``, :func:`core.gap.data._one_way_travel_mm`) as a place in
    the model's own gap: (s h + delta) / h, clipped to the gap's flanks."""
    side = prog.initial_sides[prog.axes.index(axis)]
    w = (prog.meta.get("rest_one_way_mm") or {}).get(axis)
    half_mm = 0.5e-3 * float(model.backlash_um)
    if w is None or half_mm <= 0:
        return side
    sgn, delta = w
    return float(np.clip(sgn + delta / half_mm, -1.0, 1.0))


def _one_axis(prog: Program, i: int, side=None) -> Program:
    """Axis ``i`` of a program alone (the simulator's axes do not interact), starting on
    ``side`` (default: the program's initial side of that axis)."""
    side = prog.initial_sides[i] if side is None else side
    return Program(
        kind=prog.kind, axes=(prog.axes[i],), feed_mm_min=prog.feed_mm_min, duration_s=prog.duration_s,
        record_from_s=prog.record_from_s, record_to_s=prog.record_to_s, initial_sides=(side,),
        path=lambda t, _p=prog.path, _i=i: np.atleast_2d(_p(t))[_i : _i + 1], meta=prog.meta,
    )  # fmt: skip


ENVELOPE_WINDOW_S = 0.05  # contour scores: slower than this sample by sample, faster by its envelope


def envelope_residual_um(measured_um: np.ndarray, simulated_um: np.ndarray, window: int,
                         stacked: bool = False) -> np.ndarray:
    """Measured against simulated, sample by sample below the window's frequency and by
    envelope above it: each signal is split into its moving average over ``window``
    samples and the rest; the rest is compared by its moving RMS. The result is
    sign(d) sqrt(d^2 + e^2), d the difference of the slow parts, e that of the envelopes.

    Why: a self-excited oscillation (a chain hunting about the target with the loop
    closed on the table scale, stick-slip below the critical speed) has a frequency and an
    amplitude a model can reproduce, but not its phase: a time-domain difference of two
    such oscillations is larger than either. For white noise and for anything slower than
    the window the RMS of this residual equals that of the plain difference (the
    envelope of a fast signal has its RMS); a fast feature is judged by its amplitude
    where it occurs, to within the window, not by its sign. ``stacked``: (d, e) one after
    the other instead (the same sum of squares, smooth for a least-squares fit)."""
    n = max(1, int(window))
    if n < 3 or measured_um.size < 2 * n:
        return measured_um - simulated_um
    lm, em = slow_and_envelope(measured_um, n)
    ls, es = slow_and_envelope(simulated_um, n)
    d = lm - ls
    if stacked:
        return np.concatenate([d, em - es])
    return np.where(d < 0, -1.0, 1.0) * np.sqrt(d * d + (em - es) ** 2)


def _window(c: Contour) -> int:
    return int(round(ENVELOPE_WINDOW_S * c.rate_hz))


def contour_plain_residual_um(c: Contour, sim: Mapping[str, np.ndarray]) -> np.ndarray:
    """Measured minus simulated contour error (µm) on the scored samples (the data arc)."""
    k = c.scored
    return c.deviation_um({a: v[k] for a, v in c.table_mm.items()}) - c.deviation_um({a: v[k] for a, v in sim.items()})


def contour_residual_um(c: Contour, sim: Mapping[str, np.ndarray]) -> np.ndarray:
    """The scored contour residual (µm) on the data arc: :func:`envelope_residual_um` of the
    measured and simulated contour errors (what the gaps are computed from)."""
    k = c.scored
    meas = c.deviation_um({a: v[k] for a, v in c.table_mm.items()})
    return envelope_residual_um(meas, c.deviation_um({a: v[k] for a, v in sim.items()}), _window(c))


def tracking_envelope_residual_um(c: Contour, sim: Mapping[str, np.ndarray], axes: Sequence[str] | None = None,
                                  stacked: bool = False) -> np.ndarray:
    """Per-axis tracking residual on the scored samples, scored as :func:`contour_residual_um`."""
    k = c.scored
    return np.concatenate([envelope_residual_um(c.table_mm[a][k] * 1e3, sim[a][k] * 1e3, _window(c), stacked)
                           for a in (axes or c.axes)])  # fmt: skip


def tracking_residual_um(c: Contour, sim: Mapping[str, np.ndarray], axes: Sequence[str] | None = None) -> np.ndarray:
    i = c.fit_idx
    return np.concatenate([(c.table_mm[a][i] - sim[a][i]) * 1e3 for a in (axes or c.axes)])


def fit_backlash_on_contours(memo: SimMemo, contours: Sequence[Contour], axes: Mapping[str, AxisSpec], axis: str,
                             others_um: Mapping[str, float]) -> float:
    """Constant backlash of ``axis`` from train contours (bounded scalar fit of the tracking error)."""

    def cost(b):
        bl = dict(others_um)
        bl[axis] = b
        m = models_for(axes, bl)
        return sum(float(np.sum(tracking_residual_um(c, memo.table(c, m), [axis]) ** 2))
                   for c in contours if axis in c.axes)  # fmt: skip

    sol = minimize_scalar(cost, bounds=(0.0, 1000.0), method="bounded", options={"xatol": 0.2, "maxiter": 25})
    return float(sol.x)


def apparent_gain_per_s(contours: Sequence[Contour], axis: str) -> float | None:
    """Linearised servo start: the lag of the table behind the recorded command against
    the command's speed, e = v (1 - ff) / K_eff, as one apparent gain (least squares on
    the samples at steady speed, both directions, so the backlash offset cancels)."""
    vs, es = [], []
    for c in contours:
        if c.command_mm is None or axis not in c.axes:
            continue
        t = c.t_s
        cmd = c.command_mm[axis]
        v = np.gradient(cmd, t)
        a = np.gradient(v, t)
        vmax = float(np.max(np.abs(v))) if v.size else 0.0
        ok = (np.abs(v) > 0.3 * vmax) & (np.abs(a) < 0.2 * float(np.percentile(np.abs(a), 90)) + 1e-9)
        ok &= c.score if c.score is not None else True
        if ok.sum() > 20:
            e = cmd - c.table_mm[axis]
            vs.append(v[ok])
            es.append(e[ok])  # the backlash-like offsets are fitted as +-c below
    if not vs:
        return None
    v = np.concatenate(vs)
    e = np.concatenate(es)
    A = np.stack([v, np.sign(v)], axis=1)  # lag per speed, +- half backlash-like offset
    sol, *_ = np.linalg.lstsq(A, e, rcond=None)
    return float(1.0 / sol[0]) if sol[0] > 1e-6 else None
