"""An axis' prognosis (core.prognosis) and its history clearance estimate
(core.criteria.lost_motion), from its stored history.

Reads at most ``MAX_ROWS`` measurements (a regular thinning past that: a year of
measurements every ten minutes is 52,560 rows, and the Huber fit's intervals do not
need them all), and memoises the answer per axis (a HistoryMemo, one per status cache)
on what it depends on (the newest measurement, the tasks, the rule, the worst-case
temperature), so the status cache's
periodic recomputation does not refit an unchanged history.
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
    fitted_since: datetime | None = None  # the last repair: the fit uses only what came after (issue 20)


def _key(axis: AxisRecord, latest: ResultRecord | None, history_n: int, since: datetime | None = None) -> tuple:
    st = axis.settings
    return (latest.id if latest else None, history_n, since, st.tasks, st.decision_rule, st.warning_fraction,
            st.worst_case_temperature_c,
            latest.round_trip.backlash_mean_uncertainty_um if latest and latest.round_trip.budgets else 0.0)


class HistoryMemo:
    """The last answers per axis of one database (the status cache owns one), with what
    they were computed from."""

    def __init__(self) -> None:
        self._memo: dict[int, tuple[tuple, HistoryAnswers]] = {}
        self._lock = threading.Lock()

    def get(self, axis_id: int, key: tuple) -> HistoryAnswers | None:
        with self._lock:
            hit = self._memo.get(axis_id)
        return hit[1] if hit is not None and hit[0] == key else None

    def put(self, axis_id: int, key: tuple, answers: HistoryAnswers) -> None:
        with self._lock:
            self._memo[axis_id] = (key, answers)


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
    rows = results_repo.history_rows(s, axis.id, max_rows=MAX_ROWS, since=since)
    t_s, temp, day, b = rows["measured_at_s"], rows["temperature_c"], rows["utility_day"], rows["backlash_mean_um"]
    fit = fit_thermal_wear(temp, day, b)
    now = utcnow()
    day_now = latest.utility_day if latest is not None and latest.utility_day is not None else (
        float(np.nanmax(day)) if np.isfinite(day).any() else None)
    u_b = latest.round_trip.backlash_mean_uncertainty_um if latest and latest.round_trip.budgets else 0.0
    p = prognosis(fit, axis.tasks, worst_case_temperature_c=axis.settings.worst_case_temperature_c,
                  now_s=now.timestamp(), day_now=day_now, days_per_second=days_per_second(day, t_s),
                  backlash_uncertainty_um=u_b, warning_fraction=axis.settings.warning_fraction,
                  rule=axis.settings.decision_rule)
    clear = clearance_from_feeds(rows["feed_mm_min"], b, source="history", temperature_c=temp)
    out = HistoryAnswers(p, clear, int(t_s.size), int(rows["total"]), now, (t_s, temp, day, b), since)
    if memo is not None:
        memo.put(axis.id, key, out)
    return out


def iso(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, tz=utcnow().tzinfo).isoformat().replace("+00:00", "Z")


def to_dict(h: HistoryAnswers) -> dict:
    """The JSON body of ``GET /axes/{id}/prognosis`` (and the status' ``prognosis``)."""
    return {
        **h.prognosis.to_dict(iso=iso),
        "rows_used": h.rows_used, "rows_total": h.rows_total,
        "fitted_since_repair": None if h.fitted_since is None else h.fitted_since.isoformat().replace("+00:00", "Z"),
        "computed_at": h.computed_at.isoformat().replace("+00:00", "Z"),
        "clearance_history": h.clearance.to_dict(),
    }
