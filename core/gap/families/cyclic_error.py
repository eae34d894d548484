"""The cyclic-error family: a periodic transmission error of the nut travel."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from core.dataset import AxisSpec
from core.gap.families.base import Family
from core.gap.roundtrip import residual_periods_mm
from core.gap.stages import Stage
from core.sim import CyclicError

NAME = "cyclic_error"
N_PERIODS = 2  # components


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
    return Stage(NAME, tuple(names), np.zeros(2 * per.size), -lim, lim,
                 info={"periods_mm": per.tolist()}, u_map=u_map)  # fmt: skip


def _factory(runs, axis, resid):
    periods, _ = residual_periods_mm(runs, resid, axis.screw_lead_mm, axis.transmission_mm_per_rev, N_PERIODS)
    return cyclic_stage(periods)


def sim_piece(p: Mapping[str, float], info: Mapping, axis: AxisSpec, b_um: float) -> tuple[object | None, float]:
    comps = []
    for per in info["periods_mm"]:
        a, b = p[f"sin_{per:.3f}mm_um"], p[f"cos_{per:.3f}mm_um"]
        if math.hypot(a, b) > 0:
            comps.append((per, math.hypot(a, b), math.degrees(math.atan2(b, a))))
    return (CyclicError.of(*comps) if comps else None), 0.0


FAMILY = Family(NAME, cyclic_stage.__doc__, _factory, sim_piece=sim_piece)
