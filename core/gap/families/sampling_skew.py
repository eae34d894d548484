"""The sampling-skew family: the table encoder latched later or earlier than the motor."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from core.dataset import AxisSpec
from core.gap.families.base import Family
from core.gap.stages import Stage
from core.sim import SamplingSkew

NAME = "sampling_skew"


def skew_stage() -> Stage:
    """The table encoder latched later (or earlier) than the motor: a delay that may
    drift linearly over a run (clock drift, a changing bus load). Not covered: random
    jitter (it shows as noise), a delay that jumps mid-run."""

    def out_map(th, run, x):
        t = run.t_s
        span = max(float(t[-1] - t[0]), 1e-9)
        tau = 1e-3 * (th[0] + th[1] * ((t - t[0]) / span - 0.5))
        return np.interp(t + tau, t, x)

    return Stage(NAME, ("table_delay_ms", "delay_drift_ms"), np.zeros(2), np.array([-20.0, -20.0]),
                 np.array([20.0, 20.0]), out_map=out_map,
                 starts=tuple(np.array([tau, 0.0]) for tau in (-6.0, -3.0, -1.0, 1.0, 3.0, 6.0)))  # fmt: skip


def sim_piece(p: Mapping[str, float], info: Mapping, axis: AxisSpec, b_um: float) -> tuple[object | None, float]:
    # on contours the mean delay (a drift within a run is left out)
    return SamplingSkew(table_delay_s=1e-3 * p["table_delay_ms"]), 0.0


FAMILY = Family(NAME, skew_stage.__doc__, lambda runs, axis, resid: skew_stage(), sim_piece=sim_piece)
