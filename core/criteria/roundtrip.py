"""Analysis of one programmed round trip of an axis (Section 3 of the seed paper).

From time, motor position (rev) and table position (mm) of one axis:
1. check the trace is trustworthy (finite, time increasing, motor moving, k_a plausible);
2. find the strokes and drop the reversal transients (``segmentation``);
3. average each direction's l_a - l_0 into bins of a uniform grid over the useful
   travel, and smooth lightly (features longer than ``smoothing_mm`` are kept);
4. backlash profile b(x) = x_l- - x_l+ at equal nominal travel (Eq. 5, Fig. 9);
5. lead criteria per direction (Eqs. 1-3, ``lead``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from core.criteria.lead import LeadCriteria, lead_criteria
from core.criteria.segmentation import SegmentationSettings, Stroke, find_strokes
from core.dataset import AxisSpec
from core.errors import InputError, TraceError


@dataclass(frozen=True)
class RoundTripSettings:
    """How a round trip is reduced. ``grid_step_mm`` is the resolution of b(x) and of
    the lead curves; ``smoothing_mm`` the Savitzky-Golay (cubic) window applied to
    the binned curves (0 disables it); ``max_gap_mm`` the largest stretch without
    samples that may be interpolated over; ``max_ratio_error`` how far table and
    motor travel may disagree before k_a or the units are declared wrong."""

    grid_step_mm: float = 0.25
    smoothing_mm: float = 2.0
    max_gap_mm: float = 2.0
    max_ratio_error: float = 0.05
    min_motion_mm: float = 0.1
    segmentation: SegmentationSettings = field(default_factory=SegmentationSettings)


@dataclass(frozen=True)
class BacklashProfile:
    """b(x) in µm on ``position_mm`` (nominal travel, table coordinates) and its statistics."""

    position_mm: np.ndarray
    backlash_um: np.ndarray
    mean_um: float
    min_um: float
    max_um: float
    std_um: float


@dataclass(frozen=True)
class RoundTripResult:
    axis: str
    useful_travel_mm: tuple[float, float]
    backlash: BacklashProfile
    strokes: dict[str, LeadCriteria]
    n_samples: int
    peak_speed_mm_min: float

    @property
    def backlash_mean_um(self) -> float:
        return self.backlash.mean_um

    def to_dict(self, *, curves: bool = False) -> dict:
        """JSON-ready summary; the top-level lead criteria are the positive stroke's."""
        pos = self.strokes["positive"]
        out = {
            "axis": self.axis,
            "useful_travel_mm": list(self.useful_travel_mm),
            "n_samples": self.n_samples,
            "peak_speed_mm_min": self.peak_speed_mm_min,
            "backlash_mean_um": self.backlash.mean_um,
            "backlash_min_um": self.backlash.min_um,
            "backlash_max_um": self.backlash.max_um,
            "backlash_std_um": self.backlash.std_um,
            "e_p_um": pos.e_p_um,
            "e_p_um_per_1000mm": pos.e_p_um_per_1000mm,
            "v_u_um": pos.v_u_um,
            "v_300_um": pos.v_300_um,
            "v_2pi_um": pos.v_2pi_um,
            "strokes": {name: s.to_dict() for name, s in self.strokes.items()},
        }
        if curves:
            out["curves"] = {
                "position_mm": self.backlash.position_mm.tolist(),
                "backlash_um": self.backlash.backlash_um.tolist(),
                **{
                    f"{name}_travel_deviation_um": s.travel_deviation_um.tolist()
                    for name, s in self.strokes.items()
                },
            }
        return out


