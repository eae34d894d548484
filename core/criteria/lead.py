"""Lead error criteria after ISO 3408-3 (Eqs. 1-3) for one stroke direction.

On a grid of nominal travel l_0 = k_a x_m over the useful travel, the actual travel
l_a = x_l is fitted by least squares (the actual mean travel l_m). Then
e_p = (l_m - l_0) across the useful travel, v_u = band of l_a - l_m over the useful
travel (Eq. 1), v_300 = largest band within any 300 mm (Eq. 2; the whole travel if
shorter) and v_2pi = largest band within any one screw lead (Eq. 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

from core.errors import InputError

# ISO 3408-3's names of the criteria, for every place a person reads them (dashboard,
# CLI, docs); the symbols stay the keys of results and JSON.
CRITERION_NAMES = {
    "e_p": "mean travel deviation",
    "v_u": "travel variation over the useful travel",
    "v_300": "travel variation within 300 mm",
    "v_2pi": "travel variation within one revolution (2π rad)",
}
CRITERION_SYMBOLS = {"e_p": "e_p", "v_u": "v_u", "v_300": "v_300", "v_2pi": "v_2π"}


def criterion_label(key: str) -> str:
    """The name and symbol of a lead criterion (``"v_u"`` or ``"v_u_um"``), e.g.
    "travel variation within 300 mm v_300"."""
    base = next((k for k in sorted(CRITERION_NAMES, key=len, reverse=True) if key.startswith(k)), None)
    if base is None:
        raise KeyError(f"{key!r} is not a lead criterion (one of {', '.join(CRITERION_NAMES)})")
    return f"{CRITERION_NAMES[base]} {CRITERION_SYMBOLS[base]}"


@dataclass(frozen=True)
class LeadCriteria:
    """ISO 3408-3 criteria of one direction. Curves are in µm on ``position_mm``:
    ``travel_deviation_um`` is l_a - l_0 and ``mean_travel_deviation_um`` l_m - l_0
    (both relative to the alignment of the two directions' midline)."""

    direction: str
    position_mm: np.ndarray
    travel_deviation_um: np.ndarray
    mean_travel_deviation_um: np.ndarray
    e_p_um: float
    e_p_um_per_1000mm: float
    v_u_um: float
    v_300_um: float
    v_2pi_um: float | None  # None: the screw lead, its window, is not known
    n_strokes: int

    def to_dict(self) -> dict:
        return {
            "direction": self.direction,
            "e_p_um": self.e_p_um,
            "e_p_um_per_1000mm": self.e_p_um_per_1000mm,
            "v_u_um": self.v_u_um,
            "v_300_um": self.v_300_um,
            "v_2pi_um": self.v_2pi_um,
            "n_strokes": self.n_strokes,
        }


def max_window_band(values: np.ndarray, window_points: int) -> float:
    """Largest max-min of ``values`` over any ``window_points`` consecutive points, O(n).

    Centred windows clipped at the ends are subsets of the first or last full window,
    so taking the maximum over every centre equals the maximum over full windows.
    """
    w = int(min(max(window_points, 1), values.shape[0]))
    band = maximum_filter1d(values, size=w, mode="nearest") - minimum_filter1d(values, size=w, mode="nearest")
    return float(band.max())


def lead_criteria(
    position_mm: np.ndarray,
    deviation_mm: np.ndarray,
    *,
    direction: str,
    screw_lead_mm: float | None,
    n_strokes: int = 1,
    window_300_mm: float = 300.0,
) -> LeadCriteria:
    """Criteria from l_a - l_0 (``deviation_mm``) sampled on a uniform grid ``position_mm``.
    Without ``screw_lead_mm`` (None) v_2π, whose window it is, is None; the rest is computed."""
    x = np.asarray(position_mm, dtype=float)
    d = np.asarray(deviation_mm, dtype=float)
    if x.shape != d.shape or x.shape[0] < 3:
        raise InputError("position_mm and deviation_mm must be equal-length arrays of >= 3 points")
    step = float(x[1] - x[0])
    if not step > 0 or not np.allclose(np.diff(x), step, rtol=1e-6, atol=1e-9):
        raise InputError("position_mm must be a uniform increasing grid")
    length = float(x[-1] - x[0])
    slope, intercept = np.polyfit(x - x[0], d, 1)  # l_m - l_0, least squares
    fit = intercept + slope * (x - x[0])
    residual_um = (d - fit) * 1e3  # l_a - l_m
    points_300 = int(round(min(window_300_mm, length) / step)) + 1
    points_2pi = int(round(min(screw_lead_mm, length) / step)) + 1 if screw_lead_mm is not None else None
    return LeadCriteria(
        direction=direction,
        position_mm=x,
        travel_deviation_um=d * 1e3,
        mean_travel_deviation_um=fit * 1e3,
        e_p_um=float(slope * length * 1e3),
        e_p_um_per_1000mm=float(slope * 1e6),
        v_u_um=float(np.ptp(residual_um)),  # Eq. 1
        v_300_um=max_window_band(residual_um, points_300),  # Eq. 2
        v_2pi_um=max_window_band(residual_um, points_2pi) if points_2pi is not None else None,  # Eq. 3
        n_strokes=n_strokes,
    )
