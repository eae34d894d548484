"""/maintenance and /axes/{id}/repairs: work orders, repairs and the managers' summary.

Orders are opened by the service (ALARM: corrective; WARNING with the prognosis' date
within the horizon: condition-based, EN 13306). People acknowledge, repair and cancel
them with an operate key; the verification measurement closes them. A step the order's
state forbids is a 409 naming the state and what it allows.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import AfterValidator

from api.rest.auth import OperateKey, ReadKey
from api.rest.deps import AxisId, ServiceDep, SessionDep
from api.service.maintenance.input import NoteIn, RepairIn, summary_csv, summary_rows, utc
from core.maintenance import TransitionError
from core.tbe import stored_repair_target
from storage.db import ConflictError, RepairRecord, WorkOrderRecord, config_repo, maintenance_repo, session_scope

router = APIRouter(tags=["maintenance"])
OrderId = Annotated[int, Path(ge=1, le=2**31 - 1, description="work order id")]


def _iso(t: datetime | None) -> str | None:
    return None if t is None else t.isoformat().replace("+00:00", "Z")


def repair_doc(r: RepairRecord) -> dict:
    return {"id": r.id, "axis_id": r.axis_id, "order_id": r.order_id, "kind": r.kind, "note": r.note,
            "performed_at": _iso(r.performed_at), "recorded_at": _iso(r.recorded_at), "recorded_by": r.recorded_by,
            "compensation_measurement_id": r.compensation_measurement_id, "compensation_file": r.compensation_file,
            "before_measurement_id": r.before_measurement_id}


def restore_below_explanation(o: WorkOrderRecord) -> str | None:
    """Why the order's target is below the backlash limit (None: the order names no target)."""
    target = stored_repair_target(o.restore_below_um, o.backlash_limit_um)
    return target.explanation if target is not None else None


def order_doc(o: WorkOrderRecord) -> dict:
    return {
        "id": o.id, "axis_id": o.axis_id, "kind": o.kind, "state": o.state, "active": o.active,
        "opened_at": _iso(o.opened_at), "closed_at": _iso(o.closed_at), "due_at": _iso(o.due_at),
        "opened_by_measurement_id": o.opened_by_measurement_id,
        "opened_by_circular_test_id": o.opened_by_circular_test_id, "alert_id": o.alert_id,
        "binding_task": o.binding_task, "tolerance_um": o.tolerance_um, "backlash_um": o.backlash_um,
        "backlash_uncertainty_um": o.backlash_uncertainty_um, "tbe_um": o.tbe_um,
        "tbe_uncertainty_um": o.tbe_uncertainty_um, "backlash_limit_um": o.backlash_limit_um,
        "restore_below_um": o.restore_below_um, "restore_below_explanation": restore_below_explanation(o),
        "recommendation": o.recommendation, "verification_measurement_id": o.verification_measurement_id, "verification": o.verification,
        "verified_against": (o.verification or {}).get("against"),
        "transitions": [{"at": _iso(t.at), "from": t.from_state, "to": t.to_state, "by": t.by, "note": t.note,
                         "figures": t.figures} for t in o.transitions],
        "repairs": [repair_doc(r) for r in o.repairs],
    }


@router.get("/maintenance/orders", response_model=dict[str, Any], summary="Work orders, newest first")
def list_orders(s: SessionDep, _k: ReadKey,
                state: Annotated[Literal["active", "closed", "all", "open", "acknowledged", "repaired", "verified",
                                         "cancelled"], Query()] = "active",
                axis_id: Annotated[int | None, Query(ge=1, le=2**31 - 1)] = None,
                limit: Annotated[int, Query(ge=1, le=500)] = 100, offset: Annotated[int, Query(ge=0, le=10**7)] = 0):
    total, rows = maintenance_repo.list_orders(s, state, axis_id=axis_id, limit=limit, offset=offset)
    return {"items": [order_doc(o) for o in rows], "total": total, "limit": limit, "offset": offset}


@router.get("/maintenance/orders/{order_id}", response_model=dict[str, Any],
            summary="A work order with its transitions, repairs and verification")
