"""The circular test's polar plot (ISO 230-4): both directions' radial deviation,
magnified about the least-squares circle, with the reversal spikes and Eq. 8's prediction.

What is drawn:

- each pass (ccw solid blue, cw dashed red) as its radial deviation about the
  **least-squares circle**: the stored deviation is about the nominal centre and radius; the
  LSQ centre offset (c_x, c_y) and radius deviation ΔR are removed to first order,
  ``d(θ) - c_x cos θ - c_y sin θ - ΔR`` (the neglected term is c²/2R: 10⁻⁶ µm for a 10 µm
  offset on R = 50 mm). This is the circle ISO 230-4's G and the spike heights are taken about;
- the radial scale is in µm, magnified: the LSQ circle is the ring at 0 µm, and the centre
  of the plot is well below the smallest deviation, as on a ballbar's plot;
- the tolerance band of the circle task the test was judged against: from the undisturbed
  circle's level up to that level plus the task's tolerance (shaded), and the warning
  threshold (dashed ring). A spike that leaves the band is a TBE above the tolerance;
- each reversal spike: a radial bar from the undisturbed level (its peak minus its measured
  height) to its peak, and a diamond where Eq. 8 at the axis' b̄ puts the peak, the two
  figures written beside it;
- beside the plot: the legend, G (LSQ and minimum zone) and H with their expanded
  uncertainties, each axis' spikes against Eq. 8 with the agreement verdict, and the decision.

The plot's inputs are plain values (:class:`SpikeMark`, :class:`Band`, :class:`Summary`), so
the figure can be drawn in the service's plot process (:mod:`api.service.figures.process`)
and tested on its artists (:func:`polar_figure`; the artists carry ``gid``\\ s).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from matplotlib.figure import Figure

from api.service.figures.plots import png_bytes  # also sets Agg and plain text (no mathtext)
from core.downsample import minmax_indices

DIRECTION_STYLE = {"ccw": dict(color="#1f77b4", ls="-", label="counter-clockwise (ccw, G03)"),
                   "cw": dict(color="#d62728", ls="--", label="clockwise (cw, G02)")}
MAX_POINTS = 4000  # per pass: min and max per bucket, more than a 700-pixel circle shows
SPIKE_WINDOW_DEG = (4.0, 30.0)  # where the peak is looked for after a quadrant point (at least, at most)


@dataclass(frozen=True)
class SpikeMark:
    """One reversal spike as the plot marks it: measured (k = 2) and Eq. 8's prediction."""

    axis: str
    quadrant_deg: float
    direction: str
    height_um: float
    height_uncertainty_um: float
    width_deg: float = 0.0
    predicted_um: float | None = None  # Eq. 8 at the axis' b̄; None without a backlash measurement
    predicted_uncertainty_um: float | None = None
    peak_deg: float | None = None  # where the analysis found the peak (None: looked for here)


@dataclass(frozen=True)
class Band:
    """The tolerance band of the circle task the test was judged against (µm)."""

    task: str
    tolerance_um: float
    warning_um: float | None = None


@dataclass(frozen=True)
class Summary:
    """The figures written beside the plot (expanded uncertainties, k = 2)."""

    circular_deviation_um: float
    circular_deviation_mz_um: float
    circular_deviation_uncertainty_um: float
    hysteresis_um: float | None = None
    hysteresis_uncertainty_um: float | None = None
    # per axis: the agreement line ("agree", "larger", "smaller" with E_n)
    agreements: Mapping[str, str] = field(default_factory=dict)
    decisions: tuple[str, ...] = ()  # per judged axis: "x: OK on ring-50, TBE 8.1 ± 1.0 µm against 20 µm"


def lsq_deviation_um(angle_deg, radial_um, centre_offset_um: tuple[float, float],
                     mean_radius_deviation_um: float) -> np.ndarray:
    """The radial deviation about the least-squares circle, from the deviation about the
    nominal one (first order in the centre offset: see the module's docstring)."""
    th = np.deg2rad(np.asarray(angle_deg, float))
    cx, cy = centre_offset_um
    return np.asarray(radial_um, float) - cx * np.cos(th) - cy * np.sin(th) - mean_radius_deviation_um


