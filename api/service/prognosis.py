"""An axis' prognosis (core.prognosis) and its history clearance estimate
(core.criteria.lost_motion), from its stored history.

Reads at most ``MAX_ROWS`` measurements (a regular thinning past that: a year of
measurements every ten minutes is 52,560 rows, and the Huber fit's intervals do not
need them all), and memoises the answer per axis (a HistoryMemo, one per status cache)
on what it depends on (the newest measurement, the tasks, the rule, the worst-case
temperature), so the status cache's
periodic recomputation does not refit an unchanged history. Past ``MAX_ROWS`` the fit is
redone once per thinning step of new measurements, not on each (``_history_fit``).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from datetime import datetime

import numpy as np

from core.criteria.lost_motion import ClearanceEstimate, clearance_from_feeds
from core.prognosis import Prognosis, days_per_second, fit_thermal_wear, prognosis
from storage.db import AxisRecord, ResultRecord, maintenance_repo, results_repo, utcnow

MAX_ROWS = 3000


@dataclass(frozen=True)
class HistoryAnswers:
    prognosis: Prognosis
    clearance: ClearanceEstimate
    rows_used: int
    rows_total: int
    computed_at: datetime
    # the history the plot draws: (measured_at_s, temperature_c, utility_day, backlash_mean_um)
    series: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    fitted_since: datetime | None = None  # the last repair: the fit uses only what came after


def _key(axis: AxisRecord, latest: ResultRecord | None, history_n: int, since: datetime | None = None) -> tuple:
    st = axis.settings
    return (latest.id if latest else None, history_n, since, st.tasks, st.decision_rule, st.warning_fraction,
            st.worst_case_temperature_c,
            latest.round_trip.backlash_mean_uncertainty_um if latest and latest.round_trip.budgets else 0.0)


class HistoryMemo:
    """The last answers per axis of one database (the status cache owns one), with what
    they were computed from, and the last fit of the history (:class:`HistoryFit`)."""

    def __init__(self) -> None:
        self._memo: dict[tuple[str, int], tuple[tuple, object]] = {}
        self._lock = threading.Lock()

    def get(self, axis_id: int, key: tuple, kind: str = "answers"):
        with self._lock:
            hit = self._memo.get((kind, axis_id))
        return hit[1] if hit is not None and hit[0] == key else None

    def put(self, axis_id: int, key: tuple, value, kind: str = "answers") -> None:
        with self._lock:
            self._memo[(kind, axis_id)] = (key, value)

    def last(self, axis_id: int, kind: str):
        """(key, value) last put for the axis, whatever its key; None if none."""
        with self._lock:
            return self._memo.get((kind, axis_id))

    def staged(self) -> StagedMemo:
        """A view that reads this memo and keeps its own writes until :meth:`StagedMemo.apply`
        (for a computation inside a transaction that may still roll back)."""
        return StagedMemo(self)


class StagedMemo:
    def __init__(self, parent: HistoryMemo) -> None:
        self._parent = parent
        self._puts: dict[tuple[str, int], tuple[tuple, object]] = {}

    def get(self, axis_id: int, key: tuple, kind: str = "answers"):
        hit = self.last(axis_id, kind)
        return hit[1] if hit is not None and hit[0] == key else None

    def last(self, axis_id: int, kind: str):
        hit = self._puts.get((kind, axis_id))
        return hit if hit is not None else self._parent.last(axis_id, kind)

    def put(self, axis_id: int, key: tuple, value, kind: str = "answers") -> None:
        self._puts[(kind, axis_id)] = (key, value)

    def apply(self) -> None:
        for (kind, axis_id), (key, value) in self._puts.items():
            self._parent.put(axis_id, key, value, kind)


@dataclass(frozen=True)
class HistoryFit:
    """The rows read and what was fitted on them; reused while fewer new measurements than
    one thinning step have come (see :func:`_history_fit`)."""
    rows: dict
    fit: object
    clearance: ClearanceEstimate
    history_n: int  # the rollups' count when it was made

    @property
    def step(self) -> int:
        """How many rows the thinning skips: 1 up to MAX_ROWS rows."""
        return max(1, -(-int(self.rows["total"]) // MAX_ROWS))


def _history_fit(s, axis_id: int, history_n: int, since: datetime | None, memo) -> HistoryFit:
    """The fit of the axis' history since ``since``. Up to MAX_ROWS rows it is redone on
    every new measurement. Past that, the history is thinned to every k-th row anyway, so
    it is redone once k more measurements have come (k the thinning step): reading and
    thinning a year of rows took 0.47 s on the 2-core machine, and the status is
    recomputed after every cycle. The newest measurement's own figures (its
    b̄'s uncertainty, its utility day) enter the prognosis at once; only the fitted
    history lags, by fewer than k measurements."""
    last = memo.last(axis_id, "fit") if memo is not None else None
    if last is not None:
        (since_then,), hf = last
        if since_then == since and 0 <= history_n - hf.history_n < hf.step:
            return hf
    rows = results_repo.history_rows(s, axis_id, max_rows=MAX_ROWS, since=since)
    fit = fit_thermal_wear(rows["temperature_c"], rows["utility_day"], rows["backlash_mean_um"])
    clear = clearance_from_feeds(rows["feed_mm_min"], rows["backlash_mean_um"], source="history",
                                 temperature_c=rows["temperature_c"])
    hf = HistoryFit(rows, fit, clear, history_n)
    if memo is not None:
        memo.put(axis_id, (since,), hf, "fit")
    return hf


def history_answers(s, axis: AxisRecord, latest: ResultRecord | None, history_n: int,
                    memo: HistoryMemo | None = None) -> HistoryAnswers:
    """The prognosis and the history's clearance estimate of ``axis``, memoised in
    ``memo`` on the newest result and ``history_n`` (how many results with a temperature
    the rollups count: a deletion by the retention policy or an import changes it)."""
    since = maintenance_repo.last_repair_at(s, axis.id)  # a repair resets b̄ and the wear term
    key = _key(axis, latest, history_n, since)
    hit = memo.get(axis.id, key) if memo is not None else None
    if hit is not None:
        return hit
    hf = _history_fit(s, axis.id, history_n, since, memo)
    rows = hf.rows
    t_s, temp, day, b = rows["measured_at_s"], rows["temperature_c"], rows["utility_day"], rows["backlash_mean_um"]
    now = utcnow()
    day_now = latest.utility_day if latest is not None and latest.utility_day is not None else (
        float(np.nanmax(day)) if np.isfinite(day).any() else None)
    u_b = latest.round_trip.backlash_mean_uncertainty_um if latest and latest.round_trip.budgets else 0.0
    p = prognosis(hf.fit, axis.tasks, worst_case_temperature_c=axis.settings.worst_case_temperature_c,
                  now_s=now.timestamp(), day_now=day_now, days_per_second=days_per_second(day, t_s),
                  backlash_uncertainty_um=u_b, warning_fraction=axis.settings.warning_fraction,
                  rule=axis.settings.decision_rule)
    out = HistoryAnswers(p, hf.clearance, int(t_s.size), int(rows["total"]), now, (t_s, temp, day, b), since)
    if memo is not None:
        memo.put(axis.id, key, out)
    return out


def iso(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, tz=utcnow().tzinfo).isoformat().replace("+00:00", "Z")


def to_dict(h: HistoryAnswers, *, points: bool = True) -> dict:
    """The JSON body of ``GET /axes/{id}/prognosis``; with ``points`` False the status'
    ``prognosis`` (the history clearance's points counted, not listed)."""
    return {
        **h.prognosis.to_dict(iso=iso),
        "rows_used": h.rows_used, "rows_total": h.rows_total,
        "fitted_since_repair": None if h.fitted_since is None else h.fitted_since.isoformat().replace("+00:00", "Z"),
        "computed_at": h.computed_at.isoformat().replace("+00:00", "Z"),
        "clearance_history": h.clearance.to_dict(points=points),
    }
