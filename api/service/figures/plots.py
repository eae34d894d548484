"""PNG figures for the maintenance team, after the seed paper's Figs. 5, 9, 10, 14, 15.

Plain functions from arrays to PNG bytes (matplotlib's object API with the Agg
canvas: no pyplot state, so no global lock: each render has its own Figure and canvas,
and matplotlib keeps its font objects per thread; no text is parsed as mathtext, so a
name with ``$`` is drawn as written. Concurrent renders are tested to give the same bytes
as serial ones).
Every axis is labelled with its unit; limits are drawn as dash-dot lines as in the paper.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence
from datetime import datetime

import matplotlib

matplotlib.use("Agg")
# every text is drawn as written: a task or machine name with "$" is a name, not a formula
# (mathtext would refuse "$\\frac{$" and the figure would not be drawn)
matplotlib.rcParams.update({"text.parse_math": False, "text.usetex": False})
import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from core.criteria import LeadCriteria  # noqa: E402
from core.downsample import minmax_indices  # noqa: E402
from core.errors import MebmError  # noqa: E402
from core.tbe import MachiningTask  # noqa: E402

SCREEN_POINTS = 2000  # a 1000-pixel-wide chart: min and max per pixel column
NAMES = ("backlash_profile", "lead_deviation", "tbe_vs_backlash", "tbe_history", "backlash_trend")
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2")


def png_bytes(fig: Figure) -> bytes:
    """The figure as PNG bytes, on its own Agg canvas."""
    buf = io.BytesIO()
    FigureCanvasAgg(fig).print_png(buf)
    return buf.getvalue()


def new_figure(w=9.0, h=5.0, rows=1) -> tuple[Figure, list]:
    """A figure of ``w`` x ``h`` inches with ``rows`` gridded axes, one below the other."""
    fig = Figure(figsize=(w, h), dpi=100, layout="constrained")
    axes = [fig.add_subplot(rows, 1, i + 1) for i in range(rows)]
    for ax in axes:
        ax.grid(True, alpha=0.3)
    return fig, axes


def _empty(title: str, message: str) -> bytes:
    fig, (ax,) = new_figure(7, 3)
    ax.set_axis_off()
    ax.set_title(title)
    # wrapped here, not by matplotlib: its wrapping measures a text with "$" as mathtext
    ax.text(0.5, 0.5, textwrap.fill(message, 70), ha="center", va="center", fontsize=12)
    return png_bytes(fig)


def empty(title: str, message: str) -> bytes:
    """A labelled placeholder (no data yet) instead of an error image."""
    return _empty(title, message)


def backlash_profile(position_mm, backlash_um, pos_dev_um, neg_dev_um, *, mean_um: float,
                     limit_um: float | None, title: str) -> bytes:
    """Fig. 9: (a) the upward side k_a x_m ~ x_l+ and downward side k_a x_m ~ x_l- as
    deviations from the nominal travel, (b) the backlash width b(x) = x_l- - x_l+."""
    fig, (a, b) = new_figure(9, 6.5, rows=2)
    a.plot(position_mm, pos_dev_um, color="#d62728", lw=1.2, label="upward side  x_l+ − k_a·x_m (feeding +)")
    a.plot(position_mm, neg_dev_um, color="#1f77b4", lw=1.2, label="downward side  x_l− − k_a·x_m (feeding −)")
    a.set_ylabel("table − nominal travel (µm)")
    a.set_title(f"(a) round trip — {title}")
    a.legend(loc="best", fontsize=8)
    b.plot(position_mm, backlash_um, color="black", lw=1.2, label="backlash width b(x)")
    b.axhline(mean_um, color="#2ca02c", ls="--", lw=1.2, label=f"mean b̄ = {mean_um:.1f} µm")
    if limit_um is not None:
        b.axhline(limit_um, color="#d62728", ls="-.", lw=1.4, label=f"backlash limit {limit_um:.1f} µm")
    b.set_xlabel("position (nominal travel l₀ = k_a·x_m, mm)")
    b.set_ylabel("backlash width b (µm)")
    b.set_title("(b) backlash width along the travel")
    b.legend(loc="best", fontsize=8)
    return png_bytes(fig)


def _worst_window(position_mm: np.ndarray, resid: np.ndarray, window_mm: float) -> tuple[float, float, float, float]:
    """(x0, x1, lo, hi) of the window of ``window_mm`` with the widest band of ``resid``."""
    step = float(position_mm[1] - position_mm[0]) if position_mm.size > 1 else 1.0
    w = max(1, min(int(round(window_mm / step)) + 1, resid.size))
    # a strided view: max - min of every full window (the curves have a few thousand points)
    view = np.lib.stride_tricks.sliding_window_view(resid, w)
    band = view.max(axis=1) - view.min(axis=1)
    arg = int(np.argmax(band))
    seg = resid[arg:arg + w]
    return float(position_mm[arg]), float(position_mm[arg + w - 1]), float(seg.min()), float(seg.max())


def lead_deviation(lc: LeadCriteria, *, screw_lead_mm: float, title: str) -> bytes:
    """Fig. 5: l_a − l_0 (actual travel), l_m − l_0 (actual mean travel), l_0 (zero) over
    the useful travel; v_u band (green dotted), worst 300 mm (red dashed) and worst
    one-lead (magenta dash-dot) windows, and the four criteria."""
    x = np.asarray(lc.position_mm, float)
    # The stroke sits half a backlash off the two directions' midline; remove that
    # constant so l_a and l_m are seen against l_0 (slope e_p and bands are unchanged).
    offset = float(np.mean(lc.mean_travel_deviation_um))
    la = np.asarray(lc.travel_deviation_um, float) - offset
    lm = np.asarray(lc.mean_travel_deviation_um, float) - offset
    resid = la - lm
    fig, (ax,) = new_figure(10, 5.5)
    ax.plot(x, la, color="black", lw=1.0, label="actual travel l_a")
    ax.plot(x, lm, color="#1f77b4", lw=1.6, label="actual mean travel l_m", zorder=4)
    ax.axhline(0.0, color="#d62728", lw=1.4, label="nominal travel l₀", zorder=1)
    ax.plot(x, lm + resid.max(), color="#2ca02c", ls=":", lw=1.4, label=f"v_u = {lc.v_u_um:.2f} µm")
    ax.plot(x, lm + resid.min(), color="#2ca02c", ls=":", lw=1.4)
    for window, color, ls, name, value in ((300.0, "#d62728", "--", "v_300", lc.v_300_um),
                                           (screw_lead_mm, "#e377c2", "-.", "v_2π", lc.v_2pi_um)):
        x0, x1, lo, hi = _worst_window(x, resid, window)
        sel = (x >= x0) & (x <= x1)
        ax.plot(x[sel], lm[sel] + hi, color=color, ls=ls, lw=1.6, label=f"{name} = {value:.2f} µm")
        ax.plot(x[sel], lm[sel] + lo, color=color, ls=ls, lw=1.6)
    ax.set_xlabel("nominal travel l₀ (mm)")
    ax.set_ylabel("travel deviation (µm), l₀ subtracted")
    lo_y = min(float(np.min(la)), float(np.min(lm)), 0.0)
    hi_y = max(float(np.max(la)), float(np.max(lm)), 0.0)
    pad = 0.35 * max(hi_y - lo_y, 1.0)
    ax.set_ylim(lo_y - pad, hi_y + pad)  # room for the legend and the criteria box
    ax.text(0.01, 0.97, f"stroke offset {offset:+.1f} µm (half the backlash) removed", transform=ax.transAxes,
            fontsize=8, color="gray", va="top")
    ax.set_title(f"lead error of the mechanical chain ({lc.direction} stroke) — {title}")
    ax.text(0.01, 0.02, f"e_p = {lc.e_p_um_per_1000mm:.2f} µm/1000 mm   v_u = {lc.v_u_um:.2f} µm   "
            f"v_300 = {lc.v_300_um:.2f} µm   v_2π = {lc.v_2pi_um:.2f} µm",
            transform=ax.transAxes, fontsize=9, bbox=dict(facecolor="white", alpha=0.8, edgecolor="none"))
    ax.legend(loc="upper right", fontsize=8, ncol=2, framealpha=0.9)
    return png_bytes(fig)


def _safe_tbe(task: MachiningTask, b: np.ndarray) -> np.ndarray:
    """TBE over ``b``, NaN where the model is outside its validity (not drawn)."""
    try:
        return np.asarray(task.tbe_um(b), float)
    except MebmError:
        out = np.full(b.shape, np.nan)
        for i, v in enumerate(b):
            try:
                out[i] = float(task.tbe_um(float(v)))
            except MebmError:
                pass
        return out


def tbe_vs_backlash(tasks: Sequence[MachiningTask], limits_um: Sequence[float | None], *,
                    backlash_um: float | None, title: str, backlash_uncertainty_um: float = 0.0,
                    rule: str = "guarded") -> bytes:
    """Fig. 14: TBE against backlash width for each task, its tolerance (warning
    threshold of the TBE, red dash-dot) and the backlash limit (blue dash-dot); the
    measured b̄ with its expanded uncertainty (shaded) and the decision rule applied."""
    finite = [v for v in limits_um if v is not None]
    top = max([*finite, backlash_um or 0.0, 100.0]) * 1.3
    b = np.linspace(0.0, top, 300)
    fig, (ax,) = new_figure(9, 5.5)
    for i, (task, limit) in enumerate(zip(tasks, limits_um)):
        c = COLORS[i % len(COLORS)]
        # one task: the paper's colours (TBE black, tolerance red, backlash limit blue)
        c_curve, c_tol, c_lim = ("black", "#d62728", "#1f77b4") if len(tasks) == 1 else (c, c, c)
        shape = f"R {task.radius_mm:g} mm" if task.profile == "circle" else f"θ {task.angle_deg:g}°"
        ax.plot(b, _safe_tbe(task, b), color=c_curve, lw=1.8,
                label=f"{task.name}: {task.profile} {shape}, {task.feed_mm_min:g} mm/min")
        ax.axhline(task.tolerance_um, color=c_tol, ls="-.", lw=1.2, alpha=0.9)
        ax.annotate(f"tolerance {task.tolerance_um:g} µm", (b[5], task.tolerance_um), color=c_tol, fontsize=8,
                    va="bottom")
        if limit is not None:
            ax.axvline(limit, color=c_lim, ls="-.", lw=1.2, alpha=0.9)
            ax.annotate(f"backlash limit {limit:.1f} µm", (limit, 0), color=c_lim, fontsize=8, rotation=90,
                        va="bottom", ha="right")
        if backlash_um is not None:
            ax.plot([backlash_um], _safe_tbe(task, np.array([backlash_um])), "o", color=c_curve if len(tasks) > 1
                    else "#ff7f0e", ms=8, mec="black")
    if backlash_um is not None:
        u = f" ± {backlash_uncertainty_um:.1f}" if backlash_uncertainty_um > 0 else ""
        ax.axvline(backlash_um, color="black", ls=":", lw=1.0, label=f"measured b̄ = {backlash_um:.1f}{u} µm (k = 2)")
        if backlash_uncertainty_um > 0:
            ax.axvspan(backlash_um - backlash_uncertainty_um, backlash_um + backlash_uncertainty_um,
                       color="grey", alpha=0.2)
    ax.set_xlabel("backlash width b (µm)")
    ax.set_ylabel("transient backlash error ε_b (µm)")
    ax.set_xlim(0, top)
    ax.set_ylim(bottom=0)
    ax.set_title(f"TBE vs backlash and their warning thresholds ({rule} decision rule) — {title}")
    ax.legend(loc="upper left", fontsize=8)
    return png_bytes(fig)


def thin_for_screen(values, *others, max_points: int = SCREEN_POINTS):
    """The series (and its companions) downsampled for the screen (min/max per bucket)."""
    idx = minmax_indices(values, max_points)
    if len(idx) == len(values):
        return (list(values), *[list(o) for o in others])
    return tuple([seq[i] for i in idx] for seq in (values, *others))


def mark_repairs(ax, repairs: Sequence[tuple[datetime, str]]) -> None:
    """Each repair as a vertical line labelled with its kind: the history on
    either side belongs to a different chain."""
    for i, (when, kind) in enumerate(repairs):
        ax.axvline(when, color="#2ca02c", ls=":", lw=1.6, label="repair" if i == 0 else None)
        ax.annotate(kind.replace("_", " "), xy=(when, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -3),
                    textcoords="offset points", rotation=90, va="top", ha="left", fontsize=7, color="#2ca02c")


def tbe_history(series: dict[str, tuple[list[datetime], list[float], list[float]]], *, title: str,
                repairs: Sequence[tuple[datetime, str]] = ()) -> bytes:
    """Fig. 15: the estimated TBE of each task over time against its threshold (repairs marked)."""
    thinned = {}
    for name, (t, tbe, tol) in series.items():
        tbe_d, t_d, tol_d = thin_for_screen(tbe, t, tol)
        thinned[name] = (t_d, tbe_d, tol_d)
    series = thinned
    fig, (ax,) = new_figure(10, 5)
    for i, (name, (t, tbe, tol)) in enumerate(series.items()):
        c = COLORS[i % len(COLORS)]
        tbe_a, tol_a = np.asarray(tbe, float), np.asarray(tol, float)
        ax.plot(t, tbe_a, "-", color=c, lw=1.2, label=f"TBE {name}")
        over = tbe_a > tol_a
        ax.plot([x for x, o in zip(t, over) if not o], tbe_a[~over], "o", color=c, ms=4)
        ax.plot([x for x, o in zip(t, over) if o], tbe_a[over], "o", color="#d62728", ms=6, mec="black",
                label=f"above tolerance ({int(over.sum())})" if over.any() else None)
        ax.step(t, tol_a, where="post", color=c, ls="-.", lw=1.4, label=f"threshold {name} ({tol_a[-1]:g} µm)")
    mark_repairs(ax, repairs)
    ax.set_xlabel("measured at (UTC)")
    ax.set_ylabel("estimated TBE ε_b (µm)")
    ax.set_title(f"TBE caused by the backlash — {title}")
    ax.legend(loc="best", fontsize=8)
    fig.autofmt_xdate()
    return png_bytes(fig)


def with_temperature_axis(ax, t, temperature_c, fmt: str, **style) -> tuple[list, list]:
    """The ambient temperature on a second y axis (Figs. 10 and the prognosis), where it
    was recorded; the legend handles and labels of both axes, for one legend."""
    lines, labels = ax.get_legend_handles_labels()
    tt = [(x, v) for x, v in zip(t, temperature_c) if v is not None]
    if tt:
        ax2 = ax.twinx()
        ax2.plot([x for x, _ in tt], [v for _, v in tt], fmt, color="#ff7f0e", label="ambient temperature t", **style)
        ax2.set_ylabel("ambient temperature t (°C)", color="#ff7f0e")
        l2, lab2 = ax2.get_legend_handles_labels()
        lines, labels = lines + l2, labels + lab2
    return lines, labels


def backlash_trend(t: list[datetime], backlash_um: list[float], temperature_c: list[float | None], *,
                   limit_um: float | None, title: str, repairs: Sequence[tuple[datetime, str]] = ()) -> bytes:
    """Fig. 10: mean backlash b̄ and ambient temperature over time, repairs marked."""
    backlash_um, t, temperature_c = thin_for_screen(backlash_um, t, temperature_c)
    fig, (ax,) = new_figure(10, 5)
    ax.plot(t, backlash_um, "o-", color="black", ms=4, lw=1.2, label="mean backlash b̄")
    if limit_um is not None:
        ax.axhline(limit_um, color="#d62728", ls="-.", lw=1.4, label=f"backlash limit {limit_um:.1f} µm")
    mark_repairs(ax, repairs)
    ax.set_xlabel("measured at (UTC)")
    ax.set_ylabel("mean backlash width b̄ (µm)")
    lines, labels = with_temperature_axis(ax, t, temperature_c, "s--", ms=3, lw=1.0)
    ax.legend(lines, labels, loc="best", fontsize=8, framealpha=0.9)
    ax.set_title(f"mean backlash and temperature — {title}")
    fig.autofmt_xdate()
    return png_bytes(fig)


def _rms(x) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def gap_residual(curve: dict, effect: str) -> bytes:
    """One test run of a gap diagnosis: measured minus the nominal model, and measured
    minus the model with the diagnosed ``effect`` ("none": the nominal model again);
    along the nut travel for a round trip (``u_mm``), against the angle or the distance
    along the path for a contour (``angle_deg``). The RMS of each is in its legend."""
    label = effect if effect != "none" else "nominal (no effect named)"
    fig, (ax,) = new_figure(9, 3.6)
    nominal, corrected = np.asarray(curve["nominal_um"], float), np.asarray(curve["corrected_um"], float)
    if "u_mm" in curve:
        x = np.asarray(curve["u_mm"], float)
        ax.plot(x, nominal, lw=0.5, label=f"measured - nominal (RMS {_rms(nominal):.2f} µm)")
        ax.plot(x, corrected, lw=0.5, label=f"measured - {label} (RMS {_rms(corrected):.2f} µm)")
        ax.set_xlabel("nut travel k_a x_m (mm)")
        ax.set_ylabel("table given motor: residual (µm)")
        ax.set_title(f"{curve['file']} (axis {curve.get('axis')}, test run)")
    else:
        x = np.asarray(curve["angle_deg"], float)
        ax.plot(x, nominal, ".", ms=1, label=f"measured - nominal (RMS {_rms(nominal):.2f} µm)")
        ax.plot(x, corrected, ".", ms=1, label=f"measured - {label} (RMS {_rms(corrected):.2f} µm)")
        ax.set_xlabel("angle (deg)" if curve["kind"] == "circle" else "distance along the line (mm)")
        ax.set_ylabel("contour error residual (µm)")
        if curve["kind"] == "circle":
            for q in (0, 90, 180, 270, 360):
                ax.axvline(q, color="0.8", lw=0.5)
        ax.set_title(f"{curve['file']} ({curve['kind']}, test run)")
    ax.legend(loc="best", fontsize=8, markerscale=8)
    return png_bytes(fig)


def thin_residuals(curve: dict, max_points: int = SCREEN_POINTS) -> dict:
    """``curve`` (numpy arrays) as JSON-able lists of at most ``max_points`` points: the
    minimum and maximum of both residuals per bucket (a 1000-pixel chart loses nothing)."""
    nominal, corrected = np.asarray(curve["nominal_um"], float), np.asarray(curve["corrected_um"], float)
    idx = np.union1d(minmax_indices(nominal, max_points // 2), minmax_indices(corrected, max_points // 2))
    out = {k: v for k, v in curve.items() if k not in ("u_mm", "angle_deg", "nominal_um", "corrected_um")}
    for k in ("u_mm", "angle_deg", "nominal_um", "corrected_um"):
        if k in curve and curve[k] is not None:
            out[k] = np.asarray(curve[k], float)[idx].tolist()
    out["rms_nominal_um"], out["rms_corrected_um"] = _rms(nominal), _rms(corrected)  # of every point
    return out