def spike_peak(angle_deg: np.ndarray, dev_um: np.ndarray, mark: SpikeMark,
               window_deg: float | None = None) -> tuple[float, float] | None:
    """(angle, deviation) of the spike's peak. At ``mark.peak_deg`` when the analysis gave it
    (the sample nearest it); else the largest deviation within ``window_deg`` (default: three
    spike widths, 4-30°) after the quadrant point in the pass' direction of travel, where the
    axis has reversed. None when the pass has no sample there."""
    if angle_deg.size == 0:
        return None
    if mark.peak_deg is not None and np.isfinite(mark.peak_deg):
        gap = np.abs((angle_deg - mark.peak_deg + 180.0) % 360.0 - 180.0)
        near = np.flatnonzero(gap <= gap.min() + 1e-9)
        i = near[int(np.argmax(dev_um[near]))]
        return float(angle_deg[i]), float(dev_um[i])
    w = float(window_deg) if window_deg is not None else float(np.clip(3.0 * mark.width_deg, *SPIKE_WINDOW_DEG))
    ahead = (angle_deg - mark.quadrant_deg) % 360.0 if mark.direction == "ccw" else \
        (mark.quadrant_deg - angle_deg) % 360.0
    sel = np.flatnonzero(ahead <= w)
    if sel.size == 0:
        return None
    i = sel[int(np.argmax(dev_um[sel]))]
    return float(angle_deg[i]), float(dev_um[i])


