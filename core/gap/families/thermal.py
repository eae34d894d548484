"""The thermal family: lead growth and backlash change with temperature."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from core.dataset import AxisSpec
from core.gap.data import RoundTrip
from core.gap.families.base import NOT_IDENTIFIABLE, Family
from core.gap.roundtrip import REFERENCE_C
from core.gap.stages import Stage
from core.sim import Thermal

NAME = "thermal"


def _dt_c(run: RoundTrip) -> float:
    return run.temperature_c - REFERENCE_C


def thermal_stage(runs: Sequence[RoundTrip], axis: AxisSpec) -> Stage | None:
    """Lead growth with temperature about any bearing point (a bearing offset is a
    constant shift, absorbed by the per-run offset), a temperature-independent lead
    error, and a backlash that changes linearly with temperature. Not covered: a
    gradient along the screw (non-uniform heating), hysteresis between warming and
    cooling, a growth that changes during a run (one growth per run, set by the run's
    temperature)."""
    temps = [r.temperature_c for r in runs]
    if max(temps) - min(temps) < 1.0:
        return None
    fixed = axis.travel_mm[0]

    def u_map(th, run, u):
        return fixed + (u - fixed) * (1.0 + (th[1] + th[2] * _dt_c(run)) * 1e-6)

    def width(th, run, u, hb):
        return hb + 0.5e-3 * th[0] * _dt_c(run)

    return Stage(NAME, ("backlash_um_per_k", "lead_error_um_per_m", "lead_growth_ppm_per_k"),
                 np.zeros(3), np.array([-20.0, -500.0, -40.0]), np.array([20.0, 500.0, 40.0]),
                 u_map=u_map, width=width)  # fmt: skip



def sim_piece(p: Mapping[str, float], info: Mapping, axis: AxisSpec, b_um: float) -> tuple[object | None, float]:
    return Thermal(lead_error_um_per_m=p["lead_error_um_per_m"], lead_growth_ppm_per_k=p["lead_growth_ppm_per_k"],
                   backlash_um_per_k=p["backlash_um_per_k"], fixed_end_mm=axis.travel_mm[0]), 0.0  # fmt: skip


def identifiable(d, f) -> tuple[bool, str | None]:
    """Not identifiable where no round-trip axis took it and a round-trip axis could not
    fit it (its train round trips at one temperature)."""
    if not any(a in f.rt_fits and NAME in f.rt_fits[a].effects for a in d.rt_axes):
        if any(NOT_IDENTIFIABLE in n for n in f.notes):
            return False, None
    return True, None


FAMILY = Family(NAME, thermal_stage.__doc__, lambda runs, axis, resid: thermal_stage(runs, axis), sim_piece=sim_piece,
                identifiable=identifiable, no_stage_reason="train round trips at one temperature")  # fmt: skip
