"""Repository: measurement cycles, their results (criteria, curves, TBE) and alerts.

:func:`save_finished_cycle` is the one write of a cycle's end: cycle, result,
criteria, curves, TBE and the alert transition in one transaction, idempotent on
the cycle's uuid.
"""

from __future__ import annotations

import json
import math
from datetime import datetime

import numpy as np
from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, selectinload

from core.criteria import BacklashProfile, LeadCriteria, RoundTripResult
from core.criteria.lost_motion import ClearanceEstimate, LostMotion
from core.criteria.uncertainty import UncertaintyBudget, UncertaintyComponent
from core.errors import InputError
from core.tbe import MachiningTask, State
from core.history import MomentSums
from storage.db import curves as curve_codec
from storage.db import rollup
from storage.db.errors import NotFoundError, WaitingCycleError
from storage.db.models import Alert, Axis, Curve, Cycle, LeadCriteriaRow, Result, TbeRow
from storage.db.records import (
    CYCLE_STATES,
    TRIGGERS,
    AlertRecord,
    CycleRecord,
    FinishedCycle,
    ResultRecord,
    TbeRecord,
    TrendView,
    as_utc,
    utcnow,
)

DIRECTIONS = ("positive", "negative")
ALERT_KIND = "tbe_exceeded"
RAW_RUN_LOST = "raw_run_lost"  # alert kind: a cycle's raw run could not be kept; cleared by the next kept run
# reason code and alert kind: a cycle found no room under the data folder (its failure_reason
# starts with "storage_full:"); the alert is cleared by the next cycle stored without it
STORAGE_FULL = "storage_full"


