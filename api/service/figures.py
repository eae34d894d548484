"""The figures of an axis (Figs. 5, 9, 10, 14, 15) as PNG bytes, from the stored results.

One function for every reader: the REST plot endpoint and the dashboard both call
:func:`render`, so the queries behind a figure exist once.
"""

from __future__ import annotations

import math
from datetime import datetime

from api.service import plots
from core.errors import MebmError
from storage.db import NotFoundError, config_repo, results_repo

NAMES = plots.NAMES


def backlash_limit_um(tasks) -> float | None:
    """The smallest finite backlash limit of ``tasks`` (None: no task limits it)."""
    lims = []
    for t in tasks:
        try:
            lims.append(t.backlash_limit_um())
        except MebmError:
            pass
    lims = [v for v in lims if math.isfinite(v)]
    return min(lims) if lims else None


def render(s, axis_id: int, name: str, *, measurement_id: int | None = None, direction: str = "positive",
           since: datetime | None = None) -> bytes:
    """The PNG of figure ``name`` (one of :data:`NAMES`) for ``axis_id``; an explanatory
    empty figure when there is nothing to draw yet."""
    axis = config_repo.get_axis(s, axis_id)
    title = f"{axis.machine_name} axis {axis.name}"
    limit = backlash_limit_um(axis.tasks)
    if name in ("backlash_profile", "lead_deviation"):
        if measurement_id is not None:
            c, r = results_repo.get_measurement(s, measurement_id)
            if c.axis_id != axis_id:
                raise NotFoundError(f"measurement of axis {axis_id}", measurement_id)
        else:
            r = results_repo.latest_result(s, axis_id, curves=True)
        if r is None or r.round_trip.backlash.position_mm.size == 0:
            return plots.empty(title, "no good measurement yet")
        rt = r.round_trip
        when = f"{r.measured_at:%Y-%m-%d %H:%M} UTC" + (
            f", {r.temperature_c:.1f} °C" if r.temperature_c is not None else "")
        if name == "backlash_profile":
            return plots.backlash_profile(
                rt.backlash.position_mm, rt.backlash.backlash_um, rt.strokes["positive"].travel_deviation_um,
                rt.strokes["negative"].travel_deviation_um, mean_um=rt.backlash.mean_um, limit_um=limit,
                title=f"{title}, {when}")
        return plots.lead_deviation(rt.strokes[direction], screw_lead_mm=axis.spec.screw_lead_mm,
                                    title=f"{title}, {when}")
    if name == "tbe_vs_backlash":
        if not axis.tasks:
            return plots.empty(title, "no machining task configured")
        latest = results_repo.latest_result(s, axis_id)
        lims = []
        for t in axis.tasks:
            try:
                v = t.backlash_limit_um()
            except MebmError:
                v = math.inf
            lims.append(v if math.isfinite(v) else None)
        rt = latest.round_trip if latest else None
        return plots.tbe_vs_backlash(axis.tasks, lims,
                                     backlash_um=rt.backlash.mean_um if rt else None,
                                     backlash_uncertainty_um=rt.backlash_mean_uncertainty_um
                                     if rt is not None and rt.budgets else 0.0,
                                     rule=axis.settings.decision_rule, title=title)
    if name == "tbe_history":
        rows = results_repo.tbe_history(s, axis_id, since=since, max_points=plots.SCREEN_POINTS)
        if not rows:
            return plots.empty(title, "no TBE estimated yet (needs a good measurement and a machining task)")
        series: dict = {}
        for t, task, tbe, tol in rows:
            ts, vs, tols = series.setdefault(task, ([], [], []))
            ts.append(t)
            vs.append(tbe)
            tols.append(tol)
        return plots.tbe_history(series, title=title)
    if name == "backlash_trend":
        tr = results_repo.trend(s, axis_id, since=since, max_points=plots.SCREEN_POINTS).series
        if not tr.measured_at:
            return plots.empty(title, "no good measurement yet")
        return plots.backlash_trend(list(tr.measured_at), list(tr.backlash_mean_um), list(tr.temperature_c),
                                    limit_um=limit, title=title)
    raise ValueError(f"name (={name!r}) must be one of {', '.join(NAMES)}")
