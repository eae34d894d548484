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
    the lead curves (None: chosen from the axis, 0.25 mm or 1/64 of a short screw
    lead); ``smoothing_mm`` the smallest Savitzky-Golay (cubic) window applied to the
    binned curves (0 disables it): on sparse traces it widens to
    ``smoothing_samples`` sample spacings, never beyond a quarter of the screw lead so
    that v_2π keeps its feature; ``max_gap_mm`` the largest stretch between two
    samples of a stroke that may be interpolated over; ``max_ratio_error`` how far
    table and motor travel may disagree before k_a or the units are declared wrong."""

    grid_step_mm: float | None = None
    smoothing_mm: float = 2.0
    smoothing_samples: float = 4.0
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
    grid_step_mm: float = 0.25
    smoothing_mm: float = 2.0
    sample_spacing_mm: float = 0.0

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
            "grid_step_mm": self.grid_step_mm,
            "grid_points": int(self.backlash.position_mm.size),
            "smoothing_mm": self.smoothing_mm,
            "sample_spacing_mm": self.sample_spacing_mm,
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


def _grid_crossings(
    u: np.ndarray, val: np.ndarray, pair_ok: np.ndarray, grid0: float, step: float
) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation between consecutive samples onto every grid point they
    straddle (grid index, value). ``pair_ok[i]`` allows the pair (i, i + 1): pairs
    across strokes or across a hole are never interpolated over."""
    a = (u[:-1] - grid0) / step
    b = (u[1:] - grid0) / step
    lo = np.floor(np.minimum(a, b))
    hi = np.floor(np.maximum(a, b))
    count = np.where(pair_ok, hi - lo, 0).astype(np.int64)  # grid points in (min, max]
    total = int(count.sum())
    if total == 0:
        return np.empty(0, np.int64), np.empty(0)
    pair = np.repeat(np.arange(count.size), count)
    first = np.cumsum(count) - count
    j = lo[pair].astype(np.int64) + 1 + (np.arange(total) - first[pair])
    g = grid0 + step * j
    u0, u1 = u[pair], u[pair + 1]
    w = (g - u0) / (u1 - u0)
    return j, val[pair] + w * (val[pair + 1] - val[pair])


def _bin_direction(
    strokes: list[Stroke],
    travel: np.ndarray,
    dev: np.ndarray,
    grid: np.ndarray,
    step: float,
    max_gap_mm: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[float, float]]]:
    """Centroids (mean travel, mean deviation) per grid bin over all strokes of one
    direction, the number of contributions per bin, and the holes (travel spans
    longer than ``max_gap_mm`` between consecutive samples of a stroke).

    Each bin averages the samples that fall into it *and* the linear interpolation
    between consecutive samples of a stroke at every grid point they straddle: dense
    traces are averaged (noise drops as 1/√n), sparse ones (more than a bin between
    samples, e.g. 0.67 mm at 8000 mm/min and 200 Hz) are interpolated, and neither
    needs a sample in every bin. Averaging the travel too removes the bias of where
    the samples fall inside a bin (lead slope x half a bin) to second order."""
    n = grid.size
    sel = [slice(s.engaged, s.end + 1) for s in strokes]
    u = np.concatenate([travel[k] for k in sel])
    val = np.concatenate([dev[k] for k in sel])
    gap = np.abs(np.diff(u))
    same_stroke = np.ones(gap.size, bool)
    ends = np.cumsum([k.stop - k.start for k in sel])[:-1]
    same_stroke[ends - 1] = False
    hole = same_stroke & (gap > max_gap_mm)
    holes = [
        (float(min(u[i], u[i + 1])), float(max(u[i], u[i + 1])))
        for i in np.flatnonzero(hole)
    ]
    j, v = _grid_crossings(u, val, same_stroke & ~hole, float(grid[0]), step)
    idx = np.rint((u - grid[0]) / step).astype(np.int64)
    inside = (idx >= 0) & (idx < n)
    j_in = (j >= 0) & (j < n)
    idx = np.concatenate((idx[inside], j[j_in]))
    u_all = np.concatenate((u[inside], grid[0] + step * j[j_in]))
    val = np.concatenate((val[inside], v[j_in]))
    counts = np.bincount(idx, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        u_c = np.bincount(idx, weights=u_all - grid[idx], minlength=n) / counts + grid
        d_c = np.bincount(idx, weights=val, minlength=n) / counts
    return u_c, d_c, counts, holes


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
    step = settings.grid_step_mm
    if step is None:
        step = min(0.25, axis.screw_lead_mm / 64.0)
    elif not step > 0:
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

    # travel between consecutive kept samples: what the grid and the smoothing must bridge
    spacing = float(np.median(np.concatenate([np.abs(np.diff(travel[s.engaged : s.end + 1])) for s in strokes])))
    smoothing_mm = settings.smoothing_mm
    if smoothing_mm > 0:
        smoothing_mm = max(smoothing_mm, min(settings.smoothing_samples * spacing, axis.screw_lead_mm / 4.0))
    n = int(round((end - start) / step)) + 1
    grid = start + step * np.arange(n)
    curves = {}
    for d, name in ((1, "positive"), (-1, "negative")):
        u_c, d_c, counts, holes = _bin_direction(by_dir[d], travel, dev, grid, step, settings.max_gap_mm)
        holes = [h for h in holes if h[1] > start and h[0] < end]
        if holes:
            lo, hi = max(holes, key=lambda h: h[1] - h[0])
            raise TraceError(
                f"the {name} stroke has no samples between {lo:.2f} and {hi:.2f} mm "
                f"({hi - lo:.2f} mm > max_gap_mm {settings.max_gap_mm:g} mm): samples lost?"
            )
        filled = counts > 0
        covered = grid[filled]
        if not filled[0] or not filled[-1]:
            lo = float(covered[0]) if covered.size else float("nan")
            hi = float(covered[-1]) if covered.size else float("nan")
            raise TraceError(
                f"the {name} stroke covers {lo:.2f}..{hi:.2f} mm outside its reversal transient, "
                f"shorter than the useful travel {start:g}..{end:g} mm asked for"
            )
        empty = np.diff(covered)
        if empty.size and empty.max() > settings.max_gap_mm:  # strokes that cover disjoint pieces
            i = int(np.argmax(empty))
            raise TraceError(
                f"the {name} strokes leave {covered[i]:.2f}..{covered[i + 1]:.2f} mm uncovered "
                f"(> max_gap_mm {settings.max_gap_mm:g} mm)"
            )
        mean = np.interp(grid, u_c[filled], d_c[filled])
        window = int(round(smoothing_mm / step)) | 1
        if smoothing_mm > 0 and window >= 5 and window < n:
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
        grid_step_mm=float(step),
        smoothing_mm=float(smoothing_mm),
        sample_spacing_mm=spacing,
    )