def _thin(angle: np.ndarray, dev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pass in the order the machine ran it, at most MAX_POINTS samples, every extreme kept."""
    if angle.size <= MAX_POINTS:
        return angle, dev
    idx = minmax_indices(dev, MAX_POINTS)
    return angle[idx], dev[idx]


def _signed(v: float) -> str:
    """``v`` with its sign to 0.1, never "-0.0"."""
    return f"{round(v, 1) + 0.0:+.1f}"


def _fmt_pm(value: float, u: float | None, nd: int = 1) -> str:
    return f"{value:.{nd}f}" + (f" ± {u:.{nd}f}" if u is not None else "") + " µm"


def polar_figure(passes: Mapping[str, tuple[Sequence[float], Sequence[float]]], *, radius_mm: float,
                 feed_mm_min: float, plane: tuple[str, str], centre_offset_um: tuple[float, float],
                 mean_radius_deviation_um: float, spikes: Sequence[SpikeMark], summary: Summary,
                 band: Band | None, title: str, spike_window_deg: float | None = None) -> Figure:
    """The polar plot as a matplotlib Figure (its artists named by ``gid``: ``pass-<dir>``,
    ``lsq-circle``, ``tolerance-band``, ``warning-ring``, ``spike-<axis>-<quadrant>-<dir>``,
    ``eq8-<axis>-<quadrant>-<dir>``, ``spike-label-...``, ``summary``).

    ``passes``: direction -> (angle in degrees from the + ``plane[0]`` direction, ccw positive;
    radial deviation about the *nominal* circle, µm), in the order the machine ran them."""
    fig = Figure(figsize=(11.0, 7.0), dpi=100, layout="constrained")
    grid = fig.add_gridspec(1, 2, width_ratios=(2.6, 1.4))
    ax = fig.add_subplot(grid[0, 0], projection="polar")
    side = fig.add_subplot(grid[0, 1])
    side.set_axis_off()

    devs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for direction, (angle, radial) in passes.items():
        a = np.asarray(angle, float) % 360.0
        devs[direction] = (a, lsq_deviation_um(a, radial, centre_offset_um, mean_radius_deviation_um))

    # the spikes' peaks, and the undisturbed level under each (peak minus measured height)
    marks = []
    for m in spikes:
        if m.direction not in devs:
            continue
        peak = spike_peak(*devs[m.direction], m, spike_window_deg)
        if peak is None:
            continue
        marks.append((m, *peak, peak[1] - m.height_um))
    everything = np.concatenate([d for _, d in devs.values()]) if devs else np.zeros(1)
    level = float(np.median([base for *_, base in marks])) if marks else float(np.median(everything))

    top_candidates = [float(everything.max()), 0.0]
    if band is not None:
        top_candidates.append(level + band.tolerance_um)
    top_candidates += [base + m.predicted_um for m, _, _, base in marks if m.predicted_um is not None]
    lo, hi = min(float(everything.min()), level, 0.0), max(top_candidates)
    span = max(hi - lo, 1.0)
    r_min, r_max = lo - 0.08 * span, hi + 0.12 * span
    ax.set_rorigin(r_min - 0.9 * span)  # the magnification: the hole in the middle is ~ the plotted span
    ax.set_ylim(r_min, r_max)

    theta = np.linspace(0.0, 2.0 * np.pi, 721)
    if band is not None:
        ax.fill_between(theta, np.full_like(theta, level), np.full_like(theta, level + band.tolerance_um),
                        color="#2ca02c", alpha=0.15, lw=0, gid="tolerance-band",
                        label=f"tolerance of {band.task}: {band.tolerance_um:g} µm above the undisturbed circle")
        if band.warning_um is not None:
            ax.plot(theta, np.full_like(theta, level + band.warning_um), color="#2ca02c", ls=":", lw=1.2,
                    gid="warning-ring", label=f"warning threshold {band.warning_um:.3g} µm")
    ax.plot(theta, np.zeros_like(theta), color="black", lw=0.8, gid="lsq-circle",
            label=f"least-squares circle (R {radius_mm:g} mm {mean_radius_deviation_um:+.1f} µm)")

    for direction, (a, d) in devs.items():
        style = DIRECTION_STYLE.get(direction, dict(color="gray", ls="-", label=direction))
        at, dt = _thin(a, d)
        ax.plot(np.deg2rad(at), dt, lw=1.1, gid=f"pass-{direction}", **style)

    first = {"spike": True, "eq8": True}
    for m, peak_deg, peak_um, base in marks:
        key = f"{m.axis}-{m.quadrant_deg:g}-{m.direction}"
        color = DIRECTION_STYLE.get(m.direction, {}).get("color", "gray")
        th = np.deg2rad(peak_deg)
        ax.plot([th, th], [base, peak_um], color=color, lw=3.0, alpha=0.6, solid_capstyle="butt",
                gid=f"spike-{key}", label="reversal spike: measured height" if first.pop("spike", False) else None)
        text = f"{m.axis} {m.direction}: {_fmt_pm(m.height_um, m.height_uncertainty_um)}"
        if m.predicted_um is not None:
            ax.plot([th], [base + m.predicted_um], "D", color="black", mfc="white", ms=6, mew=1.2,
                    gid=f"eq8-{key}", label="Eq. 8 at the axis' b̄" if first.pop("eq8", False) else None)
            text += f"\nEq. 8: {_fmt_pm(m.predicted_um, m.predicted_uncertainty_um)}"
        # beside the plot's rim, on the pass' side of the quadrant (ccw after it, cw before it), so
        # the two directions' labels of one quadrant never overlap
        out = np.deg2rad(m.quadrant_deg + (22.0 if m.direction == "ccw" else -22.0))
        cos_out = float(np.cos(out))
        ax.annotate(text, xy=(th, peak_um), xytext=(0.5 + 0.58 * cos_out, 0.5 + 0.58 * float(np.sin(out))),
                    textcoords="axes fraction", annotation_clip=False, fontsize=7, color=color, va="center",
                    ha="left" if cos_out > 0.2 else "right" if cos_out < -0.2 else "center",
                    bbox=dict(facecolor="white", alpha=0.85, edgecolor=color, lw=0.5, boxstyle="round,pad=0.2"),
                    arrowprops=dict(arrowstyle="-", color=color, lw=0.5, alpha=0.7), gid=f"spike-label-{key}")

    first_axis, second_axis = plane
    ax.set_thetagrids([0, 90, 180, 270], [f"+{first_axis}", f"+{second_axis}", f"−{first_axis}",
                                          f"−{second_axis}"])
    ax.set_rlabel_position(112.5)
    ax.tick_params(axis="y", labelsize=7)
    ax.grid(True, alpha=0.35)
    fig.suptitle(f"{title}\nR {radius_mm:g} mm, {feed_mm_min:g} mm/min; radial deviation about the "
                 f"least-squares circle, µm (centre offset {_signed(centre_offset_um[0])}, "
                 f"{_signed(centre_offset_um[1])} µm removed)", fontsize=9)

    handles, labels = ax.get_legend_handles_labels()
    side.legend(handles, labels, loc="upper left", fontsize=8, frameon=False)
    u_g = summary.circular_deviation_uncertainty_um
    lines = [f"G (least squares) = {_fmt_pm(summary.circular_deviation_um, u_g)}",
             f"G (minimum zone) = {_fmt_pm(summary.circular_deviation_mz_um, u_g)}"]
    if summary.hysteresis_um is not None:
        lines.append(f"H = {_fmt_pm(summary.hysteresis_um, summary.hysteresis_uncertainty_um)}")
    else:
        lines.append("H: one direction only")
    for axis_name, line in summary.agreements.items():
        lines.append(f"{axis_name}: {line}")
    lines += list(summary.decisions)
    lines.append("(expanded uncertainties, k = 2)")
    side.text(0.0, 0.0, "\n".join(textwrap.fill(t, 48, subsequent_indent="  ") for t in lines),
              transform=side.transAxes, fontsize=8.5, va="bottom", ha="left", gid="summary")
    return fig


def polar(passes, **kwargs) -> bytes:
    """:func:`polar_figure` as PNG bytes (what the service's plot process draws)."""
    return png_bytes(polar_figure(passes, **kwargs))
