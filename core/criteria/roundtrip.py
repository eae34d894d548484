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

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from core.criteria.lead import LeadCriteria, lead_criteria
from core.criteria.lost_motion import LostMotion, lost_motion, stroke_lost_motion
from core.criteria.outliers import OutlierSettings, check_outlier_fraction, encoder_outliers, noise_sigma_mm
from core.criteria.segmentation import SegmentationSettings, find_strokes
from core.criteria.uncertainty import (
    UncertaintyBudget,
    UncertaintyComponent,
    UncertaintyInputs,
    BAND_TEMPERATURE,
    history_components,
    resolution_component,
    sampling_component,
    scale_component,
    temperature_component,
)
from core.dataset import AxisSpec
from core.errors import InputError, TraceError


CRITERIA = ("e_p", "v_u", "v_300", "v_2pi")
REDUCTION_BOUND_UM = 0.01  # see _budgets
NEEDS_SCREW_LEAD = ("v_2π (travel variation within one revolution) is not computed: its window is one screw "
                    "lead; give the axis' screw_lead_mm")
TBE_NEEDS_POSITION_GAIN = "TBE not computed: the position-loop gain K is not known"
COVERED = "covered"  # useful_travel_mm: what both strokes cover outside their reversal transients
TBE_BASIS = ("the TBE uses the total lost motion b̄ (= B̄, clearance and friction wind-up together), "
             "as the seed paper's table does")


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
    outliers: OutlierSettings = field(default_factory=OutlierSettings)


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
    outliers_removed: int = 0
    noise_um: float = 0.0
    # GUM budgets: "backlash_mean", and "<stroke>.<criterion>" (e.g. "positive.v_2pi")
    budgets: dict[str, UncertaintyBudget] = field(default_factory=dict)
    # ISO 230-2 reversal values and the clearance estimate (core.criteria.lost_motion)
    lost_motion: LostMotion | None = None
    # the bound on the samples' time stamps the outlier test allowed for (polled samples)
    clock_uncertainty_s: float = 0.0

    @property
    def backlash_mean_uncertainty_um(self) -> float:
        """Expanded (k = 2) uncertainty of b̄, µm."""
        return self.budgets["backlash_mean"].expanded_um

    def criterion_uncertainty_um(self, stroke: str, criterion: str) -> float:
        """Expanded (k = 2) uncertainty of a lead criterion (e_p, v_u, v_300, v_2pi), µm;
        None for a criterion not computed (v_2pi without the screw lead)."""
        budget = self.budgets.get(f"{stroke}.{criterion}")
        return budget.expanded_um if budget is not None else None

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
            "outliers_removed": self.outliers_removed,
            "clock_uncertainty_s": self.clock_uncertainty_s,
            "noise_um": self.noise_um,
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
        if pos.v_2pi_um is None:
            out["needs_screw_lead"] = {"v_2pi": NEEDS_SCREW_LEAD}
        if self.budgets:
            out["backlash_mean_uncertainty_um"] = self.backlash_mean_uncertainty_um
            for key in CRITERIA:
                out[f"{key}_uncertainty_um"] = self.criterion_uncertainty_um("positive", key)
                for name in self.strokes:
                    out["strokes"][name][f"{key}_uncertainty_um"] = self.criterion_uncertainty_um(name, key)
            out["uncertainty_budget"] = {k: b.to_dict() for k, b in self.budgets.items()}
            if "backlash_mean_20c" in self.budgets:
                out["backlash_mean_20c_uncertainty_um"] = self.budgets["backlash_mean_20c"].expanded_um
        if self.lost_motion is not None:
            lm = self.lost_motion
            out["reversal_mean_um"] = lm.mean_um
            out["reversal_max_um"] = lm.max_abs_um
            out["clearance_um"] = lm.clearance.clearance_um
            out["lost_motion"] = {**lm.to_dict(), "tbe_basis": TBE_BASIS}
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
    pieces: list[tuple[np.ndarray, np.ndarray]],
    grid: np.ndarray,
    step: float,
    max_gap_mm: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[float, float]]]:
    """Centroids (mean travel, mean deviation) per grid bin over all strokes of one
    direction, the number of contributions per bin, and the holes (travel spans
    longer than ``max_gap_mm`` between consecutive samples of a stroke).

    ``pieces`` holds (travel, deviation) of each stroke's kept samples, in time order.
    Each bin averages the samples that fall into it *and* the linear interpolation
    between consecutive samples of a stroke at every grid point they straddle: dense
    traces are averaged (noise drops as 1/√n), sparse ones (more than a bin between
    samples, e.g. 0.67 mm at 8000 mm/min and 200 Hz) are interpolated, and neither
    needs a sample in every bin. Never across strokes or a hole. Averaging the travel
    too removes the bias of where the samples fall inside a bin (lead slope x half a
    bin) to second order."""
    n = grid.size
    g0, inv = float(grid[0]), 1.0 / step
    idx_parts, du_parts, val_parts, holes = [], [], [], []
    j_parts, jv_parts = [], []
    for u, val in pieces:
        if u.size == 0:
            continue
        a = u - g0
        a *= inv  # travel in grid steps
        nearest = np.floor(a + 0.5)  # the bin of the sample: its nearest grid point
        du = a - nearest  # offset from the bin centre, in steps
        idx = nearest.astype(np.int64)
        below = np.floor(a)
        k = below.astype(np.int64)
        # pairs that straddle grid points: k changes between them (grid points in (min, max])
        pair = np.flatnonzero(k[1:] != k[:-1])
        if pair.size:
            gap = np.abs(u[pair + 1] - u[pair])
            hole = gap > max_gap_mm
            if hole.any():
                holes += [(float(min(u[i], u[i + 1])), float(max(u[i], u[i + 1]))) for i in pair[hole]]
                pair = pair[~hole]
            lo = np.minimum(k[pair], k[pair + 1])
            count = np.abs(k[pair + 1] - k[pair])
            total = int(count.sum())
            rep = np.repeat(np.arange(pair.size), count)
            first = np.cumsum(count) - count
            j = lo[rep] + 1 + (np.arange(total) - first[rep])
            p0 = pair[rep]
            w = (j - a[p0]) / (a[p0 + 1] - a[p0])
            j_parts.append(j)
            jv_parts.append(val[p0] + w * (val[p0 + 1] - val[p0]))
        idx_parts.append(idx)
        du_parts.append(du)
        val_parts.append(val)
    if step > max_gap_mm:  # pairs inside one bin were not examined above
        for u, _ in pieces:
            big = np.flatnonzero(np.abs(np.diff(u)) > max_gap_mm)
            holes += [(float(min(u[i], u[i + 1])), float(max(u[i], u[i + 1]))) for i in big]
    idx = np.concatenate(idx_parts) if idx_parts else np.empty(0, np.int64)
    du = np.concatenate(du_parts) if du_parts else np.empty(0)
    val = np.concatenate(val_parts) if val_parts else np.empty(0)
    # samples beyond the grid go to two overflow bins, dropped after counting: cheaper
    # than selecting the inside ones from a million
    np.clip(idx, -1, n, out=idx)
    idx += 1
    counts = np.bincount(idx, minlength=n + 2)[1:-1]
    sum_du = np.bincount(idx, weights=du, minlength=n + 2)[1:-1]  # interpolated points sit on the grid
    sum_val = np.bincount(idx, weights=val, minlength=n + 2)[1:-1]
    if j_parts:
        j = np.concatenate(j_parts)
        jv = np.concatenate(jv_parts)
        ok = (j >= 0) & (j < n)
        j, jv = j[ok], jv[ok]
        counts = counts + np.bincount(j, minlength=n)
        sum_val = sum_val + np.bincount(j, weights=jv, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        u_c = grid + step * sum_du / counts
        d_c = sum_val / counts
    return u_c, d_c, counts, holes


def analyze_round_trip(
    time_s,
    motor_rev,
    table_mm,
    axis: AxisSpec,
    *,
    useful_travel_mm: tuple[float, float] | str | None = None,
    settings: RoundTripSettings = RoundTripSettings(),
    uncertainty: UncertaintyInputs = UncertaintyInputs(),
) -> RoundTripResult:
    """Backlash profile and lead criteria of one axis from one round trip, each with
    its GUM uncertainty budget (``uncertainty`` gives what the samples cannot show).

    ``useful_travel_mm`` defaults to the axis' ``travel_mm`` and is in table
    coordinates; :data:`COVERED` takes what both directions' strokes cover outside their
    reversal transients (a trace recorded without overtravel), reported in the result.
    Without the axis' screw lead v_2π is None. Raises :class:`TraceError` for a trace
    that cannot be trusted.
    """
    t, motor, table = _check_trace(time_s, motor_rev, table_mm)
    covered = useful_travel_mm == COVERED
    if isinstance(useful_travel_mm, str) and not covered:
        raise InputError(f"useful_travel_mm (={useful_travel_mm!r}) must be [start, end] or {COVERED!r}")
    start, end = axis.travel_mm if useful_travel_mm is None or covered else useful_travel_mm
    if not end > start:
        raise InputError(f"useful_travel_mm (={[start, end]}) must be [start, end] with end > start")
    lead_mm = axis.screw_lead_mm
    step = settings.grid_step_mm
    if step is None:
        step = min(0.25, lead_mm / 64.0) if lead_mm is not None else 0.25
    elif not step > 0:
        raise InputError(f"grid_step_mm (={settings.grid_step_mm}) must be > 0")
    n_samples = int(t.size)
    nominal = motor * axis.transmission_mm_per_rev  # l_0 = k_a x_m, arbitrary zero
    # Glitches first: a 5 mm spike of one encoder would otherwise pass for motion, for
    # a reversal, or for a lead error of 5 mm in one bin. Dropped, counted, and refused
    # past max_fraction: the same rule the acquisition applies online.
    outliers = encoder_outliers(nominal, table, settings.outliers, time_s=t,
                                sampling_bound_um=uncertainty.sampling_bound_um,
                                clock_uncertainty_s=uncertainty.clock_uncertainty_s)
    n_out = int(np.count_nonzero(outliers))
    check_outlier_fraction(n_out, n_samples, settings.outliers, "of the round trip")
    if n_out:
        keep = ~outliers
        t, motor, table, nominal = t[keep], motor[keep], table[keep], nominal[keep]
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
    # Robust levels (an alignment offset, a typical spacing) from a strided subsample of
    # at most ~20,000 samples: their exact value does not matter, a median of millions costs.
    stride = max(1, t.size // 20_000)
    med = [float(np.median(np.concatenate([raw_dev[s.engaged : s.end + 1 : stride] for s in by_dir[d]])))
           for d in (1, -1)]
    offset = 0.5 * (med[0] + med[1])
    travel = nominal + offset
    dev = raw_dev - offset

    # travel between consecutive kept samples: what the grid and the smoothing must bridge
    spacing = float(np.median(np.abs(np.concatenate(
        [travel[s.engaged + 1 : s.end + 1 : stride] - travel[s.engaged : s.end : stride] for s in strokes]))))
    # noise of l_a - l_0 about its smooth part: the median over the strokes
    noise_mm = float(np.median([noise_sigma_mm(dev[s.engaged : s.end + 1]) for s in strokes]))
    smoothing_mm = settings.smoothing_mm
    if smoothing_mm > 0:
        bridge_mm = settings.smoothing_samples * spacing
        smoothing_mm = max(smoothing_mm, min(bridge_mm, lead_mm / 4.0) if lead_mm is not None else bridge_mm)
    if covered:
        start, end = _covered_travel_mm(travel, by_dir, step)
    n = int(round((end - start) / step)) + 1
    grid = start + step * np.arange(n)
    curves = {}
    for d, name in ((1, "positive"), (-1, "negative")):
        pieces = [(travel[s.engaged : s.end + 1], dev[s.engaged : s.end + 1]) for s in by_dir[d]]
        u_c, d_c, counts, holes = _bin_direction(pieces, grid, step, settings.max_gap_mm)
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
            screw_lead_mm=lead_mm,
            n_strokes=len(by_dir[d]),
        )
        for d, name in ((1, "positive"), (-1, "negative"))
    }
    # differences over ~10 ms: sample-to-sample ones would turn encoder noise into speed;
    # taken within the strokes only, so that a long dwell does not pull the percentile down
    lag = int(max(1, round(0.01 / float(np.median(t[1::stride] - t[:-1:stride])))))
    # (on every stride-th sample: a percentile of a million speeds costs a full sort pass)
    at = np.concatenate([np.arange(s.engaged, max(s.engaged, s.end - lag), stride) for s in strokes] or [[]])
    at = at.astype(np.intp)
    if at.size == 0:
        at = np.arange(0, t.size - lag, stride)
    speed = np.abs(nominal[at + lag] - nominal[at]) / (t[at + lag] - t[at])
    budgets = _budgets(
        uncertainty, table=table, nominal=nominal, stride=stride, noise_mm=noise_mm, spacing_mm=spacing,
        smoothing_mm=smoothing_mm, length_mm=float(end - start), screw_lead_mm=lead_mm,
        backlash_um=profile.mean_um, n_dir={name: sum(int(np.count_nonzero((travel[s.engaged : s.end + 1] >= start)
                                               & (travel[s.engaged : s.end + 1] <= end))) for s in by_dir[d])
               for d, name in ((1, "positive"), (-1, "negative"))},
    )
    feeds, feed_lost, feed_u = stroke_lost_motion(t, travel, dev, strokes, start, end, stride)
    lm = lost_motion(grid, b_um, start_mm=start, end_mm=end, feeds_mm_min=feeds, feed_lost_motion_um=feed_lost,
                     feed_uncertainty_um=feed_u)
    return RoundTripResult(
        axis=axis.name,
        useful_travel_mm=(float(start), float(end)),
        backlash=profile,
        strokes=criteria,
        n_samples=n_samples,
        peak_speed_mm_min=float(np.percentile(speed, 99) * 60.0),
        grid_step_mm=float(step),
        smoothing_mm=float(smoothing_mm),
        sample_spacing_mm=spacing,
        outliers_removed=n_out,
        noise_um=noise_mm * 1e3,
        budgets=budgets,
        lost_motion=lm,
        clock_uncertainty_s=float(uncertainty.clock_uncertainty_s),
    )