def _fin(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _cycle(c: Cycle, result: Result | None = None) -> CycleRecord:
    return CycleRecord(
        id=c.id, uuid=c.uuid, axis_id=c.axis_id, trigger=c.trigger, requested_by=c.requested_by, status=c.status,
        requested_at=as_utc(c.requested_at), started_at=as_utc(c.started_at), finished_at=as_utc(c.finished_at),
        failure_reason=c.failure_reason, temperature_c=c.temperature_c, utility_day=c.utility_day,
        uncertainty_um=c.uncertainty_um, run_file=c.run_file,
        backlash_mean_um=result.backlash_mean_um if result is not None else None,
        state=result.state if result is not None else None, raw_run_lost=c.raw_run_lost,
    )


# -- cycle life ----------------------------------------------------------------------------
def queue_cycle(s: Session, axis_id: int, uuid: str, trigger: str, *, requested_by: str | None = None,
                requested_at: datetime | None = None) -> CycleRecord:
    if trigger not in TRIGGERS:
        raise InputError(f"trigger (={trigger!r}) must be one of {TRIGGERS}")
    if s.get(Axis, axis_id) is None:
        raise NotFoundError("axis", axis_id)
    c = Cycle(uuid=uuid, axis_id=axis_id, trigger=trigger, requested_by=requested_by, status="queued",
              requested_at=requested_at or utcnow())
    if trigger != "manual":
        s.add(c)
        s.flush()
        return _cycle(c)
    try:
        with s.begin_nested():  # the unique index decides, atomically, whether another manual one waits
            s.add(c)
            s.flush()
    except IntegrityError as exc:
        waiting = s.scalar(select(Cycle).where(Cycle.axis_id == axis_id, Cycle.status == "queued",
                                               Cycle.trigger == "manual").limit(1))
        raise WaitingCycleError(axis_id, None if waiting is None else _cycle(waiting)) from exc
    return _cycle(c)


def axis_of_cycles(s: Session, uuids: list[str]) -> dict[str, int]:
    """{cycle uuid: axis id} of the given uuids that are stored."""
    out: dict[str, int] = {}
    for i in range(0, len(uuids), 500):
        out.update({u: a for u, a in s.execute(select(Cycle.uuid, Cycle.axis_id).where(Cycle.uuid.in_(uuids[i:i + 500])))})
    return out


def event_cycle_uuids(s: Session, axis_id: int) -> set[str]:
    """Uuids of the cycles that raised or cleared an alert of the axis (retention keeps
    the raw runs around them)."""
    out: set[str] = set()
    for col in (Alert.raised_by_result_id, Alert.cleared_by_result_id):
        q = (select(Cycle.uuid).join(Result, Result.cycle_id == Cycle.id).join(Alert, col == Result.id)
             .where(Alert.axis_id == axis_id))
        out.update(s.scalars(q))
    return out


def mark_running(s: Session, uuid: str, started_at: datetime | None = None) -> CycleRecord:
    c = s.scalar(select(Cycle).where(Cycle.uuid == uuid))
    if c is None:
        raise NotFoundError("cycle", uuid)
    c.status = "running"
    c.started_at = started_at or utcnow()
    s.flush()
    return _cycle(c)


def is_storage_full(failure_reason: str | None) -> bool:
    return bool(failure_reason) and failure_reason.startswith(f"{STORAGE_FULL}:")


def close_stale_cycles(s: Session, now: datetime | None = None, *, held: dict | None = None) -> int:
    """At start-up: cycles left 'running' by a crash become 'interrupted', 'queued' ones
    'cancelled' (an axis is not moved on its own after a restart). Returns how many.
    ``held``: uuid -> (status, reason) of cycles that finished and wait in the spool; a
    running row of one takes that reason (the spool stores the rest of it later) and is
    not counted: it was not interrupted."""
    now = now or utcnow()
    held = held or {}
    n = 0
    for c in s.scalars(select(Cycle).where(Cycle.status.in_(("running", "queued")))):
        c.finished_at = now
        if c.uuid in held:
            status, reason = held[c.uuid]
            c.status = "failed" if status == "ok" else status  # (an ok result is stored with the spool file)
            c.failure_reason = reason or "finished; waiting in the spool to be stored"
            continue
        if c.status == "running":
            c.status, c.failure_reason = "interrupted", "the service stopped during the cycle"
        else:
            c.status, c.failure_reason = "cancelled", "the service stopped before the cycle started"
        n += 1
    s.flush()
    return n


def save_finished_cycle(s: Session, fc: FinishedCycle) -> tuple[CycleRecord, list[AlertRecord]]:
    """Store a cycle's end (and its result when ok) atomically; raise/clear the alert.

    Idempotent: a cycle whose uuid is stored as finished already is returned as is.
    Returns the cycle and the alerts raised or cleared by it.
    """
    if fc.status not in CYCLE_STATES or fc.status in ("queued", "running"):
        raise InputError(f"status (={fc.status!r}) must be a final state")
    if fc.status == "ok" and fc.round_trip is None:
        raise InputError("an ok cycle needs its round_trip result")
    axis = s.get(Axis, fc.axis_id)
    if axis is None:
        raise NotFoundError("axis", fc.axis_id)
    c = s.scalar(select(Cycle).where(Cycle.uuid == fc.uuid).options(selectinload(Cycle.result)))
    if c is not None and c.status not in ("queued", "running", "interrupted", "cancelled") and not (
            c.status == "failed" and c.result is None and is_storage_full(c.failure_reason)):
        return _cycle(c, c.result), []  # (a storage_full row closed at a start is completed by its spool file)
    if c is None:
        c = Cycle(uuid=fc.uuid, axis_id=fc.axis_id, trigger=fc.trigger, requested_by=fc.requested_by,
                  requested_at=fc.requested_at, status=fc.status)
        s.add(c)
    c.status = fc.status
    c.started_at = fc.started_at
    c.finished_at = fc.finished_at
    c.failure_reason = fc.failure_reason
    c.temperature_c = _fin(fc.temperature_c)
    c.utility_day = _fin(fc.utility_day)
    c.uncertainty_um = _fin(fc.uncertainty_um)
    c.run_file = fc.run_file
    c.raw_run_lost = fc.raw_run_lost
    s.flush()
    changes: list[AlertRecord] = []
    result = None
    if fc.status == "ok":
        result = _insert_result(s, c, fc)
        rollup.refresh(s, fc.axis_id, result.measured_at)
        if fc.decision is not None:
            changes = _update_alerts(s, fc, result)
    changes += _update_lost_run_alert(s, fc, c)
    s.flush()
    return _cycle(c, result), changes


def _update_lost_run_alert(s: Session, fc: FinishedCycle, c: Cycle) -> list[AlertRecord]:
    """A lost raw run raises a ``raw_run_lost`` alert (one per axis while active); the
    next cycle whose run is kept clears it."""
    active = s.scalar(select(Alert).where(Alert.axis_id == fc.axis_id, Alert.kind == RAW_RUN_LOST,
                                          Alert.cleared_at.is_(None)))
    changes = _update_storage_full_alert(s, fc, c)
    if fc.raw_run_lost and active is None:
        a = Alert(axis_id=fc.axis_id, kind=RAW_RUN_LOST, raised_at=fc.finished_at,
                  message=f"the raw run of cycle {c.id} ({fc.uuid}) was lost: {fc.raw_run_lost}")
        s.add(a)
        s.flush()
        return changes + [_alert_full(s, a)]
    if not fc.raw_run_lost and fc.run_file and active is not None:
        active.cleared_at = fc.finished_at
        s.flush()
        return changes + [_alert_full(s, active)]
    return changes


def _update_storage_full_alert(s: Session, fc: FinishedCycle, c: Cycle) -> list[AlertRecord]:
    """A cycle that found the disk full raises a ``storage_full`` alert (one per axis while
    active); the next cycle stored without that reason clears it."""
    active = s.scalar(select(Alert).where(Alert.axis_id == fc.axis_id, Alert.kind == STORAGE_FULL,
                                          Alert.cleared_at.is_(None)))
    if is_storage_full(fc.failure_reason) and active is None:
        a = Alert(axis_id=fc.axis_id, kind=STORAGE_FULL, raised_at=fc.finished_at,
                  message=f"cycle {c.id} ({fc.uuid}): {fc.failure_reason[len(STORAGE_FULL) + 1:].strip()}")
        s.add(a)
        s.flush()
        return [_alert_full(s, a)]
    if not is_storage_full(fc.failure_reason) and fc.status == "ok" and active is not None:
        active.cleared_at = fc.finished_at
        s.flush()
        return [_alert_full(s, active)]
    return []


def _insert_result(s: Session, c: Cycle, fc: FinishedCycle) -> Result:
    rt = fc.round_trip
    d = fc.decision
    r = Result(
        cycle_id=c.id, axis_id=fc.axis_id, measured_at=fc.finished_at, temperature_c=_fin(fc.temperature_c),
        utility_day=_fin(fc.utility_day), backlash_mean_um=rt.backlash.mean_um, backlash_min_um=rt.backlash.min_um,
        backlash_max_um=rt.backlash.max_um, backlash_std_um=rt.backlash.std_um,
        useful_travel_start_mm=rt.useful_travel_mm[0], useful_travel_end_mm=rt.useful_travel_mm[1],
        n_samples=rt.n_samples, peak_speed_mm_min=rt.peak_speed_mm_min, uncertainty_um=_fin(fc.uncertainty_um),
        state=d.state.value if d else None, binding_task=d.binding_task if d else None,
        backlash_limit_um=_fin(d.backlash_limit_um) if d else None, message=d.message() if d else None,
        backlash_mean_uncertainty_um=_fin(rt.backlash_mean_uncertainty_um) if rt.budgets else None,
        outliers_removed=rt.outliers_removed, grid_step_mm=_fin(rt.grid_step_mm), noise_um=_fin(rt.noise_um),
        uncertainty_budget=json.dumps({k: b.to_dict() for k, b in rt.budgets.items()}) if rt.budgets else None,
        decision_rule=d.rule if d else None,
        reversal_mean_um=_fin(rt.lost_motion.mean_um) if rt.lost_motion else None,
        reversal_max_um=_fin(rt.lost_motion.max_abs_um) if rt.lost_motion else None,
        lost_motion=json.dumps(rt.lost_motion.to_dict()) if rt.lost_motion else None,
    )
    s.add(r)
    s.flush()
    curves = {"backlash_um": (rt.backlash.position_mm, rt.backlash.backlash_um)}
    for name in DIRECTIONS:
        lc = rt.strokes[name]
        s.add(LeadCriteriaRow(
            result_id=r.id, direction=name, e_p_um=lc.e_p_um, e_p_um_per_1000mm=lc.e_p_um_per_1000mm,
            v_u_um=lc.v_u_um, v_300_um=lc.v_300_um, v_2pi_um=lc.v_2pi_um, n_strokes=lc.n_strokes,
        ))
        curves[f"{name}_travel_deviation_um"] = (lc.position_mm, lc.travel_deviation_um)
        curves[f"{name}_mean_travel_deviation_um"] = (lc.position_mm, lc.mean_travel_deviation_um)
    for name, (x, v) in curves.items():
        start, step, n, blob = curve_codec.pack(x, v)
        s.add(Curve(result_id=r.id, name=name, position_start_mm=start, position_step_mm=step, n_points=n,
                    values_f32=blob))
    if d is not None:
        for a in d.assessments:
            t = a.task
            s.add(TbeRow(
                result_id=r.id, task_name=t.name, profile=t.profile, radius_mm=t.radius_mm, angle_deg=t.angle_deg,
                feed_mm_min=t.feed_mm_min, gain_per_s=t.gain_per_s, tolerance_um=t.tolerance_um, tbe_um=a.tbe_um,
                backlash_limit_um=_fin(a.backlash_limit_um), state=a.state.value,
                tbe_uncertainty_um=_fin(a.tbe_uncertainty_um),
                backlash_limit_uncertainty_um=_fin(a.backlash_limit_uncertainty_um),
                decision_rule=a.rule, reason=a.reason or None,
            ))
    s.flush()
    return r


def _alert(a: Alert) -> AlertRecord:
    raised_cycle = cleared_cycle = None
    return AlertRecord(
        id=a.id, axis_id=a.axis_id, kind=a.kind, raised_at=as_utc(a.raised_at), cleared_at=as_utc(a.cleared_at),
        acknowledged_at=as_utc(a.acknowledged_at), acknowledged_by=a.acknowledged_by,
        raised_by_measurement_id=raised_cycle, cleared_by_measurement_id=cleared_cycle, task_name=a.task_name,
        tbe_um=a.tbe_um, tolerance_um=a.tolerance_um, backlash_um=a.backlash_um,
        backlash_limit_um=a.backlash_limit_um, message=a.message,
        raised_by_circular_test_id=a.raised_by_circle_id, cleared_by_circular_test_id=a.cleared_by_circle_id,
    )


def _alert_full(s: Session, a: Alert) -> AlertRecord:
    rec = _alert(a)
    ids = {}
    for key, rid in (("raised", a.raised_by_result_id), ("cleared", a.cleared_by_result_id)):
        ids[key] = s.scalar(select(Result.cycle_id).where(Result.id == rid)) if rid is not None else None
    from dataclasses import replace

    return replace(rec, raised_by_measurement_id=ids["raised"], cleared_by_measurement_id=ids["cleared"])


def alert_record(s: Session, a: Alert) -> AlertRecord:
    """The record of a stored alert, with the measurements (cycle ids) that raised and cleared it."""
    return _alert_full(s, a)


def _update_alerts(s: Session, fc: FinishedCycle, r: Result) -> list[AlertRecord]:
    d = fc.decision
    active = s.scalar(select(Alert).where(Alert.axis_id == fc.axis_id, Alert.kind == ALERT_KIND,  # (a circular
                                          Alert.raised_by_circle_id.is_(None), Alert.cleared_at.is_(None)))  # test's is its own)
    if d.state is State.ALARM and active is None:
        binding = next(a for a in d.assessments if a.task.name == d.binding_task)
        a = Alert(
            axis_id=fc.axis_id, kind=ALERT_KIND, raised_at=fc.finished_at, raised_by_result_id=r.id,
            task_name=d.binding_task, tbe_um=binding.tbe_um, tolerance_um=binding.task.tolerance_um,
            backlash_um=d.backlash_um, backlash_limit_um=_fin(d.backlash_limit_um), message=d.message(),
        )
        s.add(a)
        s.flush()
        return [_alert_full(s, a)]
    if d.state is not State.ALARM and active is not None:
        active.cleared_at = fc.finished_at
        active.cleared_by_result_id = r.id
        s.flush()
        return [_alert_full(s, active)]
    return []


# -- reading ---------------------------------------------------------------------------------
def _round_trip(r: Result, lead: list[LeadCriteriaRow], curves: list[Curve] | None) -> RoundTripResult:
    arrays = {}
    for cv in curves or ():
        arrays[cv.name] = curve_codec.unpack(cv.position_start_mm, cv.position_step_mm, cv.n_points, cv.values_f32)
    empty = np.zeros(0)
    pos_b, b = arrays.get("backlash_um", (empty, empty))
    profile = BacklashProfile(position_mm=pos_b, backlash_um=b, mean_um=r.backlash_mean_um,
                              min_um=r.backlash_min_um, max_um=r.backlash_max_um, std_um=r.backlash_std_um)
    strokes = {}
    for lc in lead:
        x, dev = arrays.get(f"{lc.direction}_travel_deviation_um", (empty, empty))
        _, mean = arrays.get(f"{lc.direction}_mean_travel_deviation_um", (empty, empty))
        strokes[lc.direction] = LeadCriteria(
            direction=lc.direction, position_mm=x, travel_deviation_um=dev, mean_travel_deviation_um=mean,
            e_p_um=lc.e_p_um, e_p_um_per_1000mm=lc.e_p_um_per_1000mm, v_u_um=lc.v_u_um, v_300_um=lc.v_300_um,
            v_2pi_um=lc.v_2pi_um, n_strokes=lc.n_strokes,
        )
    return RoundTripResult(
        axis="", useful_travel_mm=(r.useful_travel_start_mm, r.useful_travel_end_mm), backlash=profile,
        strokes=strokes, n_samples=r.n_samples, peak_speed_mm_min=r.peak_speed_mm_min,
        grid_step_mm=r.grid_step_mm if r.grid_step_mm is not None else 0.25,
        outliers_removed=r.outliers_removed or 0, noise_um=r.noise_um or 0.0,
        budgets=_budgets(r.uncertainty_budget), lost_motion=_lost_motion(r.lost_motion),
    )


def _lost_motion(text: str | None) -> LostMotion | None:
    if not text:
        return None
    d = json.loads(text)
    c = d.get("clearance") or {}
    clear = ClearanceEstimate(
        c.get("clearance_um"), c.get("clearance_uncertainty_um"), c.get("slope_um_per_m_min"),
        tuple(c.get("feeds_mm_min", ())), tuple(c.get("lost_motion_um", ())), c.get("source", "program"),
        c.get("reason", ""))
    return LostMotion(np.asarray(d["reversal_target_mm"], float), np.asarray(d["reversal_um"], float),
                      float(d["reversal_mean_um"]), float(d["reversal_max_um"]), clear)


def _budgets(text: str | None) -> dict[str, UncertaintyBudget]:
    if not text:
        return {}
    out = {}
    for key, b in json.loads(text).items():
        comps = tuple(UncertaintyComponent(c["name"], float(c["standard_um"]), c.get("note", ""))
                      for c in b["components"])
        out[key] = UncertaintyBudget(b.get("quantity", key), comps, float(b.get("coverage_factor", 2.0)))
    return out


def _tbe(row: TbeRow) -> TbeRecord:
    task = MachiningTask(name=row.task_name, profile=row.profile, feed_mm_min=row.feed_mm_min,
                         gain_per_s=row.gain_per_s, tolerance_um=row.tolerance_um, radius_mm=row.radius_mm,
                         angle_deg=row.angle_deg)
    limit = math.inf if row.backlash_limit_um is None else row.backlash_limit_um
    return TbeRecord(task=task, tbe_um=row.tbe_um, backlash_limit_um=limit, state=row.state,
                     tbe_uncertainty_um=row.tbe_uncertainty_um,
                     backlash_limit_uncertainty_um=row.backlash_limit_uncertainty_um,
                     decision_rule=row.decision_rule, reason=row.reason)


def _result(s: Session, r: Result, *, curves: bool) -> ResultRecord:
    lead = list(s.scalars(select(LeadCriteriaRow).where(LeadCriteriaRow.result_id == r.id)
                          .order_by(LeadCriteriaRow.id)))
    cv = list(s.scalars(select(Curve).where(Curve.result_id == r.id))) if curves else None
    tbe = [_tbe(t) for t in s.scalars(select(TbeRow).where(TbeRow.result_id == r.id).order_by(TbeRow.id))]
    return ResultRecord(
        id=r.id, cycle_id=r.cycle_id, axis_id=r.axis_id, measured_at=as_utc(r.measured_at),
        temperature_c=r.temperature_c, utility_day=r.utility_day, uncertainty_um=r.uncertainty_um,
        round_trip=_round_trip(r, lead, cv), state=r.state, binding_task=r.binding_task,
        backlash_limit_um=r.backlash_limit_um, message=r.message, tbe=tuple(tbe), decision_rule=r.decision_rule,
    )


def latest_result(s: Session, axis_id: int, *, curves: bool = False) -> ResultRecord | None:
    """The newest ok measurement of the axis."""
    r = s.scalar(select(Result).where(Result.axis_id == axis_id)
                 .order_by(Result.measured_at.desc(), Result.id.desc()).limit(1))
    return None if r is None else _result(s, r, curves=curves)


def latest_measurement_id(s: Session, axis_id: int) -> int | None:
    """The id of the newest ok measurement of the axis (the one :func:`latest_result` reads)."""
    return s.scalar(select(Result.cycle_id).where(Result.axis_id == axis_id)
                    .order_by(Result.measured_at.desc(), Result.id.desc()).limit(1))


def results_signature(s: Session, axis_id: int, since: datetime | None = None) -> tuple[int, int | None, int | None]:
    """(count, smallest id, largest id) of the axis' ok measurements since ``since``: it
    changes when one is stored or deleted (retention), and only then (a stored result
    never changes), so it names the content of a figure drawn from them."""
    q = select(func.count(Result.id), func.min(Result.id), func.max(Result.id)).where(Result.axis_id == axis_id)
    if since is not None:
        q = q.where(Result.measured_at >= since)
    n, lo, hi = s.execute(q).one()
    return int(n or 0), lo, hi


def get_measurement(s: Session, cycle_id: int, *, curves: bool = True) -> tuple[CycleRecord, ResultRecord | None]:
    c = s.get(Cycle, cycle_id)
    if c is None:
        raise NotFoundError("measurement", cycle_id)
    r = s.scalar(select(Result).where(Result.cycle_id == c.id))
    return _cycle(c, r), (None if r is None else _result(s, r, curves=curves))


def list_measurements(
    s: Session, axis_id: int, *, since: datetime | None = None, until: datetime | None = None,
    status: str | None = None, limit: int = 50, offset: int = 0,
) -> tuple[int, list[CycleRecord]]:
    """Cycles of an axis, newest first, by request time; ``(total, page)``."""
    if s.get(Axis, axis_id) is None:
        raise NotFoundError("axis", axis_id)
    if status is not None and status not in CYCLE_STATES:
        raise InputError(f"status (={status!r}) must be one of {CYCLE_STATES}")
    where = [Cycle.axis_id == axis_id]
    if since is not None:
        where.append(Cycle.requested_at >= since)
    if until is not None:
        where.append(Cycle.requested_at <= until)
    if status is not None:
        where.append(Cycle.status == status)
    total = s.scalar(select(func.count()).select_from(Cycle).where(*where))
    rows = s.execute(
        select(Cycle, Result).outerjoin(Result, Result.cycle_id == Cycle.id).where(*where)
        .order_by(Cycle.requested_at.desc(), Cycle.id.desc()).limit(limit).offset(offset)
    ).all()
    return int(total or 0), [_cycle(c, r) for c, r in rows]


def trend(s: Session, axis_id: int, *, since: datetime | None = None, until: datetime | None = None,
          max_points: int | None = None) -> TrendView:
    """The criteria of the ok measurements (positive stroke) in ``[since, until]``, oldest
    first: at most ``max_points`` of them (the min/max of b̄ per bucket) and the moment
    sums of all of them. The cost does not grow with the history (storage.db.rollup)."""
    if s.get(Axis, axis_id) is None:
        raise NotFoundError("axis", axis_id)
    return rollup.trend_view(s, axis_id, since=since, until=until, max_points=max_points)


def backlash_history(s: Session, axis_id: int) -> MomentSums:
    """Moment sums of (temperature_c, backlash_mean_um) over every ok measurement with a
    temperature (for the thermal model: core.history.TemperatureModel.fit_sums)."""
    return trend(s, axis_id, max_points=4).stats["temperature_c"]["backlash_mean_um"]


def recent_at_temperature(s: Session, axis_id: int, temperature_c: float, *, window_k: float = 1.0,
                          limit: int = 20, before: datetime | None = None,
                          since: datetime | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(temperature_c, backlash_mean_um) of the newest ``limit`` ok measurements within
    ±``window_k`` of ``temperature_c`` (and before ``before``, after ``since``: the last
    repair, which changed b̄): for the repeatability."""
    q = (select(Result.temperature_c, Result.backlash_mean_um)
         .where(Result.axis_id == axis_id, Result.temperature_c.between(temperature_c - window_k,
                                                                         temperature_c + window_k)))
    if before is not None:
        q = q.where(Result.measured_at < before)
    if since is not None:
        q = q.where(Result.measured_at > since)
    rows = s.execute(q.order_by(Result.measured_at.desc(), Result.id.desc()).limit(limit)).all()
    return (np.array([r[0] for r in rows], dtype=float), np.array([r[1] for r in rows], dtype=float))


def history_rows(s: Session, axis_id: int, *, max_rows: int = 3000,
                 since: datetime | None = None) -> dict[str, np.ndarray]:
    """Arrays of the ok measurements with a temperature, oldest first, for a robust fit
    (the prognosis): measured_at_s (epoch), temperature_c, utility_day, backlash_mean_um,
    feed_mm_min. At most ``max_rows``: past that, every k-th row (a regular thinning keeps
    the spread of temperatures and days the fit needs), always with the newest. With
    ``since`` (the axis' last repair), only the measurements after it."""
    where = (Result.axis_id == axis_id, Result.temperature_c.is_not(None))
    if since is not None:
        where = (*where, Result.measured_at > since)
    n = int(s.scalar(select(func.count()).select_from(Result).where(*where)) or 0)
    cols = (Result.measured_at, Result.temperature_c, Result.utility_day, Result.backlash_mean_um,
            Result.peak_speed_mm_min)
    if n > max_rows:
        k = -(-n // max_rows)
        rn = func.row_number().over(order_by=(Result.measured_at.desc(), Result.id.desc())).label("rn")
        sub = select(*cols, rn).where(*where).subquery()
        q = (select(sub.c.measured_at, sub.c.temperature_c, sub.c.utility_day, sub.c.backlash_mean_um,
                    sub.c.peak_speed_mm_min).where((sub.c.rn - 1) % k == 0).order_by(sub.c.measured_at))
    else:
        q = select(*cols).where(*where).order_by(Result.measured_at, Result.id)
    rows = s.execute(q).all()
    return {
        "measured_at_s": np.array([as_utc(r[0]).timestamp() for r in rows], dtype=float),
        "temperature_c": np.array([r[1] for r in rows], dtype=float),
        "utility_day": np.array([np.nan if r[2] is None else r[2] for r in rows], dtype=float),
        "backlash_mean_um": np.array([r[3] for r in rows], dtype=float),
        "feed_mm_min": np.array([r[4] for r in rows], dtype=float),
        "total": np.array(n),
    }


def tbe_history(s: Session, axis_id: int, *, since: datetime | None = None,
                max_points: int | None = None) -> list[tuple[datetime, str, float, float]]:
    """(measured_at, task_name, tbe_um, tolerance_um) of the ok measurements, oldest first:
    all of them, or with ``max_points`` those of the min/max downsampling of b̄ (the TBE of
    a task grows with b̄, Eqs. 7-8, so they are the TBE's extremes too): its cost does not
    grow with the history."""
    q = (select(Result.measured_at, TbeRow.task_name, TbeRow.tbe_um, TbeRow.tolerance_um)
         .join(TbeRow, TbeRow.result_id == Result.id).where(Result.axis_id == axis_id)
         .order_by(Result.measured_at, Result.id, TbeRow.id))
    if max_points is not None:
        view = trend(s, axis_id, since=since, max_points=max_points)
        if len(view.series.measurement_id) < view.points_total:
            q = q.where(Result.cycle_id.in_(view.series.measurement_id))
    if since is not None:
        q = q.where(Result.measured_at >= since)
    return [(as_utc(t), n, v, tol) for t, n, v, tol in s.execute(q).all()]


def mark_runs_deleted(s: Session, cycle_uuids: list[str] | tuple[str, ...], reason: str) -> int:
    """Say on each cycle whose raw run the retention policy deleted why it is gone
    (``raw_run_lost``; the result rows stay). Returns how many cycles were marked."""
    n = 0
    for i in range(0, len(cycle_uuids), 500):
        part = list(cycle_uuids[i : i + 500])
        n += s.execute(update(Cycle).where(Cycle.uuid.in_(part), Cycle.raw_run_lost.is_(None))
                       .values(raw_run_lost=reason)).rowcount or 0  # fmt: skip
    return n


def last_cycle_at(s: Session, axis_id: int, triggers: tuple[str, ...] = ("schedule", "catch_up")) -> datetime | None:
    """When the axis last had a scheduled cycle requested (for catching up a missed run)."""
    return as_utc(s.scalar(select(func.max(Cycle.requested_at))
                           .where(Cycle.axis_id == axis_id, Cycle.trigger.in_(triggers))))


# -- alerts ----------------------------------------------------------------------------------
def list_alerts(s: Session, state: str = "active", *, axis_id: int | None = None, limit: int = 100,
                offset: int = 0) -> tuple[int, list[AlertRecord]]:
    if state not in ("active", "cleared", "all"):
        raise InputError(f"state (={state!r}) must be active, cleared or all")
    where = []
    if state == "active":
        where.append(Alert.cleared_at.is_(None))
    elif state == "cleared":
        where.append(Alert.cleared_at.is_not(None))
    if axis_id is not None:
        where.append(Alert.axis_id == axis_id)
    total = s.scalar(select(func.count()).select_from(Alert).where(*where))
    rows = s.scalars(select(Alert).where(*where).order_by(Alert.raised_at.desc(), Alert.id.desc())
                     .limit(limit).offset(offset))
    return int(total or 0), [_alert_full(s, a) for a in rows]


def acknowledge_alert(s: Session, alert_id: int, by: str, when: datetime | None = None) -> AlertRecord:
    """Record who acknowledged the alert; acknowledging twice keeps the first."""
    a = s.get(Alert, alert_id)
    if a is None:
        raise NotFoundError("alert", alert_id)
    if a.acknowledged_at is None:
        a.acknowledged_at = when or utcnow()
        a.acknowledged_by = by
        s.flush()
    return _alert_full(s, a)


# -- metrics ----------------------------------------------------------------------------------
def metrics_snapshot(s: Session) -> dict:
    """Counts for Prometheus: cycles per axis and status, last success per axis, active alerts."""
    cycles = {(a, st): n for a, st, n in s.execute(
        select(Cycle.axis_id, Cycle.status, func.count()).group_by(Cycle.axis_id, Cycle.status)).all()}
    last_ok = {a: as_utc(t) for a, t in s.execute(
        select(Result.axis_id, func.max(Result.measured_at)).group_by(Result.axis_id)).all()}
    alerts = {a: n for a, n in s.execute(
        select(Alert.axis_id, func.count()).where(Alert.cleared_at.is_(None)).group_by(Alert.axis_id)).all()}
    lost = {a: n for a, n in s.execute(
        select(Cycle.axis_id, func.count()).where(Cycle.raw_run_lost.is_not(None)).group_by(Cycle.axis_id)).all()}
    return {"cycles": cycles, "last_success": last_ok, "active_alerts": alerts, "raw_runs_lost": lost}