def get_order(order_id: OrderId, s: SessionDep, _k: ReadKey):
    return order_doc(maintenance_repo.get_order(s, order_id))


def _step(svc, order_id: int, action: str, by: str, note: str) -> dict:
    try:
        return order_doc(svc.maintenance.transition(order_id, action, by=by, note=note))
    except TransitionError as exc:
        raise ConflictError(str(exc)) from exc


@router.post("/maintenance/orders/{order_id}/ack", response_model=dict[str, Any],
             summary="Acknowledge a work order (operate)")
async def acknowledge(order_id: OrderId, svc: ServiceDep, key: OperateKey, body: NoteIn | None = None):
    return await run_in_threadpool(_step, svc, order_id, "acknowledge", key.name, body.note if body else "")


@router.post("/maintenance/orders/{order_id}/cancel", response_model=dict[str, Any],
             summary="Cancel a work order, with the reason (operate)")
async def cancel(order_id: OrderId, body: NoteIn, svc: ServiceDep, key: OperateKey):
    return await run_in_threadpool(_step, svc, order_id, "cancel", key.name, body.note)


@router.post("/maintenance/orders/{order_id}/verify", response_model=dict[str, Any],
             status_code=status.HTTP_202_ACCEPTED,
             summary="Queue the verification measurement of a repaired order again (operate)")
async def verify_again(order_id: OrderId, svc: ServiceDep, key: OperateKey):
    def run():
        with session_scope(svc.factory) as s:
            o = maintenance_repo.get_order(s, order_id)
        if o.state != "repaired":
            raise ConflictError(f"order {order_id} is {o.state!r}: only a repaired order is verified")
        return order_doc(svc.maintenance.queue_verification(order_id, key.name) or o)

    return await run_in_threadpool(run)


@router.post("/axes/{axis_id}/repairs", response_model=dict[str, Any], status_code=status.HTTP_201_CREATED,
             summary="Record a repair (operate): the axis' order becomes repaired and a verification "
                     "measurement is queued")
async def record_repair(axis_id: AxisId, body: RepairIn, svc: ServiceDep, key: OperateKey):
    def run():
        repair, order = svc.maintenance.record_repair(
            axis_id, body.kind, by=key.name, note=body.note, performed_at=body.performed_at,
            compensation_measurement_id=body.compensation_measurement_id, compensation_file=body.compensation_file)
        return {"repair": repair_doc(repair), "order": order_doc(order) if order is not None else None}

    return await run_in_threadpool(run)


@router.get("/axes/{axis_id}/repairs", response_model=dict[str, Any], summary="The axis' repairs, oldest first")
def list_repairs(axis_id: AxisId, s: SessionDep, _k: ReadKey):
    config_repo.get_axis(s, axis_id)
    return {"items": [repair_doc(r) for r in maintenance_repo.list_repairs(s, axis_id)]}


@router.get("/maintenance/summary", response_model=dict[str, Any],
            responses={200: {"content": {"application/json": {}, "text/csv": {}}}},
            summary="Per axis and fleet: repairs the error called for, their intervals, ALARM to verified, "
                    "against a fixed maintenance interval (JSON or CSV)")
async def summary(
    svc: ServiceDep, _k: ReadKey,
    since: Annotated[datetime | None, AfterValidator(utc), Query(description="from (default: each axis' first "
                                                                              "measurement)")] = None,
    until: Annotated[datetime | None, AfterValidator(utc), Query(description="up to (default: now)")] = None,
    fixed_interval_days: Annotated[float | None, Query(gt=0, le=36500, description="the fixed plan's period "
                                                       "(default: maintenance.fixed_interval_days)")] = None,
    format: Annotated[Literal["json", "csv"], Query()] = "json",  # noqa: A002 - the API's name
):
    axes, fleet = await run_in_threadpool(svc.maintenance.summary, since, until, fixed_interval_days)
    rows = summary_rows(axes)
    if format == "csv":
        return Response(summary_csv(rows, fleet), media_type="text/csv",
                        headers={"Content-Disposition": 'attachment; filename="maintenance-summary.csv"'})
    return {"axes": rows, "fleet": fleet, "until": _iso(until), "since": _iso(since)}
