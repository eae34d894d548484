"""Records and core types -> response schemas."""

from __future__ import annotations

from datetime import datetime

import numpy as np

from api.rest import schemas as sc
from api.service.circles import axis_summary
from api.service.prognosis import to_dict as prognosis_body
from api.service.status import AxisStatus, state_and_message
from core.criteria.roundtrip import TBE_BASIS
from core.history import TemperatureModel
from core.errors import MebmError
from core.tbe import stored_repair_target
from storage.db import results_repo
from storage.db import AlertRecord, AxisRecord, CycleRecord, KeyRecord, MachineRecord, ResultRecord, TrendView


def machine(m: MachineRecord) -> sc.MachineOut:
    return sc.MachineOut(id=m.id, name=m.name, description=m.description, axis_ids=list(m.axis_ids))


def task(t) -> sc.TaskOut:
    try:
        limit = t.backlash_limit_um()
    except MebmError:
        limit = None
    return sc.TaskOut(name=t.name, profile=t.profile, feed_mm_min=t.feed_mm_min, tolerance_um=t.tolerance_um,
                      gain_per_s=t.gain_per_s, radius_mm=t.radius_mm, angle_deg=t.angle_deg,
                      backlash_limit_um=sc.fin(limit))


def axis(a: AxisRecord, next_run: datetime | None = None) -> sc.AxisOut:
    st = a.settings
    return sc.AxisOut(
        id=a.id, machine_id=a.machine_id, machine_name=a.machine_name, name=a.name,
        transmission_mm_per_rev=st.spec.transmission_mm_per_rev, screw_lead_mm=st.spec.screw_lead_mm,
        position_gain_per_s=st.spec.position_gain_per_s, travel_mm=st.spec.travel_mm,
        controller_url=st.controller_url, measure_feed_mm_min=st.measure_feed_mm_min,
        measure_acceleration_mm_s2=st.measure_acceleration_mm_s2, warning_fraction=st.warning_fraction,
        decision_rule=st.decision_rule, worst_case_temperature_c=st.worst_case_temperature_c,
        **st.instruments.to_dict(), schedule=sc.ScheduleOut(interval_s=st.schedule.interval_s, cron=st.schedule.cron,
                                enabled=st.schedule.enabled, next_run_at=next_run),
        tasks=[task(t) for t in st.tasks],
    )


def status(s: AxisStatus, now: datetime, next_run: datetime | None) -> sc.AxisStatusOut:
    a, latest, d = s.axis, s.latest, s.decision
    tasks = []
    if d is not None:
        for x in d.assessments:
            tasks.append(sc.TaskStatus(
                name=x.task.name, profile=x.task.profile, tolerance_um=x.task.tolerance_um,
                warning_threshold_um=d.warning_fraction * x.task.tolerance_um, tbe_um=x.tbe_um,
                tbe_uncertainty_um=x.tbe_uncertainty_um, backlash_limit_um=sc.fin(x.backlash_limit_um),
                backlash_limit_uncertainty_um=sc.fin(x.backlash_limit_uncertainty_um), state=x.state.value,
                decision_rule=x.rule, reason=x.reason, utilisation=x.utilisation,
            ))
    rt = latest.round_trip if latest else None
    unc = {}
    if rt is not None and rt.budgets:
        unc["backlash_mean_uncertainty_um"] = rt.backlash_mean_uncertainty_um
        for key in ("e_p", "v_u", "v_300", "v_2pi"):
            unc[f"{key}_uncertainty_um"] = rt.criterion_uncertainty_um("positive", key)
        unc["uncertainty_budget"] = {k: v.to_dict() for k, v in rt.budgets.items()
                                     if "." not in k or k.startswith("positive.")}
        if "backlash_mean_20c" in rt.budgets:
            unc["backlash_mean_20c_uncertainty_um"] = rt.budgets["backlash_mean_20c"].expanded_um
    lm = _lost_motion(rt, s)
    b = latest.round_trip.backlash.mean_um if latest else None
    limit = sc.fin(d.backlash_limit_um) if d else None
    target = d.repair_target if d else None
    state, message = state_and_message(s)
    return sc.AxisStatusOut(
        axis_id=a.id, machine_id=a.machine_id, machine_name=a.machine_name, axis_name=a.name, state=state,
        message=message, measurement_id=latest.cycle_id if latest else None,
        measured_at=latest.measured_at if latest else None,
        age_s=(now - latest.measured_at).total_seconds() if latest else None,
        temperature_c=latest.temperature_c if latest else None, utility_day=latest.utility_day if latest else None,
        backlash_mean_um=b, backlash_mean_20c_um=sc.fin(s.backlash_mean_20c_um),
        thermal_beta_um_per_k=sc.fin(s.thermal_beta_um_per_k), uncertainty_um=latest.uncertainty_um if latest else None,
        **unc, outliers_removed=rt.outliers_removed if rt is not None and rt.budgets else None,
        decision_rule=d.rule if d else a.settings.decision_rule,
        backlash_limit_um=limit,
        restore_below_um=target.restore_below_um if target is not None else None,
        restore_below_explanation=target.explanation if target is not None else None,
        backlash_reduction_needed_um=max(b - limit, 0.0) if (b is not None and limit is not None) else None,
        binding_task=d.binding_task if d else None, tasks=tasks, active_alert_id=s.active_alert_id,
        last_cycle_status=s.last_cycle_status, last_cycle_at=s.last_cycle_at,
        last_failure_reason=s.last_failure_reason, next_run_at=next_run, last_raw_run_lost=s.last_raw_run_lost,
        **lm, prognosis=_prognosis(s), work_order=_active_order(s.work_order),
        circular_test=axis_summary(s.circle, a.name),
    )


