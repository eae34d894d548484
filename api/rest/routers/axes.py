"""/axes/{id}: configuration, current status, machining tasks, schedule, cycles, trend."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response, status
from pydantic import AfterValidator
from fastapi.concurrency import run_in_threadpool

from api.rest import convert, schemas as sc
from api.rest.auth import AdminKey, OperateKey, ReadKey
from api.rest.deps import AxisId, ServiceDep, SessionDep
from api.rest.errors import TooManyRequestsError
from api.rest.status_body import cached_status, status_json
from api.service.prognosis import to_dict as prognosis_body
from api.service.config.input import machining_tasks, schedule_of
from storage.db import CycleRecord, config_repo, results_repo

router = APIRouter(tags=["axes"])

def utc(t: datetime | None) -> datetime | None:
    """``t`` in UTC (naive: taken as UTC). A time that leaves years 1-9999 once converted
    (``9999-12-31T23:59:59-23:59``) is a ValueError: a 422 naming the parameter."""
    if t is None:
        return None
    try:
        return t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)
    except OverflowError:
        raise ValueError(f"{t.isoformat()} is out of range once converted to UTC (years 1 to 9999)") from None


Since = Annotated[datetime | None, AfterValidator(utc), Query(description="from this time (ISO 8601; UTC if no offset)")]
Until = Annotated[datetime | None, AfterValidator(utc), Query(description="up to this time (ISO 8601; UTC if no offset)")]


@router.get("/axes/{axis_id}", response_model=sc.AxisOut, summary="An axis and its configuration")
def get_axis(axis_id: AxisId, s: SessionDep, svc: ServiceDep, _k: ReadKey):
    return convert.axis(config_repo.get_axis(s, axis_id), svc.scheduler.next_run(axis_id))


@router.get("/axes/{axis_id}/status", response_model=sc.AxisStatusOut,
            summary="Current TBE per task, backlash (also at 20 °C), limit, state and age of the last measurement")
async def axis_status(axis_id: AxisId, svc: ServiceDep, _k: ReadKey, request: Request):
    # The endpoint an MES polls: async, from the status cache when it can (no thread hop);
    # api.rest.status_body.StatusFastPath answers most polls before they get here.
    st = cached_status(svc, axis_id)
    if st is None:
        st = await run_in_threadpool(svc.status.get, axis_id)
    return Response(status_json(request.app.state, svc, axis_id, st), media_type="application/json")



@router.get("/axes/{axis_id}/prognosis", response_model=dict[str, Any],
            summary="Prognosis from the history: the shop temperature above which the binding task goes ALARM "
                    "today, the date b̄ at the worst-case temperature reaches the backlash limit, the robust fit "
                    "b̄(T, d) = b̄20 + β (T - 20 °C) + γ d behind them, or why the history does not support it")
def axis_prognosis(axis_id: AxisId, svc: ServiceDep, _k: ReadKey):
    # computed and cached with the status (api.service.prognosis memoises the fit)
    st = svc.status.get(axis_id)
    if st.history is None:
        return {"identifiable": False, "reason": f"the prognosis could not be computed: {st.history_error}"}
    return prognosis_body(st.history)


@router.put("/axes/{axis_id}/tasks", response_model=sc.AxisOut, summary="Replace the machining tasks (admin)")
def put_tasks(axis_id: AxisId, body: sc.TasksIn, s: SessionDep, svc: ServiceDep, _k: AdminKey):
    axis = config_repo.get_axis(s, axis_id)
    a = config_repo.set_tasks(s, axis_id, machining_tasks(body.tasks, axis.spec.position_gain_per_s))
    s.commit()
    svc.axis_changed(a)
    return convert.axis(a, svc.scheduler.next_run(axis_id))


@router.put("/axes/{axis_id}/schedule", response_model=sc.AxisOut, summary="Set the measurement schedule (admin)")
def put_schedule(axis_id: AxisId, body: sc.ScheduleIn, s: SessionDep, svc: ServiceDep, _k: AdminKey):
    a = config_repo.set_schedule(s, axis_id, schedule_of(body))
    s.commit()
    svc.axis_changed(a)
    return convert.axis(a, svc.scheduler.next_run(axis_id))


@router.post("/axes/{axis_id}/measurements", response_model=sc.TriggerOut, status_code=status.HTTP_202_ACCEPTED,
             summary="Trigger a measurement cycle (operate: the axis will move)")
def trigger(axis_id: AxisId, svc: ServiceDep, key: OperateKey, response: Response, request: Request):
    wait_s = request.app.state.trigger_limit.take(key.name)
    if wait_s > 0:
        raise TooManyRequestsError(f"key {key.name!r} triggered too many measurements "
                                   f"(limits.triggers_per_minute); retry in {wait_s:.0f} s", wait_s)
    rec = svc.trigger(axis_id, key.name)
    stored = rec if isinstance(rec, CycleRecord) else None
    if stored is not None:
        response.headers["Location"] = f"/api/v1/measurements/{stored.id}"
    return sc.TriggerOut(
        measurement=convert.summary(stored) if stored else None, uuid=rec.uuid, queued=True,
        detail="queued; it runs after any cycle of this axis already running",
    )


@router.get("/axes/{axis_id}/measurements", response_model=sc.MeasurementPage,
            summary="Measurement cycles of an axis, newest first")
def list_measurements(
    axis_id: AxisId, s: SessionDep, svc: ServiceDep, _k: ReadKey, since: Since = None, until: Until = None,
    status_: Annotated[str | None, Query(alias="status", pattern="^(queued|running|ok|failed|interrupted|cancelled)$")] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Annotated[int, Query(ge=0, le=10**7)] = 0,
):
    total, rows = results_repo.list_measurements(s, axis_id, since=utc(since), until=utc(until), status=status_,
                                                 limit=limit, offset=offset)
    held = svc.executor.held() if svc.executor is not None else None
    return sc.MeasurementPage(items=[convert.summary(c, held) for c in rows], total=total, limit=limit,
                              offset=offset)


@router.get("/axes/{axis_id}/trend", response_model=sc.TrendOut,
            summary="b̄, e_p, v_u, v_300, v_2pi over time with temperature, utility day and Pearson r (Section 3)")
def trend(
    axis_id: AxisId, s: SessionDep, _k: ReadKey, since: Since = None, until: Until = None,
    max_points: Annotated[int, Query(ge=10, le=20000, description="downsample the series to this many points "
                                     "(the minimum and maximum of b̄ per bucket)")] = 2000,
):
    return convert.trend(axis_id, results_repo.trend(s, axis_id, since=utc(since), until=utc(until),
                                                     max_points=max_points))
