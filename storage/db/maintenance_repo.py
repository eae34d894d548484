"""Repository: maintenance orders, their transitions, and repairs.

The state machine is :mod:`core.maintenance`'s; this module stores it. "At most one
active order per axis" is the partial unique index ``uq_work_orders_one_active``: an
insert that would make a second one fails inside a savepoint, and :func:`open_order`
returns the order that won instead. Every state change is stored with its time, who
(the key's name, or ``mebm`` for the service itself) and a note.
"""

from __future__ import annotations

import json
import math
from datetime import datetime

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, selectinload

from core.errors import InputError
from core.maintenance import (
    ACTIVE_STATES,
    FINAL_STATES,
    ORDER_KINDS,
    ORDER_STATES,
    Figures,
    check_repair_kind,
    next_state,
)
from storage.db.errors import ConflictError, NotFoundError
from storage.db.models import Axis, Cycle, LeadCriteriaRow, Repair, Result, TbeRow, WorkOrder, WorkOrderTransition
from storage.db.records import (
    OrderRequest,
    RepairRecord,
    TransitionRecord,
    WorkOrderRecord,
    as_utc,
    utcnow,
)

SERVICE = "mebm"  # who: the service itself (an order opened on ALARM, a verification's verdict)


def _fin(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _cycle_of(s: Session, result_id: int | None) -> int | None:
    return None if result_id is None else s.scalar(select(Result.cycle_id).where(Result.id == result_id))


def _repair(s: Session, r: Repair) -> RepairRecord:
    return RepairRecord(
        id=r.id, axis_id=r.axis_id, order_id=r.order_id, kind=r.kind, note=r.note, performed_at=as_utc(r.performed_at),
        recorded_at=as_utc(r.recorded_at), recorded_by=r.recorded_by, compensation_measurement_id=r.compensation_cycle_id,
        compensation_file=r.compensation_file, before_measurement_id=_cycle_of(s, r.before_result_id),
    )


def _order(s: Session, o: WorkOrder) -> WorkOrderRecord:
    repairs = s.scalars(select(Repair).where(Repair.order_id == o.id).order_by(Repair.performed_at, Repair.id))
    return WorkOrderRecord(
        id=o.id, axis_id=o.axis_id, kind=o.kind, state=o.state, opened_at=as_utc(o.opened_at),
        opened_by_measurement_id=_cycle_of(s, o.opened_by_result_id), alert_id=o.alert_id,
        binding_task=o.binding_task, tolerance_um=o.tolerance_um, backlash_um=o.backlash_um,
        backlash_uncertainty_um=o.backlash_uncertainty_um, tbe_um=o.tbe_um, tbe_uncertainty_um=o.tbe_uncertainty_um,
        backlash_limit_um=o.backlash_limit_um, restore_below_um=o.restore_below_um, due_at=as_utc(o.due_at),
        recommendation=o.recommendation, verification_measurement_id=o.verification_cycle_id,
        verification=json.loads(o.verification) if o.verification else None, closed_at=as_utc(o.closed_at),
        transitions=tuple(TransitionRecord(t.id, as_utc(t.at), t.from_state, t.to_state, t.by, t.note,
                                           json.loads(t.figures) if t.figures else None) for t in o.transitions),
        repairs=tuple(_repair(s, r) for r in repairs), opened_by_circular_test_id=o.opened_by_circle_id,
    )


def _active(s: Session, axis_id: int) -> WorkOrder | None:
    return s.scalar(select(WorkOrder).where(WorkOrder.axis_id == axis_id, WorkOrder.state.in_(ACTIVE_STATES))
                    .options(selectinload(WorkOrder.transitions)))


# -- orders --------------------------------------------------------------------------------------
def open_order(s: Session, req: OrderRequest, *, by: str = SERVICE, note: str = "") -> tuple[WorkOrderRecord, bool]:
    """Open an order on the axis unless one is active: (the order, True) when this call
    opened it, (the active one, False) otherwise. Atomic across threads and processes."""
    if req.kind not in ORDER_KINDS:
        raise InputError(f"order kind (={req.kind!r}) must be one of {ORDER_KINDS}")
    if s.get(Axis, req.axis_id) is None:
        raise NotFoundError("axis", req.axis_id)
    existing = _active(s, req.axis_id)
    if existing is not None:
        return _order(s, existing), False
    o = WorkOrder(
        axis_id=req.axis_id, kind=req.kind, state="open", opened_at=req.opened_at, opened_by_result_id=req.result_id,
        alert_id=req.alert_id, binding_task=req.binding_task, tolerance_um=_fin(req.tolerance_um),
        backlash_um=_fin(req.backlash_um), backlash_uncertainty_um=_fin(req.backlash_uncertainty_um),
        tbe_um=_fin(req.tbe_um), tbe_uncertainty_um=_fin(req.tbe_uncertainty_um),
        backlash_limit_um=_fin(req.backlash_limit_um), restore_below_um=_fin(req.restore_below_um),
        due_at=req.due_at, recommendation=req.recommendation, opened_by_circle_id=req.circular_test_id,
    )
    try:
        with s.begin_nested():  # the partial unique index decides, atomically
            s.add(o)
            s.flush()
            s.add(WorkOrderTransition(order_id=o.id, at=req.opened_at, from_state=None, to_state="open", by=by,
                                      note=note or req.recommendation))
            s.flush()
    except IntegrityError:
        existing = _active(s, req.axis_id)
        if existing is None:  # pragma: no cover - the winner was closed in between: try once more
            raise ConflictError(f"axis {req.axis_id}: another order was being opened at the same time; try again")
        return _order(s, existing), False
    s.refresh(o)
    return _order(s, o), True


def get_order(s: Session, order_id: int) -> WorkOrderRecord:
    o = s.get(WorkOrder, order_id)
    if o is None:
        raise NotFoundError("work order", order_id)
    return _order(s, o)


def active_order(s: Session, axis_id: int) -> WorkOrderRecord | None:
    o = _active(s, axis_id)
    return None if o is None else _order(s, o)


def list_orders(s: Session, state: str = "active", *, axis_id: int | None = None, limit: int = 100,
                offset: int = 0) -> tuple[int, list[WorkOrderRecord]]:
    """Orders, newest first. ``state``: active, closed, all, or one state."""
    where = []
    if state == "active":
        where.append(WorkOrder.state.in_(ACTIVE_STATES))
    elif state == "closed":
        where.append(WorkOrder.state.in_(FINAL_STATES))
    elif state in ORDER_STATES:
        where.append(WorkOrder.state == state)
    elif state != "all":
        raise InputError(f"state (={state!r}) must be active, closed, all or one of {ORDER_STATES}")
    if axis_id is not None:
        where.append(WorkOrder.axis_id == axis_id)
    total = s.scalar(select(func.count()).select_from(WorkOrder).where(*where))
    rows = s.scalars(select(WorkOrder).where(*where).options(selectinload(WorkOrder.transitions))
                     .order_by(WorkOrder.opened_at.desc(), WorkOrder.id.desc()).limit(limit).offset(offset))
    return int(total or 0), [_order(s, o) for o in rows]


def _locked(s: Session, order_id: int) -> WorkOrder:
    o = s.scalar(select(WorkOrder).where(WorkOrder.id == order_id).with_for_update()
                 .execution_options(populate_existing=True))
    if o is None:
        raise NotFoundError("work order", order_id)
    return o


def transition(s: Session, order_id: int, action: str, *, by: str, note: str = "", figures: dict | None = None,
               when: datetime | None = None) -> WorkOrderRecord:
    """Take ``action`` (core.maintenance.TRANSITIONS) on the order, or
    :class:`core.maintenance.TransitionError` when its state forbids it."""
    o = _locked(s, order_id)
    _step(s, o, action, by=by, note=note, figures=figures, when=when)
    return _order(s, o)


def _step(s: Session, o: WorkOrder, action: str, *, by: str, note: str = "", figures: dict | None = None,
          when: datetime | None = None) -> None:
    if action == "cancel" and not note.strip():
        raise InputError("cancelling an order needs a reason (note)")
    to = next_state(o.state, action, order_id=o.id)
    when = when or utcnow()
    s.add(WorkOrderTransition(order_id=o.id, at=when, from_state=o.state, to_state=to, by=by, note=note,
                              figures=json.dumps(figures) if figures is not None else None))
    o.state = to
    if to in FINAL_STATES:
        o.closed_at = when
    s.flush()
    s.refresh(o)


def set_verification_cycle(s: Session, order_id: int, cycle_id: int | None) -> None:
    o = _locked(s, order_id)
    o.verification_cycle_id = cycle_id
    s.flush()


def cycle_pending_or_ok(s: Session, cycle_id: int) -> bool:
    c = s.get(Cycle, cycle_id)
    return c is not None and c.status in ("queued", "running", "ok")


def order_awaiting(s: Session, cycle_id: int) -> WorkOrderRecord | None:
    """The repaired order whose verification measurement is ``cycle_id``, if any."""
    o = s.scalar(select(WorkOrder).where(WorkOrder.verification_cycle_id == cycle_id, WorkOrder.state == "repaired"))
    return None if o is None else _order(s, o)


def conclude_verification(s: Session, order_id: int, *, passed: bool, verification: dict, note: str,
                          when: datetime | None = None) -> WorkOrderRecord:
    """Store the verification and move the order to verified, or back to open with both
    sets of figures (in the transition and on the order)."""
    o = _locked(s, order_id)
    o.verification = json.dumps(verification)
    _step(s, o, "verify_pass" if passed else "verify_fail", by=SERVICE, note=note,
          figures=None if passed else verification, when=when)
    return _order(s, o)


# -- repairs -------------------------------------------------------------------------------------
def record_repair(s: Session, axis_id: int, kind: str, *, by: str, note: str = "",
                  performed_at: datetime | None = None, compensation_measurement_id: int | None = None,
                  compensation_file: str | None = None) -> tuple[RepairRecord, WorkOrderRecord | None]:
    """Record what was done. The axis' active order (open, acknowledged, or repaired and
    waiting for its verification) takes the repair and becomes ``repaired``. A
    ``compensation_loaded`` repair names the measurement whose table was loaded (default:
    the newest ok measurement before the repair, the one ``/compensation`` exports)."""
    check_repair_kind(kind)
    if s.get(Axis, axis_id) is None:
        raise NotFoundError("axis", axis_id)
    now = utcnow()
    performed_at = performed_at or now
    if performed_at > now:
        raise InputError(f"performed_at (={performed_at.isoformat()}) is in the future")
    if compensation_measurement_id is not None and kind != "compensation_loaded":
        raise InputError("compensation_measurement_id is only for a repair of kind 'compensation_loaded'")
    before = s.scalar(select(Result).where(Result.axis_id == axis_id, Result.measured_at <= performed_at)
                      .order_by(Result.measured_at.desc(), Result.id.desc()).limit(1))
    comp_cycle = None
    if kind == "compensation_loaded":
        if compensation_measurement_id is None:
            if before is None:
                raise InputError("compensation_loaded: no measurement before the repair: name the table's "
                                 "measurement (compensation_measurement_id)")
            comp_cycle = before.cycle_id
        else:
            c = s.get(Cycle, compensation_measurement_id)
            if c is None or c.axis_id != axis_id or c.status != "ok":
                raise InputError(f"compensation_measurement_id (={compensation_measurement_id}) is not an ok "
                                 f"measurement of axis {axis_id}")
            comp_cycle = c.id
    o = _active(s, axis_id)
    if o is not None:
        o = _locked(s, o.id)
    r = Repair(axis_id=axis_id, order_id=o.id if o is not None else None, kind=kind, note=note or "",
               performed_at=performed_at, recorded_at=now, recorded_by=by, compensation_cycle_id=comp_cycle,
               compensation_file=compensation_file, before_result_id=before.id if before is not None else None)
    s.add(r)
    s.flush()
    if o is not None:
        text = f"{kind}" + (f": {note}" if note else "")
        _step(s, o, "repair", by=by, note=text, when=now)
    return _repair(s, r), (_order(s, o) if o is not None else None)


def repair_of_order(s: Session, order_id: int) -> RepairRecord | None:
    """The order's newest repair."""
    r = s.scalar(select(Repair).where(Repair.order_id == order_id)
                 .order_by(Repair.performed_at.desc(), Repair.id.desc()).limit(1))
    return None if r is None else _repair(s, r)


def list_repairs(s: Session, axis_id: int | None = None, *, since: datetime | None = None,
                 until: datetime | None = None) -> list[RepairRecord]:
    """Repairs, oldest first."""
    q = select(Repair)
    if axis_id is not None:
        q = q.where(Repair.axis_id == axis_id)
    if since is not None:
        q = q.where(Repair.performed_at >= since)
    if until is not None:
        q = q.where(Repair.performed_at <= until)
    return [_repair(s, r) for r in s.scalars(q.order_by(Repair.performed_at, Repair.id))]


def last_repair_at(s: Session, axis_id: int) -> datetime | None:
    """When the axis was last repaired (the prognosis fits only what came after)."""
    return as_utc(s.scalar(select(func.max(Repair.performed_at)).where(Repair.axis_id == axis_id)))


# -- figures of a measurement ---------------------------------------------------------------------
def figures(s: Session, measurement_id: int) -> Figures:
    """b̄ ± U, the positive stroke's lead criteria and each task's TBE of one measurement (cycle id)."""
    r = s.scalar(select(Result).where(Result.cycle_id == measurement_id))
    if r is None:
        raise NotFoundError("measurement", measurement_id)
    lead = s.scalar(select(LeadCriteriaRow).where(LeadCriteriaRow.result_id == r.id,
                                                  LeadCriteriaRow.direction == "positive"))
    tbe = s.scalars(select(TbeRow).where(TbeRow.result_id == r.id).order_by(TbeRow.id))
    return Figures(
        measurement_id=measurement_id, backlash_mean_um=r.backlash_mean_um,
        backlash_mean_uncertainty_um=r.backlash_mean_uncertainty_um or 0.0,
        lead={} if lead is None else {"e_p_um_per_1000mm": lead.e_p_um_per_1000mm, "v_u_um": lead.v_u_um,
                                      "v_300_um": lead.v_300_um, "v_2pi_um": lead.v_2pi_um},
        tasks=tuple({"task": t.task_name, "tbe_um": t.tbe_um, "tbe_uncertainty_um": t.tbe_uncertainty_um,
                     "tolerance_um": t.tolerance_um, "state": t.state} for t in tbe),
    )


def result_id_of(s: Session, measurement_id: int) -> int | None:
    return s.scalar(select(Result.id).where(Result.cycle_id == measurement_id))


# -- the managers' summary ------------------------------------------------------------------------
def summary_inputs(s: Session, axis_id: int, since: datetime | None, until: datetime) -> dict:
    """What core.maintenance.summarise_axis needs for one axis: the span (from ``since``,
    else the axis' first measurement, else its entry into service), the repairs on orders
    (called by the error), the others, and the orders opened in the span."""
    axis = s.get(Axis, axis_id)
    if axis is None:
        raise NotFoundError("axis", axis_id)
    start = since
    if start is None:
        first = as_utc(s.scalar(select(func.min(Result.measured_at)).where(Result.axis_id == axis_id)))
        start = first or as_utc(axis.in_service_since)
    start = min(start, until)
    reps = list_repairs(s, axis_id, since=start, until=until)
    orders = s.scalars(select(WorkOrder).where(WorkOrder.axis_id == axis_id, WorkOrder.opened_at >= start,
                                               WorkOrder.opened_at <= until))
    out = []
    for o in orders:
        verified = s.scalar(select(func.max(WorkOrderTransition.at)).where(
            WorkOrderTransition.order_id == o.id, WorkOrderTransition.to_state == "verified"))
        out.append((o.kind, as_utc(o.opened_at).timestamp(), as_utc(verified).timestamp() if verified else None))
    return {
        "start": start, "end": until,
        "called_repairs_s": [r.performed_at.timestamp() for r in reps if r.order_id is not None],
        "other_repairs": sum(1 for r in reps if r.order_id is None),
        "orders": out,
    }