def _check_trace(time_s, motor_rev, table_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    arrays = []
    for name, a in (("time_s", time_s), ("motor_rev", motor_rev), ("table_mm", table_mm)):
        try:
            a = np.asarray(a, dtype=float)
        except (TypeError, ValueError) as exc:
            raise TraceError(f"{name} must hold numbers ({exc})") from None
        if a.ndim != 1:
            raise TraceError(f"{name} must be one-dimensional, got shape {a.shape}")
        bad = ~np.isfinite(a)
        if bad.any():
            i = int(np.argmax(bad))
            raise TraceError(f"{name} has a NaN or inf sample at index {i} ({int(bad.sum())} in all)")
        arrays.append(a)
    t, m, x = arrays
    if not (t.shape == m.shape == x.shape):
        raise TraceError(f"time_s, motor_rev and table_mm differ in length: {t.size}, {m.size}, {x.size}")
    if t.size < 10:
        raise TraceError(f"a round trip needs at least 10 samples, got {t.size}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0)) + 1
        raise TraceError(f"time_s not strictly increasing at index {i} ({t[i - 1]!r} then {t[i]!r})")
    return t, m, x


def _bin_direction(
    strokes: list[Stroke], travel: np.ndarray, dev: np.ndarray, grid: np.ndarray, step: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroids (mean travel, mean deviation) per grid bin over all strokes of one
    direction, and the sample counts. Averaging the travel too removes the bias of
    where the samples fall inside a bin (lead slope x half a bin) to second order."""
    n = grid.size
    sel = [slice(s.engaged, s.end + 1) for s in strokes]
    u = np.concatenate([travel[k] for k in sel])
    val = np.concatenate([dev[k] for k in sel])
    idx = np.rint((u - grid[0]) / step).astype(np.int64)
    inside = (idx >= 0) & (idx < n)
    idx, u, val = idx[inside], u[inside], val[inside]
    counts = np.bincount(idx, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        u_c = np.bincount(idx, weights=u - grid[idx], minlength=n) / counts + grid
        d_c = np.bincount(idx, weights=val, minlength=n) / counts
    return u_c, d_c, counts


def analyze_round_trip(
    time_s,
    motor_rev,
    table_mm,
    axis: AxisSpec,
    *,
    useful_travel_mm: tuple[float, float] | None = None,
    settings: RoundTripSettings = RoundTripSettings(),
) -> RoundTripResult:
    """Backlash profile and lead criteria of one axis from one round trip.

    ``useful_travel_mm`` defaults to the axis' ``travel_mm`` and is in table
    coordinates. Raises :class:`TraceError` for a trace that cannot be trusted.
    """
    t, motor, table = _check_trace(time_s, motor_rev, table_mm)
    start, end = useful_travel_mm if useful_travel_mm is not None else axis.travel_mm
    if not end > start:
        raise InputError(f"useful_travel_mm (={[start, end]}) must be [start, end] with end > start")
    if not settings.grid_step_mm > 0:
        raise InputError(f"grid_step_mm (={settings.grid_step_mm}) must be > 0")
    nominal = motor * axis.transmission_mm_per_rev  # l_0 = k_a x_m, arbitrary zero
    motor_span = float(np.ptp(nominal))
    if motor_span < settings.min_motion_mm:
        raise TraceError(f"the motor does not move (nominal travel span {motor_span * 1e3:.1f} µm)")
    table_span = float(np.ptp(table))
    ratio = table_span / motor_span
    if abs(ratio - 1.0) > settings.max_ratio_error:
        raise TraceError(
            f"table travel {table_span:.3f} mm and nominal motor travel {motor_span:.3f} mm disagree by "
            f"{(ratio - 1) * 100:+.1f} % (> {settings.max_ratio_error * 100:.0f} %): "
            f"check transmission_mm_per_rev (={axis.transmission_mm_per_rev}) and the units"
        )
    strokes = find_strokes(t, nominal, table, settings.segmentation)
    by_dir = {d: [s for s in strokes if s.direction == d] for d in (1, -1)}
    if not by_dir[1] or not by_dir[-1]:
        only = "positive" if by_dir[1] else "negative"
        raise TraceError(f"a round trip needs a stroke in each direction; found only {only} stroke(s)")

    # Align l_0 with table coordinates: the midline between the two directions.
    raw_dev = table - nominal
    med = [np.median(np.concatenate([raw_dev[s.engaged : s.end + 1] for s in by_dir[d]])) for d in (1, -1)]
    offset = 0.5 * (med[0] + med[1])
    travel = nominal + offset
    dev = raw_dev - offset

    step = settings.grid_step_mm
    n = int(round((end - start) / step)) + 1
    grid = start + step * np.arange(n)
    curves = {}
    for d, name in ((1, "positive"), (-1, "negative")):
        u_c, d_c, counts = _bin_direction(by_dir[d], travel, dev, grid, step)
        filled = counts > 0
        covered = grid[filled]
        if not filled[0] or not filled[-1]:
            lo = float(covered[0]) if covered.size else float("nan")
            hi = float(covered[-1]) if covered.size else float("nan")
            raise TraceError(
                f"the {name} stroke covers {lo:.2f}..{hi:.2f} mm outside its reversal transient, "
                f"shorter than the useful travel {start:g}..{end:g} mm asked for"
            )
        holes = np.diff(covered)
        if holes.size and holes.max() > settings.max_gap_mm:
            i = int(np.argmax(holes))
            raise TraceError(
                f"the {name} stroke has no samples between {covered[i]:.2f} and {covered[i + 1]:.2f} mm "
                f"(> {settings.max_gap_mm} mm): samples lost?"
            )
        mean = np.interp(grid, u_c[filled], d_c[filled])
        window = int(round(settings.smoothing_mm / step)) | 1
        if settings.smoothing_mm > 0 and window >= 5 and window < n:
            mean = savgol_filter(mean, window, polyorder=3, mode="interp")
        curves[name] = mean

    b_um = (curves["negative"] - curves["positive"]) * 1e3  # Eq. 5: b = x_l- - x_l+
    profile = BacklashProfile(
        position_mm=grid,
        backlash_um=b_um,
        mean_um=float(b_um.mean()),
        min_um=float(b_um.min()),
        max_um=float(b_um.max()),
        std_um=float(b_um.std()),
    )
    criteria = {
        name: lead_criteria(
            grid,
            curves[name],
            direction=name,
            screw_lead_mm=axis.screw_lead_mm,
            n_strokes=len(by_dir[d]),
        )
        for d, name in ((1, "positive"), (-1, "negative"))
    }
    # differences over ~10 ms: sample-to-sample ones would turn encoder noise into speed;
    # taken within the strokes only, so that a long dwell does not pull the percentile down
    lag = int(max(1, round(0.01 / float(np.median(np.diff(t))))))
    speed = np.abs(nominal[lag:] - nominal[:-lag]) / (t[lag:] - t[:-lag])
    moving = np.concatenate([np.arange(s.engaged, max(s.engaged, s.end - lag)) for s in strokes] or [[]])
    if moving.size:
        speed = speed[moving.astype(np.intp)]
    return RoundTripResult(
        axis=axis.name,
        useful_travel_mm=(float(start), float(end)),
        backlash=profile,
        strokes=criteria,
        n_samples=int(t.size),
        peak_speed_mm_min=float(np.percentile(speed, 99) * 60.0),
    )
