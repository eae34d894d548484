"""Hourly rollups of an axis' trend, so that /trend, the trend plot and the status cost
the same after a year of one-minute cycles as after a day.

Each stored result rebuilds the rollup of its hour from that hour's rows
(:func:`refresh`); a migration or a bulk load rebuilds them all (:func:`rebuild`).
:func:`trend_view` reads the hours wholly inside the asked range from the rollups and
only the rows of the partial hours at its edges; a range of few rows is read row by row
as before. The shown points are the measurements a min/max downsampling of b̄ keeps,
and the correlations and the thermal model come from the added moment sums, so they
equal those of every row (to rounding).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from datetime import datetime, timedelta

import numpy as np
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from core.downsample import minmax_indices
from core.history import MomentSums

from .models import LeadCriteriaRow, Result, TrendRollup
from .records import TrendSeries, TrendView, as_utc

HOUR = timedelta(hours=1)
CRITERIA = ("backlash_mean_um", "e_p_um_per_1000mm", "v_u_um", "v_300_um", "v_2pi_um")
#: drivers of the correlations, with the origin of their moment sums
DRIVERS = {"temperature_c": 20.0, "utility_day": 0.0}

_COLUMNS = (Result.cycle_id, Result.measured_at, Result.temperature_c, Result.utility_day, Result.backlash_mean_um,
            LeadCriteriaRow.e_p_um_per_1000mm, LeadCriteriaRow.v_u_um, LeadCriteriaRow.v_300_um,
            LeadCriteriaRow.v_2pi_um)  # fmt: skip


def hour_of(t: datetime) -> datetime:
    return as_utc(t).replace(minute=0, second=0, microsecond=0)


def _select(axis_id: int | None):
    """The trend columns of the positive stroke; of one axis, or (None) by other keys only."""
    q = select(*_COLUMNS).join(
        LeadCriteriaRow, (LeadCriteriaRow.result_id == Result.id) & (LeadCriteriaRow.direction == "positive"))
    return q if axis_id is None else q.where(Result.axis_id == axis_id)


def _rows(s: Session, axis_id: int, lo: datetime | None, hi: datetime | None, *, hi_inclusive: bool) -> list[tuple]:
    q = _select(axis_id)
    if lo is not None:
        q = q.where(Result.measured_at >= lo)
    if hi is not None:
        q = q.where(Result.measured_at <= hi if hi_inclusive else Result.measured_at < hi)
    return [tuple(r) for r in s.execute(q.order_by(Result.measured_at, Result.id)).all()]


def _series(rows: Sequence[tuple]) -> TrendSeries:
    cols = list(zip(*rows)) if rows else [()] * 9
    return TrendSeries(
        measurement_id=tuple(cols[0]), measured_at=tuple(as_utc(t) for t in cols[1]), temperature_c=tuple(cols[2]),
        utility_day=tuple(cols[3]), backlash_mean_um=tuple(cols[4]), e_p_um_per_1000mm=tuple(cols[5]),
        v_u_um=tuple(cols[6]), v_300_um=tuple(cols[7]), v_2pi_um=tuple(cols[8]),
    )  # fmt: skip


def _arrays(rows: Sequence[tuple]) -> dict[str, np.ndarray]:
    names = ("temperature_c", "utility_day", *CRITERIA)
    if not rows:
        return {n: np.zeros(0) for n in names}
    cols = list(zip(*rows))
    return {n: np.array(cols[i + 2], dtype=float) for i, n in enumerate(names)}  # None -> NaN


def stats_of(rows: Sequence[tuple]) -> dict[str, dict[str, MomentSums]]:
    """Moment sums of every criterion against every driver, over ``rows``."""
    a = _arrays(rows)
    return {d: {c: MomentSums.of(a[d], a[c], x0=x0) for c in CRITERIA} for d, x0 in DRIVERS.items()}


_SUM_FIELDS = slice(0, 6)  # n and the sums; then x_min, x_max, y_min, y_max


def _pack(stats: dict) -> bytes:
    """The moment sums as float64 [driver][criterion][field] (NaN: an empty range)."""
    a = np.array([[[np.nan if v is None else v for v in stats[d][c].to_list()] for c in CRITERIA] for d in DRIVERS],
                 dtype="<f8")  # fmt: skip
    return a.tobytes()


def _combine(arrays: list[np.ndarray]) -> dict[str, dict[str, MomentSums]]:
    """Add blocks of packed moment sums, each (k, drivers, criteria, fields), into MomentSums."""
    a = np.concatenate(arrays) if arrays else np.full((1, len(DRIVERS), len(CRITERIA), 10), np.nan)
    tot = np.nansum(a[..., _SUM_FIELDS], axis=0)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN ranges stay NaN
        lo = np.nanmin(a[..., [6, 8]], axis=0)
        hi = np.nanmax(a[..., [7, 9]], axis=0)
    lo = np.where(np.isnan(lo), math.inf, lo)
    hi = np.where(np.isnan(hi), -math.inf, hi)
    out: dict[str, dict[str, MomentSums]] = {}
    for i, (d, x0) in enumerate(DRIVERS.items()):
        out[d] = {}
        for j, c in enumerate(CRITERIA):
            n, sx, sy, sxx, syy, sxy = (float(v) for v in tot[i, j])
            out[d][c] = MomentSums(int(n), sx, sy, sxx, syy, sxy, float(lo[i, j, 0]), float(hi[i, j, 0]),
                                   float(lo[i, j, 1]), float(hi[i, j, 1]), x0=x0)  # fmt: skip
    return out


def _bucket_row(axis_id: int, start: datetime, rows: Sequence[tuple]) -> dict:
    b = np.array([r[4] for r in rows], dtype=float)
    lo, hi = int(np.argmin(b)), int(np.argmax(b))
    return dict(axis_id=axis_id, bucket_start=start, n=len(rows), b_min_cycle_id=int(rows[lo][0]),
                b_min_um=float(b[lo]), b_max_cycle_id=int(rows[hi][0]), b_max_um=float(b[hi]),
                stats=_pack(stats_of(rows)))  # fmt: skip


def refresh(s: Session, axis_id: int, when: datetime) -> None:
    """Rebuild the rollup of the hour of ``when`` from its rows."""
    start = hour_of(when)
    rows = _rows(s, axis_id, start, start + HOUR, hi_inclusive=False)
    s.execute(delete(TrendRollup).where(TrendRollup.axis_id == axis_id, TrendRollup.bucket_start == start))
    if rows:
        s.add(TrendRollup(**_bucket_row(axis_id, start, rows)))
    s.flush()


def rebuild(s: Session, axis_id: int | None = None, chunk: int = 50_000) -> int:
    """Rebuild every rollup (of one axis, or of all); returns the number of hours. For a
    migration and for data loaded in bulk beside the service."""
    axes = [axis_id] if axis_id is not None else [a for (a,) in s.execute(select(Result.axis_id).distinct())]
    n_hours = 0
    for a in axes:
        s.execute(delete(TrendRollup).where(TrendRollup.axis_id == a))
        last_id = 0
        pending: list[tuple] = []
        current: datetime | None = None
        out: list[dict] = []
        while True:  # in id-keyed chunks: a year of rows is not held at once
            q = _select(a).where(Result.cycle_id > last_id).order_by(Result.cycle_id).limit(chunk)
            rows = [tuple(r) for r in s.execute(q).all()]
            if not rows:
                break
            last_id = int(rows[-1][0])
            for r in sorted(rows, key=lambda r: (as_utc(r[1]), r[0])):
                h = hour_of(r[1])
                if current is not None and h != current:
                    out.append(_bucket_row(a, current, pending))
                    pending = []
                current = h
                pending.append(r)
        if pending:
            out.append(_bucket_row(a, current, pending))
        # rows out of time order across chunks (ids not in time order): such an hour is read again whole
        merged: dict[datetime, list] = {}
        for b in out:
            merged.setdefault(b["bucket_start"], []).append(b)
        for start, parts in merged.items():
            if len(parts) > 1:
                parts[:] = [_bucket_row(a, start, _rows(s, a, start, start + HOUR, hi_inclusive=False))]
        if merged:
            s.execute(TrendRollup.__table__.insert(), [p[0] for p in merged.values()])
        n_hours += len(merged)
    s.flush()
    return n_hours


def trend_view(s: Session, axis_id: int, *, since: datetime | None = None, until: datetime | None = None,
               max_points: int | None = None) -> TrendView:
    """The trend of ``[since, until]``: at most ``max_points`` points (the measurements a
    min/max downsampling of b̄ keeps; all of them when None), the number of measurements
    in the range, and the moment sums over all of them."""
    since, until = (as_utc(since) if since else None), (as_utc(until) if until else None)
    cols = (TrendRollup.bucket_start, TrendRollup.n, TrendRollup.b_min_cycle_id, TrendRollup.b_min_um,
            TrendRollup.b_max_cycle_id, TrendRollup.b_max_um, TrendRollup.stats)  # fmt: skip
    q = select(*cols).where(TrendRollup.axis_id == axis_id)
    if since is not None:  # whole hours inside the range only
        q = q.where(TrendRollup.bucket_start >= (since if since == hour_of(since) else hour_of(since) + HOUR))
    if until is not None:
        q = q.where(TrendRollup.bucket_start <= until - HOUR)
    buckets = [tuple(r) for r in s.execute(q.order_by(TrendRollup.bucket_start)).all()]
    in_buckets = sum(b[1] for b in buckets)
    # rows one by one when all are asked for, or when the hours' min/max would show fewer
    # points than asked (a short range); the rollups otherwise
    if max_points is None or in_buckets <= max_points or 2 * len(buckets) < max_points:
        rows = _rows(s, axis_id, since, until, hi_inclusive=True)
        return _view_of_rows(rows, max_points)
    lo_edge = as_utc(buckets[0][0])
    hi_edge = as_utc(buckets[-1][0]) + HOUR
    head = _rows(s, axis_id, since, lo_edge, hi_inclusive=False)
    tail = _rows(s, axis_id, hi_edge, until, hi_inclusive=True)
    shape = (len(DRIVERS), len(CRITERIA), 10)
    # one buffer for every hour's sums (not one array per hour: a year is 8,760 of them)
    packed = [np.frombuffer(b"".join(b[6] for b in buckets), dtype="<f8").reshape(-1, *shape)]
    for edge in (head, tail):
        if edge:
            packed.append(np.frombuffer(_pack(stats_of(edge)), dtype="<f8").reshape(1, *shape))
    stats = _combine(packed)
    # each hour shows its cycles of smallest and largest b̄, in cycle id order (one when they are the same)
    mn_id, mx_id = (np.array([b[k] for b in buckets], dtype=np.int64) for k in (2, 4))
    mn_b, mx_b = (np.array([b[k] for b in buckets], dtype=float) for k in (3, 5))
    first = mn_id <= mx_id
    pair_ids = np.stack([np.where(first, mn_id, mx_id), np.where(first, mx_id, mn_id)], axis=1)
    pair_b = np.stack([np.where(first, mn_b, mx_b), np.where(first, mx_b, mn_b)], axis=1)
    two = np.stack([np.ones(len(buckets), bool), mn_id != mx_id], axis=1)
    ids: list[int] = [r[0] for r in head] + pair_ids[two].tolist() + [r[0] for r in tail]
    vals: list[float] = [r[4] for r in head] + pair_b[two].tolist() + [r[4] for r in tail]
    total = len(head) + len(tail) + in_buckets
    keep = range(len(ids)) if max_points is None else minmax_indices(vals, max_points).tolist()
    chosen = [ids[i] for i in keep]
    # by cycle id only: the ids are this axis' (from its rollups), and with the axis in the
    # WHERE SQLite walks the axis' whole (axis, time) index instead (64 ms against 10 ms a year)
    by_id = _select(None)
    rows = []
    for i in range(0, len(chosen), 5000):
        part = chosen[i : i + 5000]
        rows += [tuple(r) for r in s.execute(by_id.where(Result.cycle_id.in_(part))).all()]
    rows.sort(key=lambda r: (as_utc(r[1]), r[0]))
    return TrendView(_series(rows), total, stats)


def _view_of_rows(rows: list[tuple], max_points: int | None) -> TrendView:
    stats, total = stats_of(rows), len(rows)
    if max_points is not None and len(rows) > max_points:
        rows = [rows[i] for i in minmax_indices([r[4] for r in rows], max_points).tolist()]
    return TrendView(_series(rows), total, stats)
