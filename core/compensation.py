"""A bidirectional compensation table from a measured round trip.

Sign convention, used everywhere in mebm's compensation code
------------------------------------------------------------
    error e = actual - nominal   (µm)

*nominal* is l_0 = k_a x_m, the travel the motor (rotary) encoder reports: the position
a semi-closed loop, closed on that encoder, believes the table is at. *actual* is
l_a = x_l, the linear scale. ``e+`` is the error while moving in +, ``e-`` while moving
in -, and b(x) = e- - e+ (Eq. 5: the table lags the nut by b/2 in each direction, so
e+ sits b/2 below the midline and e- b/2 above it).

A controller corrects by commanding nominal - e: each writer (api.service.compensation)
turns e into what its format expects, and says which quantity each column holds.

The grid x_k spans the useful travel at ``step_mm``, coarsened (never refined) when a
format allows fewer points; positions are multiples of ``quantum_mm`` (0.1 µm, the unit
of the Beckhoff/ISG list), so every format writes them exactly. The values at x_k are
the analysis' smoothed curves there: a table can follow only features longer than about
two steps; :attr:`CompensationTable.interpolation_error_um` says how far the linearly
interpolated table strays from the measured curves between its points.

The absolute level of e is not observable from a round trip (the motor encoder has an
arbitrary zero): the analysis sets the midline (e+ + e-)/2 to a median of zero over the
travel. ``reference_mm`` moves that zero to one position instead (the reference point
of the axis, where a laser calibration would also start from zero).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.criteria.roundtrip import RoundTripResult
from core.errors import InputError

LOOP_ENCODERS = ("motor", "table")
QUANTUM_MM = 1e-4  # 0.1 µm
MAX_POINTS = 1_000_000  # a guard against a mistyped step, whatever the format allows


@dataclass(frozen=True)
class CompensationTable:
    """One axis' table on ``position_mm`` (x_k, nominal travel, uniform ``step_mm``):
    ``forward_error_um`` e+ and ``reverse_error_um`` e-, both actual - nominal."""

    axis: str
    position_mm: np.ndarray
    forward_error_um: np.ndarray
    reverse_error_um: np.ndarray
    step_mm: float
    requested_step_mm: float
    useful_travel_mm: tuple[float, float]
    backlash_mean_um: float
    backlash_mean_uncertainty_um: float | None
    interpolation_error_um: float
    reference_mm: float | None = None

    @property
    def backlash_um(self) -> np.ndarray:
        """b(x_k) = e- - e+ (Eq. 5), µm."""
        return self.reverse_error_um - self.forward_error_um

    @property
    def n_points(self) -> int:
        return int(self.position_mm.size)

    @property
    def coarsened(self) -> bool:
        return self.step_mm > self.requested_step_mm * (1 + 1e-9) + QUANTUM_MM


def _grid(start: float, end: float, step_mm: float, max_points: int | None, quantum_mm: float):
    first = math.ceil(start / quantum_mm - 1e-9) * quantum_mm
    length = end - first
    n_int = max(1, math.ceil(length / step_mm - 1e-9))
    if max_points is not None and n_int + 1 > max_points:
        n_int = max_points - 1  # coarsen to the format's limit
    if n_int + 1 > MAX_POINTS:
        raise InputError(f"step_mm (={step_mm:g}) would give {n_int + 1} points over {length:g} mm "
                         f"(at most {MAX_POINTS})")
    step = math.floor(length / n_int / quantum_mm + 1e-9) * quantum_mm  # last point <= end
    if step < quantum_mm:
        raise InputError(f"useful travel {start:g}..{end:g} mm is too short for a compensation table")
    return first + step * np.arange(n_int + 1), step


def compensation_table(
    result: RoundTripResult,
    *,
    step_mm: float = 5.0,
    max_points: int | None = None,
    reference_mm: float | None = None,
    quantum_mm: float = QUANTUM_MM,
) -> CompensationTable:
    """The table of one analysed round trip (``core.criteria.analyze_round_trip``).

    ``step_mm`` is the wanted spacing of x_k; ``max_points`` a format's limit (the step
    grows to respect it, and the table says so); ``reference_mm`` a position in the
    useful travel where the midline (e+ + e-)/2 is set to zero (None: the analysis'
    alignment, median midline zero)."""
    if not (isinstance(step_mm, (int, float)) and math.isfinite(step_mm) and step_mm > 0):
        raise InputError(f"step_mm (={step_mm!r}) must be a number > 0")
    if max_points is not None and max_points < 2:
        raise InputError(f"max_points (={max_points}) must be >= 2")
    pos, neg = result.strokes["positive"], result.strokes["negative"]
    x = np.asarray(pos.position_mm, dtype=float)
    fwd = np.asarray(pos.travel_deviation_um, dtype=float)
    rev = np.asarray(neg.travel_deviation_um, dtype=float)
    start, end = float(x[0]), float(x[-1])
    if reference_mm is not None:
        if not (math.isfinite(reference_mm) and start <= reference_mm <= end):
            raise InputError(f"reference_mm (={reference_mm!r}) must lie in the useful travel {start:g}..{end:g} mm")
        shift = -0.5 * (np.interp(reference_mm, x, fwd) + np.interp(reference_mm, x, rev))
        fwd, rev = fwd + shift, rev + shift
    grid, step = _grid(start, end, float(step_mm), max_points, quantum_mm)
    e_fwd, e_rev = np.interp(grid, x, fwd), np.interp(grid, x, rev)
    inside = x <= grid[-1] + 1e-12
    stray = max(
        float(np.max(np.abs(np.interp(x[inside], grid, e) - f[inside]))) for e, f in ((e_fwd, fwd), (e_rev, rev))
    )
    u = result.budgets.get("backlash_mean") if result.budgets else None
    return CompensationTable(
        axis=result.axis,
        position_mm=grid,
        forward_error_um=e_fwd,
        reverse_error_um=e_rev,
        step_mm=float(step),
        requested_step_mm=float(step_mm),
        useful_travel_mm=(start, end),
        backlash_mean_um=float(result.backlash_mean_um),
        backlash_mean_uncertainty_um=None if u is None else float(u.expanded_um),
        interpolation_error_um=stray,
        reference_mm=None if reference_mm is None else float(reference_mm),
    )
