"""The cyclic-error family: a periodic transmission error of the nut travel."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.stats import chi2

from core.dataset import AxisSpec
from core.gap.families.base import Family
from core.gap.roundtrip import residual_periods_mm
from core.gap.stages import Stage
from core.sim import CyclicError

NAME = "cyclic_error"
N_PERIODS = 2  # components


def _sines_mm(th: np.ndarray, at_mm: np.ndarray, periods_mm: np.ndarray) -> np.ndarray:
    """sum_i 1e-3 (th[2i] sin(2 pi x / p_i) + th[2i+1] cos(2 pi x / p_i)) at positions ``at_mm``:
    the error (mm) of sine and cosine amplitudes ``th`` in µm."""
    out = np.zeros_like(at_mm, dtype=float)
    for i, p in enumerate(periods_mm):
        arg = 2 * np.pi * at_mm / p
        out = out + 1e-3 * (th[2 * i] * np.sin(arg) + th[2 * i + 1] * np.cos(arg))
    return out


def cyclic_stage(periods_mm: Sequence[float]) -> Stage:
    """Periodic transmission error u + sum a_i sin(2 pi u / p_i + phi_i) at the strongest
    periods of the residual (0.5-60 mm, found freely: screw lead, k_a, a gear or belt
    stage, their harmonics). Not covered: periods longer than a third of the stroke,
    amplitudes that change along the travel."""
    per = np.asarray(periods_mm, float)

    def u_map(th, run, u):
        return u + _sines_mm(th, u, per)

    names: list[str] = []
    for p in per:
        names += [f"sin_{p:.3f}mm_um", f"cos_{p:.3f}mm_um"]
    # amplitude bound: 50 µm, and a slope of the error (2 pi A / p) below 0.2, so the
    # nut never nearly stops (the twin refuses 0.5)
    lim = np.repeat(np.minimum(50.0, 0.2 * per * 1e3 / (2 * np.pi) / math.sqrt(2)), 2)
    return Stage(NAME, tuple(names), np.zeros(2 * per.size), -lim, lim,
                 info={"periods_mm": per.tolist()}, u_map=u_map)  # fmt: skip


def scale_stage(period_mm: float) -> Stage:
    """The linear scale's interpolation error: the reading is x + sum a_h sin(2 pi h x / p
    + phi_h) for the scale's signal period p (20-40 µm on incremental scales, found in the
    round trips, :func:`scale_period_mm`) and its second harmonic h = 2, at the table
    position x. An error of the reading alone: the chain and the loop follow the true table
    (on a loop closed on the scale the loop would follow the reading: not covered), and
    its amplitude is the same all along the travel (a scale whose error changes along
    its length: not covered)."""
    per = np.array([period_mm, period_mm / 2.0])

    def out_map(th, run, x):
        # the phase from where the table is: the model's table corrected by the slow part of
        # what the scale reads beyond it (a screw a few ppm longer than the scale, the chain's
        # slow motion: µm that turn a 30 µm period's phase along a long stroke); the scale's
        # own error averages out of that part over its many periods
        at = x + uniform_filter1d(run.x_mm - x, max(1, int(round(SCALE_REFERENCE_S / run.dt_s))), mode="nearest")
        return x + _sines_mm(th, at, per)

    names: list[str] = []
    for p in per:
        names += [f"scale_sin_{p * 1e3:.3f}um_um", f"scale_cos_{p * 1e3:.3f}um_um"]
    lim = np.full(2 * per.size, SCALE_MAX_AMPLITUDE_UM)
    return Stage(NAME, tuple(names), np.zeros(2 * per.size), -lim, lim,
                 info={"periods_mm": per.tolist(), "on": "scale"}, out_map=out_map)  # fmt: skip


# The scale's signal periods searched (µm): 20-40 µm on incremental scales, with a margin.
SCALE_PERIODS_UM = (15.0, 50.0)
SCALE_MAX_AMPLITUDE_UM = 10.0
SCALE_WINDOW_MM = 2.0  # the stretches whose periodograms are summed (the search's resolution)
SCALE_FALSE_ALARM = 1e-3  # the chance that white noise alone passes the search's test
SCALE_MIN_ALIAS_CYCLES = 2.0  # cycles over a stretch below which its samples cannot show a period
SCALE_REFERENCE_S = 0.05  # the slow part of the table's position, as the round trips' scores split it


def _stretches(runs) -> list[tuple[np.ndarray, np.ndarray]]:
    """(table position, table minus motor in µm) of every moving sample, one pair per stroke
    direction of a run, cut into SCALE_WINDOW_MM stretches, each with its mean and slope
    taken out.

    The table given the motor, not the reference model's residual: that is kept on the
    fit's samples, which a long round trip thins (one in four: 120-170 µm apart at
    2000-3700 mm/min, several signal periods), while every recorded sample counts here. Over
    a stretch the chain's lost motion is a constant and its slow motion a slope; what is
    left of a period of tens of µm is the scale's."""
    out = []
    for run in runs:
        x = run.x_mm
        v = np.gradient(run.u_mm, run.t_s)
        r = (run.x_mm - run.u_mm) * 1e3
        moving = np.abs(v) > 0.3 * np.percentile(np.abs(v), 95)
        for sgn in (1, -1):
            m = moving & (np.sign(v) == sgn)
            if m.sum() < 20:
                continue
            xm, rm = x[m], r[m]
            cut = np.floor((xm - xm.min()) / SCALE_WINDOW_MM).astype(int)
            for k in np.unique(cut):
                w = cut == k
                if w.sum() < 12:
                    continue
                xw, rw = xm[w], rm[w]
                a = np.vstack([np.ones_like(xw), xw - xw.mean()]).T
                rw = rw - a @ np.linalg.lstsq(a, rw, rcond=None)[0]
                out.append((xw, rw))
    return out


