"""The figures of an axis (Figs. 5, 9, 10, 14, 15) as PNG bytes, from the stored results.

One function for every reader: the REST plot endpoint and the dashboard both call
:func:`render`, so the queries behind a figure exist once.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from datetime import datetime, timezone

import numpy as np

from api.service.figures import plots
from api.service.figures.cache import FigureCache
from api.service.figures.prognosis import prognosis as prognosis_plot
from core.prognosis import forecast_band
from core.errors import MebmError
from storage.db import NotFoundError, config_repo, maintenance_repo, results_repo

NAMES = (*plots.NAMES, "prognosis")


def _here(fn: Callable[..., bytes], *args, **kwargs) -> bytes:
    return fn(*args, **kwargs)


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
           since: datetime | None = None, status=None, draw: Callable[..., bytes] | None = None,
           cache: FigureCache | None = None) -> bytes:
    """The PNG of figure ``name`` (one of :data:`NAMES`) for ``axis_id``; an explanatory
    empty figure when there is nothing to draw yet. ``status`` (the axis' AxisStatus,
    from the service's status cache) is needed for the prognosis. The database is read
    here; the drawing goes through ``draw(fn, *args, **kwargs)`` (the service's
    :class:`~api.service.figures.process.PlotProcess`; default: on this thread). With
    ``cache`` (the service's :class:`~api.service.figures.cache.FigureCache`) a figure
    whose inputs (:func:`figure_key`) were drawn before is not drawn again, and ``since`` is
    rounded down to the cache's resolution first (:meth:`FigureCache.snap`)."""
    draw = draw or _here
    if name not in NAMES:
        raise ValueError(f"name (={name!r}) must be one of {', '.join(NAMES)}")
    if name == "prognosis" and status is None:
        raise ValueError("the prognosis figure needs the axis' status")
    if cache is not None:
        since = cache.snap(since)
    axis = config_repo.get_axis(s, axis_id)
    title = f"{axis.machine_name} axis {axis.name}"
    limit = backlash_limit_um(axis.tasks)
    # what the figure is drawn from, read once: the newest measurement is resolved to its id
    # here, so that the key and the drawing name the same one
    if name == "tbe_vs_backlash" or (name in ("backlash_profile", "lead_deviation") and measurement_id is None):
        measurement_id = results_repo.latest_measurement_id(s, axis_id)
    repairs = _repairs(s, axis_id, since) if name in ("tbe_history", "backlash_trend") else None

    def drawn() -> bytes:
        return _draw(s, axis, name, title, limit, measurement_id=measurement_id, direction=direction,
                     since=since, status=status, repairs=repairs, draw=draw)

    if cache is None:
        return drawn()
    key = figure_key(s, axis, name, title, limit, measurement_id=measurement_id, direction=direction, since=since,
                     status=status, repairs=repairs)
    return cache.get_or_render(key, drawn)


def figure_key(s, axis, name: str, title: str, limit: float | None, *, measurement_id: int | None,
               direction: str, since: datetime | None, status, repairs) -> tuple:
    """Everything figure ``name`` of ``axis`` is drawn from, as a hashable key: the stored
    results it shows (by id: a result never changes once stored), its parameters, and the
    settings drawn with them (title, limit, tasks, decision rule)."""
    base = (axis.id, name, title, limit)
    if name in ("backlash_profile", "lead_deviation"):
        return (*base, measurement_id, direction if name == "lead_deviation" else None, axis.spec.screw_lead_mm)
    if name == "tbe_vs_backlash":
        return (*base, measurement_id, _hashable(axis.tasks), axis.settings.decision_rule)
    if name in ("tbe_history", "backlash_trend"):
        return (*base, since, results_repo.results_signature(s, axis.id, since), tuple(repairs))
    h = status.history  # prognosis: one computation of the axis' history, and why there is none
    return (*base, None if h is None else (h.computed_at, h.rows_used, h.rows_total), status.history_error)


def _hashable(x):
    try:
        hash(x)
        return x
    except TypeError:
        return repr(x)


def _draw(s, axis, name: str, title: str, limit: float | None, *, measurement_id: int | None,
          direction: str, since: datetime | None, status, repairs, draw: Callable[..., bytes]) -> bytes:
    axis_id = axis.id
    if name in ("backlash_profile", "lead_deviation"):
        r = None
        if measurement_id is not None:
            c, r = results_repo.get_measurement(s, measurement_id)
            if c.axis_id != axis_id:
                raise NotFoundError(f"measurement of axis {axis_id}", measurement_id)
        if r is None or r.round_trip.backlash.position_mm.size == 0:
            return draw(plots.empty, title, "no good measurement yet")
        rt = r.round_trip
        when = f"{r.measured_at:%Y-%m-%d %H:%M} UTC" + (
            f", {r.temperature_c:.1f} °C" if r.temperature_c is not None else "")
        if name == "backlash_profile":
            return draw(
                plots.backlash_profile, rt.backlash.position_mm, rt.backlash.backlash_um, rt.strokes["positive"].travel_deviation_um,
                rt.strokes["negative"].travel_deviation_um, mean_um=rt.backlash.mean_um, limit_um=limit,
                title=f"{title}, {when}")
        return draw(plots.lead_deviation, rt.strokes[direction], screw_lead_mm=axis.spec.screw_lead_mm,
                    title=f"{title}, {when}")
    if name == "tbe_vs_backlash":
        if not axis.tasks:
            return draw(plots.empty, title, "no machining task configured")
        latest = results_repo.get_measurement(s, measurement_id, curves=False)[1] if measurement_id else None
        lims = []
        for t in axis.tasks:
            try:
                v = t.backlash_limit_um()
            except MebmError:
                v = math.inf
            lims.append(v if math.isfinite(v) else None)
        rt = latest.round_trip if latest else None
        return draw(plots.tbe_vs_backlash, axis.tasks, lims,
                    backlash_um=rt.backlash.mean_um if rt else None,
                    backlash_uncertainty_um=rt.backlash_mean_uncertainty_um
                    if rt is not None and rt.budgets else 0.0,
                    rule=axis.settings.decision_rule, title=title)
    if name == "tbe_history":
        rows = results_repo.tbe_history(s, axis_id, since=since, max_points=plots.SCREEN_POINTS)
        if not rows:
            return draw(plots.empty, title, "no TBE estimated yet (needs a good measurement and a machining task)")
        series: dict = {}
        for t, task, tbe, tol in rows:
            ts, vs, tols = series.setdefault(task, ([], [], []))
            ts.append(t)
            vs.append(tbe)
            tols.append(tol)
        return draw(plots.tbe_history, series, title=title, repairs=repairs)
    if name == "backlash_trend":
        tr = results_repo.trend(s, axis_id, since=since, max_points=plots.SCREEN_POINTS).series
        if not tr.measured_at:
            return draw(plots.empty, title, "no good measurement yet")
        return draw(plots.backlash_trend, list(tr.measured_at), list(tr.backlash_mean_um),
                    list(tr.temperature_c), limit_um=limit, title=title, repairs=repairs)
    return prognosis_png(status, title, draw)


def _repairs(s, axis_id: int, since: datetime | None) -> list[tuple[datetime, str]]:
    """(when, kind) of the axis' repairs in the plotted range, for the marks."""
    return [(r.performed_at, r.kind) for r in maintenance_repo.list_repairs(s, axis_id, since=since)]


def prognosis_png(st, title: str, draw: Callable[..., bytes] | None = None) -> bytes:
    """Fig. 10 with the forecast of b̄ at the worst-case temperature and its band."""
    draw = draw or _here
    h = st.history
    if h is None or h.rows_used == 0:
        return draw(plots.empty, title, "no measurement with a temperature yet" if h is not None else
                           f"no prognosis: {st.history_error}")
    t_s, temp, _day, b = h.series
    p = h.prognosis
    when = [datetime.fromtimestamp(x, tz=timezone.utc) for x in t_s]
    temps = [None if not math.isfinite(v) else float(v) for v in temp]
    kw = dict(forecast_t=None, worst_case_temperature_c=p.worst_case_temperature_c, limit_um=p.backlash_limit_um,
              limit_date=None)
    if p.fit.identifiable:
        horizon_s = p.limit_date_s if p.limit_date_s is not None else p.now_s + 365.25 * 86400.0
        end_s = max(horizon_s + 0.15 * (horizon_s - float(t_s[0])), p.now_s + 30 * 86400.0)
        end_s = min(end_s, p.now_s + 5 * 365.25 * 86400.0)
        ts = np.linspace(float(t_s[0]), end_s, 200)
        days = p.day_now + (ts - p.now_s) * p.days_per_second
        mean, lo, hi = forecast_band(p.fit, p.worst_case_temperature_c, days)
        kw.update(forecast_t=[datetime.fromtimestamp(x, tz=timezone.utc) for x in ts], forecast_um=mean,
                  band_low_um=lo, band_high_um=hi,
                  limit_date=datetime.fromtimestamp(p.limit_date_s, tz=timezone.utc) if p.limit_date_s else None)
        f = p.fit
        note = (f"b̄20 {f.backlash_20c_um.value:.1f} µm, β {f.beta_um_per_k.value:.2f} µm/K, "
                f"γ {f.gamma_um_per_day.value * 365.25:.2f} µm/year ({f.n_cycles} cycles); "
                + (f"ALARM above {p.alarm_temperature_c:.1f} °C today ({p.rule} rule)" if p.alarm_temperature_c
                   is not None else p.alarm_temperature_reason))
    else:
        note = f"not identifiable: {p.fit.reason}"
    return draw(prognosis_plot, when, [float(x) for x in b], temps, note=note, title=title, **kw)
