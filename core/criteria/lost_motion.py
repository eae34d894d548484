"""Lost motion of the chain in ISO 230-2 terms, and the clearance behind it.

The round trip compares the table (linear encoder) with the motor's nominal travel
l_0 = k_a x_m. The difference between the two approach directions at a target P_i is
the reversal value B_i. It holds everything the table loses at a reversal: the
clearance (the geometric gap between nut and screw flanks) *and* the elastic wind-up
of the chain under friction (2 F / k: the nut must load the spring to the friction
force in each direction before the table moves), plus anything proportional to speed
(viscous friction, a sampling skew). ISO 230-2 calls the total the reversal value;
machine-tool practice calls it lost motion. The seed paper's b̄ is this total.

- B_i = x̄_i↓ - x̄_i↑ at targets P_i spread over the useful travel (x̄ the mean
  deviation l_a - l_0 over the strokes of one direction). ISO 230-2 writes
  B_i = x̄_i↑ - x̄_i↓ with deviations taken as actual minus target; with the motor as
  the target and the table lagging it, that is the negative of ours. The sign here
  makes a backlash positive, as b(x) (Eq. 5) is.
- B̄ = mean of B_i; B = max |B_i|.
- The clearance: friction's wind-up grows with the feed (viscous part), the gap does
  not. A straight-line fit of the lost motion against feed, over the feeds of one
  program or of the history, gives its feed-independent part at feed 0. That part
  still holds the Coulomb wind-up 2 F_c / k, which no position signal can tell from
  a gap (it would take the motor current): it is an upper bound of the clearance, and
  is reported as such.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.errors import InputError

DEFAULT_TARGETS = 11
MIN_FEED_RATIO = 1.2  # feeds closer than this are one feed for the fit
COULOMB_NOTE = ("the feed-independent lost motion: the clearance plus the Coulomb friction wind-up "
                "2 F_c/k, which a position signal cannot tell apart (an upper bound of the clearance)")


@dataclass(frozen=True)
class ClearanceEstimate:
    """Feed-independent part of the lost motion (``clearance_um``, with its expanded
    uncertainty, k = 2), the slope against feed, the feeds used; or ``clearance_um``
    None and ``reason`` saying why it cannot be separated."""

    clearance_um: float | None
    clearance_uncertainty_um: float | None
    slope_um_per_m_min: float | None  # µm of lost motion per m/min of feed
    feeds_mm_min: tuple[float, ...]
    lost_motion_um: tuple[float, ...]
    source: str  # "program" or "history"
    reason: str

    def to_dict(self, *, points: bool = True) -> dict:
        """``points`` False: the count of the (feed, lost motion) points instead of their
        lists (a history's are up to 3000 of each; the status the MES polls needs none)."""
        if not points:
            out = self.to_dict()
            del out["feeds_mm_min"], out["lost_motion_um"]
            return {**out, "points": len(self.feeds_mm_min)}
        return {
            "clearance_um": self.clearance_um,
            "clearance_uncertainty_um": self.clearance_uncertainty_um,
            "slope_um_per_m_min": self.slope_um_per_m_min,
            "feeds_mm_min": list(self.feeds_mm_min),
            "lost_motion_um": list(self.lost_motion_um),
            "source": self.source,
            "reason": self.reason,
        }


@dataclass(frozen=True)
class LostMotion:
    """Reversal values B_i (µm) at ``target_mm``; B̄ (``mean_um``) and B (``max_abs_um``)."""

    target_mm: np.ndarray
    reversal_um: np.ndarray
    mean_um: float
    max_abs_um: float
    clearance: ClearanceEstimate

    def to_dict(self) -> dict:
        return {
            "reversal_target_mm": [float(x) for x in self.target_mm],
            "reversal_um": [float(x) for x in self.reversal_um],
            "reversal_mean_um": self.mean_um,
            "reversal_max_um": self.max_abs_um,
            "clearance": self.clearance.to_dict(),
        }


def reversal_targets_mm(start_mm: float, end_mm: float, n: int = DEFAULT_TARGETS) -> np.ndarray:
    """``n`` targets spread evenly over [start, end] (ISO 230-2 asks for at least 5, and
    5 per metre)."""
    n = max(int(n), 5, int(math.ceil(5.0 * (end_mm - start_mm) / 1000.0)) + 1)
    return np.linspace(start_mm, end_mm, n)


def clearance_from_feeds(feed_mm_min, lost_motion_um, uncertainty_um=None, *, source: str = "program",
                         temperature_c=None) -> ClearanceEstimate:
    """Fit lost motion = B0 + s feed (+ β (T - 20 °C) when ``temperature_c`` is given:
    across a history the temperature moves b̄ too) by weighted least squares; B0 is the
    feed-independent part. Needs two feeds at least ``MIN_FEED_RATIO`` apart (three
    points with temperature). ``uncertainty_um``: standard uncertainty of each point
    (None: from the residuals)."""
    f = np.asarray(feed_mm_min, dtype=float)
    b = np.asarray(lost_motion_um, dtype=float)
    if f.shape != b.shape or f.ndim != 1:
        raise InputError(f"feed_mm_min and lost_motion_um must be 1-D of equal length, got {f.shape} and {b.shape}")
    u = None if uncertainty_um is None else np.broadcast_to(np.asarray(uncertainty_um, dtype=float), f.shape)
    temp = None if temperature_c is None else np.asarray(temperature_c, dtype=float)
    keep = np.isfinite(f) & np.isfinite(b) & (f > 0)
    if temp is not None:
        keep &= np.isfinite(temp)
    f, b = f[keep], b[keep]
    u = None if u is None else u[keep]
    temp = None if temp is None else temp[keep]
    feeds = tuple(float(x) for x in f)
    lost = tuple(float(x) for x in b)

    def none(reason: str) -> ClearanceEstimate:
        return ClearanceEstimate(None, None, None, feeds, lost, source, reason)

    if f.size == 0:
        return none("no lost motion with a feed to fit")
    ratio = float(f.max() / f.min())
    if ratio < MIN_FEED_RATIO:
        return none(f"all {source} measurements ran at one feed ({f.min():.0f}..{f.max():.0f} mm/min, "
                    f"need feeds {MIN_FEED_RATIO:g}x apart): the feed-dependent part cannot be separated")
    cols = [np.ones_like(f), f / 1000.0]
    if temp is not None and np.ptp(temp) >= 1.0:
        cols.append(temp - 20.0)
    a = np.column_stack(cols)
    p = a.shape[1]
    if f.size < p or (u is None and f.size <= p and f.size > 2):
        return none(f"{f.size} points for {p} parameters: too few to fit")
    w = np.ones_like(f) if u is None else 1.0 / np.maximum(u, 1e-6)
    coef, *_ = np.linalg.lstsq(a * w[:, None], b * w, rcond=None)
    resid = b - a @ coef
    try:
        cov0 = np.linalg.inv((a * w[:, None]).T @ (a * w[:, None]))
    except np.linalg.LinAlgError:
        return none("the feeds and temperatures are collinear: the fit is not identifiable")
    if u is None:
        dof = f.size - p
        if dof <= 0:  # a line through two points: no scatter to take an uncertainty from
            return ClearanceEstimate(float(coef[0]), None, float(coef[1]), feeds, lost, source,
                                     COULOMB_NOTE + "; exact through two points, no uncertainty")
        cov = cov0 * float(resid @ resid / dof)
    else:
        cov = cov0
    u0 = math.sqrt(max(float(cov[0, 0]), 0.0))
    return ClearanceEstimate(float(coef[0]), 2.0 * u0, float(coef[1]), feeds, lost, source, COULOMB_NOTE)


def stroke_lost_motion(time_s, travel_mm, dev_mm, strokes, start_mm: float, end_mm: float, stride: int,
                       n_bins: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per feed of a program: (feeds_mm_min, lost_motion_um, standard uncertainty µm).

    Each stroke's deviation is averaged in ``n_bins`` bins of the useful travel (on every
    ``stride``-th sample: an estimate, not the criteria, so a subsample does) and its
    feed taken as the median speed there; strokes are grouped by feed (``MIN_FEED_RATIO``),
    and within a group the lost motion is the mean over the bins of (x̄↓ - x̄↑)."""
    width = (end_mm - start_mm) / n_bins
    rows = []
    for s in strokes:
        sl = slice(s.engaged, s.end + 1, stride)
        u, d, t = travel_mm[sl], dev_mm[sl], time_s[sl]
        inside = (u >= start_mm) & (u <= end_mm)
        if np.count_nonzero(inside) < 3:
            continue
        u, d, t = u[inside], d[inside], t[inside]
        speed = np.abs(np.diff(u)) / np.diff(t)
        idx = np.clip(((u - start_mm) / width).astype(np.int64), 0, n_bins - 1)
        cnt = np.bincount(idx, minlength=n_bins)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.bincount(idx, weights=d, minlength=n_bins) / cnt
        rows.append((s.direction, float(np.median(speed)) * 60.0, mean))
    if not rows:
        return np.empty(0), np.empty(0), np.empty(0)
    order = sorted(range(len(rows)), key=lambda i: rows[i][1])
    groups, current = [], [order[0]]
    for i in order[1:]:
        if rows[i][1] > MIN_FEED_RATIO ** 0.5 * rows[current[0]][1]:
            groups.append(current)
            current = [i]
        else:
            current.append(i)
    groups.append(current)
    feeds, lost, unc = [], [], []
    for g in groups:
        by = {d: [rows[i][2] for i in g if rows[i][0] == d] for d in (1, -1)}
        if not by[1] or not by[-1]:
            continue
        diff = (_bin_means(by[-1]) - _bin_means(by[1])) * 1e3
        diff = diff[np.isfinite(diff)]
        if diff.size < 2:
            continue
        feeds.append(float(np.median([rows[i][1] for i in g])))
        lost.append(float(diff.mean()))
        unc.append(float(diff.std(ddof=1) / math.sqrt(diff.size)))
    return np.array(feeds), np.array(lost), np.array(unc)


def _bin_means(rows: list[np.ndarray]) -> np.ndarray:
    """Per bin, the mean over the strokes that have samples there; NaN for a bin none has
    (a hole in the trace), which the caller leaves out (np.nanmean would warn there)."""
    a = np.asarray(rows, dtype=float)
    n = np.count_nonzero(np.isfinite(a), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.nansum(a, axis=0) / n


def lost_motion(position_mm, backlash_um, *, start_mm: float, end_mm: float,
                feeds_mm_min=(), feed_lost_motion_um=(), feed_uncertainty_um=(),
                n_targets: int = DEFAULT_TARGETS) -> LostMotion:
    """B_i at the targets (read off b(x) = x̄↓ - x̄↑ on its grid), B̄, B, and the
    clearance from the per-feed lost motion of the program (``stroke_lost_motion``)."""
    targets = reversal_targets_mm(start_mm, end_mm, n_targets)
    b_i = np.interp(targets, np.asarray(position_mm, float), np.asarray(backlash_um, float))
    f = np.asarray(feeds_mm_min, dtype=float)
    if f.size >= 2:
        # the spread between bins is the lead curve's, common to both feeds: a floor of
        # 0.05 µm keeps one perfectly smooth simulation from weighting to infinity
        clear = clearance_from_feeds(f, feed_lost_motion_um, np.maximum(np.asarray(feed_uncertainty_um), 0.05))
    else:
        only = f"{f[0]:.0f} mm/min" if f.size else "one feed"
        clear = ClearanceEstimate(None, None, None, tuple(float(x) for x in f),
                                  tuple(float(x) for x in feed_lost_motion_um), "program",
                                  f"the program ran at one feed ({only}): the clearance cannot be separated "
                                  "from the friction's lost motion within it (see the history's estimate)")
    return LostMotion(targets, b_i, float(b_i.mean()), float(np.max(np.abs(b_i))), clear)