def scale_period_mm(runs) -> float | None:
    """The scale's signal period in the table given the motor (mm), or None where there is none.

    Summed periodograms of short stretches, then one coherent periodogram about the best
    period. Each stretch (SCALE_WINDOW_MM of one stroke direction) gives the share of its
    residual's variance that a sine of each period explains; n times that share is chi^2
    with 2 degrees of freedom under white noise, so the sum over the W stretches is
    chi^2(2W), tested at a false-alarm chance of SCALE_FALSE_ALARM over the periods searched.
    A feed aliases a period shorter than two samples' spacing into another within one
    stretch; stretches run at other feeds or while accelerating alias it elsewhere, so only
    the true period adds up over all of them. A stretch whose samples alias a period to
    fewer than SCALE_MIN_ALIAS_CYCLES over its length does not count for that period. The
    coherent step (every stretch on one position axis: the error is a function of the
    scale's position) then sharpens it."""
    parts = _stretches(runs)
    if len(parts) < 3:
        return None
    f_lo, f_hi = 1e3 / SCALE_PERIODS_UM[1], 1e3 / SCALE_PERIODS_UM[0]  # cycles per mm
    step = 1.0 / (4.0 * SCALE_WINDOW_MM)
    f = np.arange(f_lo, f_hi + step, step)
    total = np.zeros(f.size)
    dof = np.zeros(f.size)
    for xw, rw in parts:
        ss = float(rw @ rw)
        spacing = float(np.median(np.abs(np.diff(xw))))
        if ss <= 0 or not spacing > 0:
            continue
        # a period the stretch's samples alias to fewer than SCALE_MIN_ALIAS_CYCLES over the
        # stretch looks like its own slow motion (a sample spacing equal to the period
        # reads the error as a constant): not observable there
        fold = np.mod(f, 1.0 / spacing)
        seen = np.minimum(fold, 1.0 / spacing - fold) * float(np.ptp(xw)) >= SCALE_MIN_ALIAS_CYCLES
        if not seen.any():
            continue
        arg = 2 * np.pi * np.outer(f[seen], xw)
        sn, cs = np.sin(arg), np.cos(arg)
        # the explained sum of squares of a sine and a cosine (nearly orthogonal over a stretch)
        explained = (sn @ rw) ** 2 / np.maximum((sn * sn).sum(1), 1e-12) + (cs @ rw) ** 2 / np.maximum(
            (cs * cs).sum(1), 1e-12)
        total[seen] += rw.size * explained / ss
        dof[seen] += 2.0
    ok = dof >= 6.0
    if not ok.any():
        return None
    log_p = np.full(f.size, 0.0)
    log_p[ok] = chi2.logsf(total[ok], dof[ok])
    independent = (f_hi - f_lo) * SCALE_WINDOW_MM
    passed = log_p <= np.log(SCALE_FALSE_ALARM / max(independent, 1.0))
    if not passed.any():
        return None
    # among the periods that pass, the one that explains most beyond what noise would (the
    # chi^2's mean is its degrees of freedom): an alias is seen in some stretches only
    excess = np.where(passed, total - dof, -np.inf)
    best = float(f[np.argmax(excess)])
    x = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    span = max(float(np.ptp(x)), SCALE_WINDOW_MM)
    fine = np.arange(best - step, best + step, 1.0 / (8.0 * span))
    if x.size > MAX_SCALE_SAMPLES:
        keep = np.linspace(0, x.size - 1, MAX_SCALE_SAMPLES).astype(int)
        x, y = x[keep], y[keep]
    power = np.zeros(fine.size)
    for j0 in range(0, fine.size, 256):  # in blocks: periods x samples
        arg = 2 * np.pi * np.outer(fine[j0:j0 + 256], x)
        power[j0:j0 + 256] = (np.sin(arg) @ y) ** 2 + (np.cos(arg) @ y) ** 2
    return float(1.0 / fine[np.argmax(power)])


MAX_SCALE_SAMPLES = 20000


def _factory(runs, axis, resid):
    periods, _ = residual_periods_mm(runs, resid, axis.screw_lead_mm, axis.transmission_mm_per_rev, N_PERIODS)
    nut = cyclic_stage(periods)
    p = scale_period_mm(runs)
    return nut if p is None else (nut, scale_stage(p))


def sim_piece(p: Mapping[str, float], info: Mapping, axis: AxisSpec, b_um: float) -> tuple[object | None, float]:
    comps = []
    on = info.get("on", "nut")
    for per in info["periods_mm"]:
        key = f"scale_{{}}_{per * 1e3:.3f}um_um" if on == "scale" else f"{{}}_{per:.3f}mm_um"
        a, b = p[key.format("sin")], p[key.format("cos")]
        if math.hypot(a, b) > 0:
            comps.append((per, math.hypot(a, b), math.degrees(math.atan2(b, a))))
    return (CyclicError.of(*comps, on=on) if comps else None), 0.0


FAMILY = Family(NAME, f"{cyclic_stage.__doc__}\n\n{scale_stage.__doc__}", _factory, sim_piece=sim_piece)
