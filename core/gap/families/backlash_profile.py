"""The backlash-profile family: a backlash width that changes along the travel."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from core.dataset import AxisSpec
from core.gap.data import RoundTrip
from core.gap.families.base import Family
from core.gap.stages import Stage
from core.sim import BacklashProfile

NAME = "backlash_profile"
N_KNOTS = 7  # knots over the characterised travel, at least
PROFILE_KNOT_SPACING_MM = 40.0  # ... and at most this far apart (up to PROFILE_MAX_KNOTS)
PROFILE_MAX_KNOTS = 31
PROFILE_SMOOTHNESS_WEIGHT = 0.05  # µm of residual per µm of second difference between knots


def profile_knots(lo_mm: float, hi_mm: float) -> np.ndarray:
    """Knots of the backlash profile over the characterised travel [lo, hi]: at most
    PROFILE_KNOT_SPACING_MM apart, N_KNOTS to PROFILE_MAX_KNOTS of them."""
    n = int(np.clip(math.ceil((hi_mm - lo_mm) / PROFILE_KNOT_SPACING_MM) + 1, N_KNOTS, PROFILE_MAX_KNOTS))
    return np.linspace(lo_mm, hi_mm, n)


def seen_knots(knots: np.ndarray, strokes_mm: Sequence[np.ndarray]) -> np.ndarray:
    """The knots some train sample weighs on: a sample strictly between a knot's two
    neighbours (the end knots always). A knot inside a stretch no train stroke crossed
    is a parameter the data never exercise: it would leave J'J singular and every
    parameter of the fit "not identifiable" (``core.gap.roundtrip.intervals``) whatever
    the rest of the travel shows; without it the profile is straight across the
    stretch, as the smoothness prior would draw it."""
    keep = np.zeros(knots.size, dtype=bool)
    keep[[0, -1]] = True
    for i in range(1, knots.size - 1):
        a, b = knots[i - 1], knots[i + 1]
        keep[i] = any(bool(np.any((u > a) & (u < b))) for u in strokes_mm)
    return knots[keep]


def knot_names(knots: np.ndarray) -> tuple[str, ...]:
    """The parameter names of the knots after the first, ``backlash_change_at_<mm>mm_um``,
    in whole millimetres where that tells them apart (knots 1 mm apart and more: a travel
    of 6 mm and more), else with as many decimals as it takes: two knots of one name
    would be one parameter of the report."""
    for decimals in range(7):
        names = tuple(f"backlash_change_at_{k:.{decimals}f}mm_um" for k in knots[1:])
        if len(set(names)) == len(names):
            return names
    return tuple(f"backlash_change_at_{k:.6f}mm_{i}_um" for i, k in enumerate(knots[1:], 1))


def profile_stage(runs: Sequence[RoundTrip], axis: AxisSpec) -> Stage:
    """Backlash width along the travel, piecewise linear on knots at most 40 mm apart
    (7 to 31 over the characterised travel) with a weak smoothness prior: one or several
    wear bumps down to about 50 mm wide (a nut's length: a screw wears where the nut
    works), a ramp. The knots are at most 40 mm apart, not a fixed seven over the travel:
    seven knots (travel / 6 apart) miss a bump of a nut's length on a long travel. The
    result depends on where the knots fall, not monotonically on their number (a choice
    of the spacing by cross-validation is not built). A knot between train strokes that
    no sample reaches is left out (:func:`seen_knots`). Not covered: features shorter than
    the knot spacing, a width that differs between directions, the travel no train round
    trip crossed (the profile is flat beyond it, straight across a stretch between two
    strokes)."""
    lo = min(float(np.min(r.u_mm)) for r in runs)
    hi = max(float(np.max(r.u_mm)) for r in runs)
    knots = seen_knots(profile_knots(lo, hi), [r.u_mm for r in runs])
    n = knots.size

    def width(th, run, u, hb):
        return hb + 0.5e-3 * np.interp(u, knots, np.r_[0.0, th])

    def prior(th):
        return PROFILE_SMOOTHNESS_WEIGHT * np.diff(np.r_[0.0, th], 2)

    names = knot_names(knots)
    return Stage(NAME, names, np.zeros(n - 1), np.full(n - 1, -500.0),
                 np.full(n - 1, 1000.0), info={"positions_mm": knots.tolist()}, width=width,
                 prior=prior)  # fmt: skip



def sim_piece(p: Mapping[str, float], info: Mapping, axis: AxisSpec, b_um: float) -> tuple[object | None, float]:
    pos = info["positions_mm"]
    deltas = [0.0] + [p[k] for k in p if k.startswith("backlash_change_at_")]
    return BacklashProfile(tuple(pos), tuple(max(0.0, b_um + d) for d in deltas)), 0.0


FAMILY = Family(NAME, profile_stage.__doc__, lambda runs, axis, resid: profile_stage(runs, axis), sim_piece=sim_piece)