def _active_order(o) -> dict | None:
    """The status' summary of the axis' active work order, for an MES that polls
    the status rather than the maintenance endpoints."""
    if o is None:
        return None
    return {"id": o.id, "kind": o.kind, "state": o.state, "opened_at": o.opened_at, "due_at": o.due_at,
            "restore_below_um": o.restore_below_um,
            "restore_below_explanation": t.explanation if (t := stored_repair_target(o.restore_below_um,
                                                                                   o.backlash_limit_um)) else None,
            "recommendation": o.recommendation, "href": f"/api/v1/maintenance/orders/{o.id}"}


def _lost_motion(rt, s: AxisStatus) -> dict:
    """The status' lost-motion keys: B̄, B, B_i, and both clearance estimates."""
    out: dict = {}
    if rt is not None and rt.lost_motion is not None:
        lm = rt.lost_motion
        out = {"reversal_mean_um": lm.mean_um, "reversal_max_um": lm.max_abs_um,
               "lost_motion": {**lm.to_dict(), "tbe_basis": TBE_BASIS}}
    if s.history is not None:
        out.setdefault("lost_motion", {"tbe_basis": TBE_BASIS})["clearance_history"] = s.history.clearance.to_dict(points=False)
    return out


def _prognosis(s: AxisStatus) -> dict | None:
    if s.history is not None:
        return prognosis_body(s.history, points=False)  # the points: GET /axes/{id}/prognosis
    if s.history_error:
        return {"identifiable": False, "reason": f"the prognosis could not be computed: {s.history_error}"}
    return None


def summary(c: CycleRecord, held: dict | None = None) -> sc.MeasurementSummary:
    """``held``: uuid -> (status, reason) of the cycles that finished but wait in the spool
    (CycleExecutor.held): shown finished (``failed`` until the spool stores an ok one) with
    their reason, never ``running``."""
    status, reason = c.status, c.failure_reason
    if held and c.status in ("queued", "running") and c.uuid in held:
        kept_status, kept_reason = held[c.uuid]
        status = "failed" if kept_status == "ok" else kept_status
        reason = kept_reason or "finished; waiting in the spool to be stored"
    return sc.MeasurementSummary(
        id=c.id, axis_id=c.axis_id, status=status, trigger=c.trigger, requested_by=c.requested_by,
        requested_at=c.requested_at, started_at=c.started_at, finished_at=c.finished_at,
        failure_reason=reason, reason_code=results_repo.STORAGE_FULL if results_repo.is_storage_full(reason) else None,
        temperature_c=c.temperature_c, utility_day=c.utility_day,
        uncertainty_um=c.uncertainty_um, backlash_mean_um=c.backlash_mean_um, state=c.state,
        raw_run_lost=c.raw_run_lost,
    )


def _list(a) -> list[float]:
    return [float(v) for v in np.asarray(a, dtype=float)]