def _min_step_um(x: np.ndarray, stride: int) -> float:
    """The encoder's resolution as the data show it, µm: the smallest gap between the
    distinct readings of (a subsample of) the trace. Quantised readings sit on a lattice
    of pitch q that a round trip visits densely, so the smallest gap is q; readings that
    are not quantised (simulated, interpolated) give a gap of ~0."""
    sub = np.unique(x[:: max(stride, x.size // 50_000, 1)])
    d = np.diff(sub)
    d = d[d > 0]
    return float(d.min() * 1e3) if d.size else 0.0


def _covered_travel_mm(travel: np.ndarray, by_dir: dict, step_mm: float) -> tuple[float, float]:
    """The travel (table coordinates, mm) that every direction covers outside its reversal
    transients (from each stroke's engagement to its end), moved inward to whole grid steps
    so that the first and last bins hold samples of both directions."""
    lo, hi = -np.inf, np.inf
    for d in (1, -1):
        spans = [travel[s.engaged : s.end + 1] for s in by_dir[d]]
        lo = max(lo, min(float(x.min()) for x in spans))
        hi = min(hi, max(float(x.max()) for x in spans))
    start = math.ceil(lo / step_mm) * step_mm + step_mm
    end = math.floor(hi / step_mm) * step_mm - step_mm
    if not end > start:
        raise TraceError(f"the two directions' strokes share no travel outside their reversal transients "
                         f"({lo:.2f}..{hi:.2f} mm)")
    return float(start), float(end)


def _budgets(inputs: UncertaintyInputs, *, table, nominal, stride, noise_mm, spacing_mm, smoothing_mm,
             length_mm, screw_lead_mm, backlash_um, n_dir) -> dict[str, UncertaintyBudget]:
    """GUM budgets of b̄ and of each lead criterion (see core.criteria.uncertainty)."""
    # An estimated resolution is bounded by the noise it would put into l_a - l_0
    # (q/√12): a lattice the motion only revisits (a simulated trace replaying the
    # same commanded positions) does not disturb the measurement.
    cap_um = math.sqrt(12.0) * noise_mm * 1e3
    q_t = inputs.table_resolution_um if inputs.table_resolution_um is not None else min(
        _min_step_um(table, stride), cap_um)
    q_m = inputs.motor_resolution_um if inputs.motor_resolution_um is not None else min(
        _min_step_um(nominal, stride), cap_um)
    res = resolution_component(q_t, q_m)
    sigma_um = noise_mm * 1e3
    n_pos, n_neg = max(n_dir["positive"], 1), max(n_dir["negative"], 1)
    history = history_components(inputs)
    # the reduction itself (grid, interpolation, smoothing): within ±0.01 µm of b̄ over the
    # accuracy envelope on exact synthetic round trips (tests/core/criteria), rectangular
    method = UncertaintyComponent("reduction", REDUCTION_BOUND_UM / math.sqrt(3.0),
                                  f"grid and interpolation, bound ±{REDUCTION_BOUND_UM} µm (validated)")
    quiet = "0: the data show no scatter (noise-free encoders, as simulated ones are)"
    out = {
        "backlash_mean": UncertaintyBudget("backlash_mean", (
            res,
            UncertaintyComponent("noise", sigma_um * math.sqrt(1.0 / n_pos + 1.0 / n_neg),
                                 f"σ {sigma_um:.3g} µm over {n_pos} + {n_neg} samples" if sigma_um > 0 else quiet),
            sampling_component(inputs.sampling_bound_um),
            method,
            scale_component(inputs, None),
            temperature_component(inputs, backlash_um * 1e-3, "b̄"),
        ) + history),
    }
    # a point of a smoothed lead curve averages the samples of one smoothing window; a
    # cubic Savitzky-Golay filter passes 1.5x the noise of a plain mean of as many
    per_window = max(1.0, smoothing_mm / max(spacing_mm, 1e-12))
    sigma_point = 1.5 * sigma_um / math.sqrt(per_window)
    ka = UncertaintyComponent("transmission", length_mm * 1e3 * inputs.transmission_rel_tolerance / math.sqrt(3.0),
                              f"k_a ±{inputs.transmission_rel_tolerance:.3g} relative over {length_mm:g} mm"
                              if inputs.transmission_rel_tolerance > 0
                              else "0: k_a is taken as configured (no tolerance stated)")
    ep_scale = scale_component(inputs, length_mm)
    ep_temperature = temperature_component(inputs, length_mm, "the useful travel")
    for name, n in (("positive", n_pos), ("negative", n_neg)):
        slope = UncertaintyComponent("noise", sigma_um * math.sqrt(12.0 / n),
                                     f"least-squares slope over {n} samples" if sigma_um > 0 else quiet)
        out[f"{name}.e_p"] = UncertaintyBudget(f"{name}.e_p", (res, slope, ka, ep_scale, ep_temperature))
        windows = [("v_u", length_mm), ("v_300", min(300.0, length_mm))]
        if screw_lead_mm is not None:
            windows.append(("v_2pi", min(screw_lead_mm, length_mm)))
        for key, window_mm in windows:
            # A band is a maximum minus a minimum: two smoothed points, two readings each.
            # Noise also widens it, as the extremes are picked from ~window/smoothing
            # independent points: the expected largest of N normals is σ √(2 ln N).
            n_ind = max(2.0, window_mm / max(smoothing_mm, spacing_mm, 1e-9))
            extreme = math.sqrt(2.0 * math.log(n_ind))
            out[f"{name}.{key}"] = UncertaintyBudget(f"{name}.{key}", (
                UncertaintyComponent("resolution", math.sqrt(2.0) * res.standard_um, res.note),
                UncertaintyComponent("noise", math.sqrt(2.0) * sigma_point * extreme,
                                     f"extremes of the smoothed curve, σ {sigma_point:.3g} µm each, "
                                     f"~{n_ind:.0f} independent points" if sigma_um > 0 else quiet),
                scale_component(inputs, window_mm),
                BAND_TEMPERATURE,
            ))
    return out


def with_history_uncertainty(result: RoundTripResult, components: dict[str, tuple[float, str]]) -> RoundTripResult:
    """``result`` with the history's components (``core.history.history_uncertainty``):
    ``repeatability`` joins b̄'s budget (it changes the decision's U); ``normalisation``
    makes a budget of its own, ``backlash_mean_20c`` (b̄'s plus the normalisation), as it
    concerns b̄ referred to 20 °C, not b̄ at the measured temperature the TBE uses."""
    if not result.budgets or not components:
        return result
    from dataclasses import replace

    budgets = dict(result.budgets)
    if "repeatability" in components and all(c.name != "repeatability" for c in budgets["backlash_mean"].components):
        u, note = components["repeatability"]
        budgets["backlash_mean"] = budgets["backlash_mean"].with_components(
            UncertaintyComponent("repeatability", float(u), note))
    if "normalisation" in components:
        u, note = components["normalisation"]
        base = budgets["backlash_mean"]
        budgets["backlash_mean_20c"] = UncertaintyBudget(
            "backlash_mean_20c", base.components + (UncertaintyComponent("normalisation", float(u), note),),
            base.coverage_factor)
    return replace(result, budgets=budgets)
