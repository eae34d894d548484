"""/alerts: raised when a TBE passes its tolerance, cleared by the next good
measurement below it; operators acknowledge them."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query

from api.rest import convert, schemas as sc
from api.rest.auth import OperateKey, ReadKey
from api.rest.deps import AlertId, SessionDep
from storage.db import results_repo

router = APIRouter(tags=["alerts"])


@router.get("/alerts", response_model=sc.AlertPage, summary="Alerts, newest first")
def list_alerts(s: SessionDep, _k: ReadKey,
                state: Annotated[Literal["active", "cleared", "all"], Query()] = "active",
                axis_id: Annotated[int | None, Query(ge=1, le=2**31 - 1)] = None,
                limit: Annotated[int, Query(ge=1, le=500)] = 100, offset: Annotated[int, Query(ge=0, le=10**7)] = 0):
    total, rows = results_repo.list_alerts(s, state, axis_id=axis_id, limit=limit, offset=offset)
    return sc.AlertPage(items=[convert.alert(a) for a in rows], total=total, limit=limit, offset=offset)


@router.post("/alerts/{alert_id}/ack", response_model=sc.AlertOut, summary="Acknowledge an alert (operate)")
def acknowledge(alert_id: AlertId, s: SessionDep, key: OperateKey):
    return convert.alert(results_repo.acknowledge_alert(s, alert_id, key.name))