def detail(c: CycleRecord, r: ResultRecord | None, curves: bool, held: dict | None = None) -> sc.MeasurementDetail:
    base = summary(c, held).model_dump()
    if r is None:
        return sc.MeasurementDetail(**base, result=None, curves=None)
    rt = r.round_trip
    lead = {d: sc.LeadOut(direction=d, e_p_um=lc.e_p_um, e_p_um_per_1000mm=lc.e_p_um_per_1000mm, v_u_um=lc.v_u_um,
                          v_300_um=lc.v_300_um, v_2pi_um=lc.v_2pi_um, n_strokes=lc.n_strokes)
            for d, lc in rt.strokes.items()}
    tbe = [sc.TbeOut(task_name=t.task.name, profile=t.task.profile, tolerance_um=t.task.tolerance_um, tbe_um=t.tbe_um,
                     backlash_limit_um=sc.fin(t.backlash_limit_um), state=t.state) for t in r.tbe]
    result = sc.ResultOut(
        backlash_mean_um=rt.backlash.mean_um, backlash_min_um=rt.backlash.min_um, backlash_max_um=rt.backlash.max_um,
        backlash_std_um=rt.backlash.std_um, useful_travel_mm=rt.useful_travel_mm, n_samples=rt.n_samples,
        peak_speed_mm_min=rt.peak_speed_mm_min, lead=lead, tbe=tbe, state=r.state, binding_task=r.binding_task,
        backlash_limit_um=sc.fin(r.backlash_limit_um), message=r.message, run_file=c.run_file,
    )
    cv = None
    if curves and rt.backlash.position_mm.size:
        p, n = rt.strokes["positive"], rt.strokes["negative"]
        cv = sc.CurvesOut(
            position_mm=_list(rt.backlash.position_mm), backlash_um=_list(rt.backlash.backlash_um),
            positive_travel_deviation_um=_list(p.travel_deviation_um),
            negative_travel_deviation_um=_list(n.travel_deviation_um),
            positive_mean_travel_deviation_um=_list(p.mean_travel_deviation_um),
            negative_mean_travel_deviation_um=_list(n.mean_travel_deviation_um),
        )
    return sc.MeasurementDetail(**base, result=result, curves=cv)


CRITERIA = ("backlash_mean_um", "e_p_um_per_1000mm", "v_u_um", "v_300_um", "v_2pi_um")


def trend(axis_id: int, v: TrendView) -> sc.TrendOut:
    """The trend: the points the storage kept for the screen, and the correlations and the
    thermal model of every measurement in the range (from their moment sums)."""
    t = v.series
    series = sc.TrendSeriesOut(
        measurement_id=list(t.measurement_id), measured_at=list(t.measured_at), temperature_c=list(t.temperature_c),
        utility_day=list(t.utility_day), backlash_mean_um=list(t.backlash_mean_um),
        e_p_um_per_1000mm=list(t.e_p_um_per_1000mm), v_u_um=list(t.v_u_um), v_300_um=list(t.v_300_um),
        v_2pi_um=list(t.v_2pi_um),
    )
    corr = {c: {d: sc.fin(v.stats[d][c].pearson_r()) for d in ("temperature_c", "utility_day")} for c in CRITERIA}
    model = None
    sums = v.stats["temperature_c"]["backlash_mean_um"]
    if sums.n >= 3 and sums.x_max - sums.x_min >= 1.0:
        try:
            m = TemperatureModel().fit_sums(sums)
            model = sc.ThermalModelOut(backlash_20c_um=m.backlash_ref_um_, beta_um_per_k=m.beta_um_per_k_,
                                       r=sc.fin(m.r_), n=m.n_)
        except MebmError:
            model = None
    return sc.TrendOut(axis_id=axis_id, points=len(t.measurement_id), points_total=v.points_total, series=series,
                       correlation=corr, thermal_model=model)


def alert(a: AlertRecord) -> sc.AlertOut:
    return sc.AlertOut(
        id=a.id, axis_id=a.axis_id, kind=a.kind, active=a.active, raised_at=a.raised_at, cleared_at=a.cleared_at,
        acknowledged_at=a.acknowledged_at, acknowledged_by=a.acknowledged_by,
        raised_by_measurement_id=a.raised_by_measurement_id, cleared_by_measurement_id=a.cleared_by_measurement_id,
        task_name=a.task_name, tbe_um=a.tbe_um, tolerance_um=a.tolerance_um, backlash_um=a.backlash_um,
        backlash_limit_um=a.backlash_limit_um, message=a.message,
        raised_by_circular_test_id=a.raised_by_circular_test_id, cleared_by_circular_test_id=a.cleared_by_circular_test_id,
    )


def key(k: KeyRecord) -> sc.KeyOut:
    return sc.KeyOut(id=k.id, name=k.name, role=k.role, key_prefix=k.key_prefix, created_at=k.created_at,
                     revoked_at=k.revoked_at)
