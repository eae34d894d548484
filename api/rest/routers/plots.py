"""/axes/{id}/plots/{name}.png: the figures a maintenance worker reads (Figs. 5, 9, 10, 14, 15)."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from enum import Enum
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Query, Response

from api.rest import plots
from api.rest.plot_prognosis import prognosis as prognosis_plot
from api.rest.auth import ReadKey
from api.rest.deps import AxisId, ServiceDep, SessionDep
from api.rest.routers.axes import Since, utc
from core.errors import MebmError
from core.prognosis import forecast_band
from storage.db import NotFoundError, config_repo, results_repo

router = APIRouter(tags=["plots"])
PNG = {200: {"content": {"image/png": {}}, "description": "a PNG image"}}


class PlotName(str, Enum):
    backlash_profile = "backlash_profile"
    lead_deviation = "lead_deviation"
    tbe_vs_backlash = "tbe_vs_backlash"
    tbe_history = "tbe_history"
    backlash_trend = "backlash_trend"
    prognosis = "prognosis"


def _limit(tasks) -> float | None:
    lims = []
    for t in tasks:
        try:
            lims.append(t.backlash_limit_um())
        except MebmError:
            pass
    lims = [v for v in lims if math.isfinite(v)]
    return min(lims) if lims else None


@router.get("/axes/{axis_id}/plots/{name}.png", response_class=Response, responses=PNG,
            summary="A figure: backlash_profile (Fig. 9), lead_deviation (Fig. 5), tbe_vs_backlash (Fig. 14), "
                    "tbe_history (Fig. 15), backlash_trend (Fig. 10), prognosis (Fig. 10 with the forecast and its band)")
def plot(
    axis_id: AxisId, name: PlotName, s: SessionDep, svc: ServiceDep, _k: ReadKey,
    measurement_id: Annotated[int | None, Query(ge=1, le=2**31 - 1,
                                                description="for profile/lead plots; default the newest")] = None,
    direction: Annotated[str, Query(pattern="^(positive|negative)$", description="lead_deviation stroke")] = "positive",
    since: Since = None,
):
    axis = config_repo.get_axis(s, axis_id)
    title = f"{axis.machine_name} axis {axis.name}"
    limit = _limit(axis.tasks)
    png = None
    if name in (PlotName.backlash_profile, PlotName.lead_deviation):
        if measurement_id is not None:
            c, r = results_repo.get_measurement(s, measurement_id)
            if c.axis_id != axis_id:
                raise NotFoundError(f"measurement of axis {axis_id}", measurement_id)
        else:
            r = results_repo.latest_result(s, axis_id, curves=True)
        if r is None or r.round_trip.backlash.position_mm.size == 0:
            png = plots.empty(title, "no good measurement yet")
        else:
            rt = r.round_trip
            when = f"{r.measured_at:%Y-%m-%d %H:%M} UTC" + (
                f", {r.temperature_c:.1f} °C" if r.temperature_c is not None else "")
            if name is PlotName.backlash_profile:
                png = plots.backlash_profile(
                    rt.backlash.position_mm, rt.backlash.backlash_um, rt.strokes["positive"].travel_deviation_um,
                    rt.strokes["negative"].travel_deviation_um, mean_um=rt.backlash.mean_um, limit_um=limit,
                    title=f"{title}, {when}")
            else:
                png = plots.lead_deviation(rt.strokes[direction], screw_lead_mm=axis.spec.screw_lead_mm,
                                           title=f"{title}, {when}")
    elif name is PlotName.tbe_vs_backlash:
        if not axis.tasks:
            png = plots.empty(title, "no machining task configured")
        else:
            latest = results_repo.latest_result(s, axis_id)
            lims = []
            for t in axis.tasks:
                try:
                    v = t.backlash_limit_um()
                except MebmError:
                    v = math.inf
                lims.append(v if math.isfinite(v) else None)
            rt = latest.round_trip if latest else None
            png = plots.tbe_vs_backlash(axis.tasks, lims,
                                        backlash_um=rt.backlash.mean_um if rt else None,
                                        backlash_uncertainty_um=rt.backlash_mean_uncertainty_um
                                        if rt is not None and rt.budgets else 0.0,
                                        rule=axis.settings.decision_rule, title=title)
    elif name is PlotName.tbe_history:
        rows = results_repo.tbe_history(s, axis_id, since=utc(since), max_points=plots.SCREEN_POINTS)
        if not rows:
            png = plots.empty(title, "no TBE estimated yet (needs a good measurement and a machining task)")
        else:
            series: dict = {}
            for t, task, tbe, tol in rows:
                ts, vs, tols = series.setdefault(task, ([], [], []))
                ts.append(t)
                vs.append(tbe)
                tols.append(tol)
            png = plots.tbe_history(series, title=title)
    elif name is PlotName.prognosis:
        png = _prognosis_png(svc.status.get(axis_id), title)
    else:
        tr = results_repo.trend(s, axis_id, since=utc(since), max_points=plots.SCREEN_POINTS).series
        if not tr.measured_at:
            png = plots.empty(title, "no good measurement yet")
        else:
            png = plots.backlash_trend(list(tr.measured_at), list(tr.backlash_mean_um), list(tr.temperature_c),
                                       limit_um=limit, title=title)
    return Response(content=png, media_type="image/png", headers={"Cache-Control": "no-cache"})


def _prognosis_png(st, title: str) -> bytes:
    h = st.history
    if h is None or h.rows_used == 0:
        return plots.empty(title, "no measurement with a temperature yet" if h is not None else
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
    return prognosis_plot(when, [float(x) for x in b], temps, note=note, title=title, **kw)
