"""The maintenance loop in the service: orders opened by the measured error,
repairs recorded by people, and the measurement that verifies them.

- After each stored ok measurement (:meth:`MaintenanceLoop.after_cycle`, called by the
  service once the cycle's own events are out): an axis in ALARM gets a *corrective*
  order, an axis in WARNING whose prognosis dates the backlash limit within
  ``maintenance.horizon_days`` a *condition-based* one (EN 13306); never two active
  orders on one axis (the database's partial unique index).
- :meth:`record_repair` stores the repair, moves the axis' order to ``repaired`` and
  queues a ``verification`` cycle (at once, or at ``maintenance.verify_at``).
- When that cycle is stored, it is compared with the last measurement before the repair
  (core.maintenance.verify_repair): the order becomes ``verified``, or ``open`` again
  with both sets of figures.
- A circular test (api.service.circles) judged like a cycle: its WARNING or ALARM opens
  the same order with the test as evidence (:meth:`MaintenanceLoop.after_circle`), and a
  test at a circle task's radius and feed measured after the repair verifies a repaired
  order (core.maintenance.verify_repair_by_circle); the verification cycle queued with
  the repair then finds the order concluded and is an ordinary measurement.
Each step is published as a ``work_order_changed`` event on the service's event hub,
so MQTT, webhooks and MTConnect carry it like an alert.
"""

from __future__ import annotations

import logging
import math
from datetime import datetime, time as dtime, timedelta, timezone

from api.service.config.settings import SIM_CONTROLLER, MaintenanceSettings
from api.service.events import Event
from core.errors import MebmError
from core.maintenance import summarise_axis, verify_repair, verify_repair_by_circle
from core.tbe import State
from storage.db import (
    AlertRecord,
    AxisRecord,
    CircularTestRecord,
    CycleRecord,
    OrderRequest,
    RepairRecord,
    StorageError,
    WorkOrderRecord,
    config_repo,
    maintenance_repo,
    results_repo,
    session_scope,
    utcnow,
)

log = logging.getLogger("mebm.maintenance")
RESTORING_KINDS = ("preload_adjusted", "nut_replaced", "screw_replaced", "other")  # what resets a simulator's wear


def next_verify_time(verify_at: str, now: datetime) -> datetime | None:
    """None for "now"; else the next ``HH:MM`` (UTC) after ``now``."""
    if verify_at == "now":
        return None
    hh, mm = (int(x) for x in verify_at.split(":"))
    at = datetime.combine(now.date(), dtime(hh, mm), tzinfo=timezone.utc)
    return at if at > now else at + timedelta(days=1)


class MaintenanceLoop:
    def __init__(self, service, settings: MaintenanceSettings):
        self.service = service
        self.settings = settings

    # -- events ------------------------------------------------------------------------------
    def publish(self, order: WorkOrderRecord) -> None:
        svc = self.service
        axis = svc.executor.known_axis(order.axis_id) if svc.executor is not None else None
        machine, name = (axis.machine_name, axis.name) if axis is not None else ("?", "?")
        if svc.status is not None:
            svc.status.invalidate(order.axis_id)
        svc.events.publish(Event("work_order_changed", order.axis_id, machine, name, utcnow(), order=order))

    # -- after a stored cycle ------------------------------------------------------------------
    def after_cycle(self, axis_id: int, cycle: CycleRecord, alerts: list[AlertRecord]) -> None:
        if not self.settings.enabled or cycle.status != "ok":
            if cycle.trigger == "verification" and cycle.status != "ok":
                log.warning("axis %s: the verification measurement %s failed (%s); the order stays repaired "
                            "(POST /maintenance/orders/{id}/verify queues another)", axis_id, cycle.id,
                            cycle.failure_reason)
            return
        try:
            if cycle.trigger == "verification" and self._verify(axis_id, cycle):
                return
            self._maybe_open(axis_id, cycle, alerts)
        except (MebmError, StorageError) as exc:
            log.error("axis %s: maintenance step after measurement %s failed: %s", axis_id, cycle.id, exc)

    def _maybe_open(self, axis_id: int, cycle: CycleRecord, alerts: list[AlertRecord]) -> None:
        if cycle.state not in ("WARNING", "ALARM"):
            return  # judged OK when stored (or not judged): nothing to open, no status to compute
        st = self.service.status.get(axis_id)
        d = st.decision
        if d is None or st.latest is None or st.latest.cycle_id != cycle.id:
            return
        opened = self._order_kind(d.state, st.history.prognosis if st.history is not None else None)
        if opened is None:
            return
        kind, due = opened
        with session_scope(self.service.factory) as s:
            if maintenance_repo.active_order(s, axis_id) is not None:
                return
        binding = next(a for a in d.assessments if a.task.name == d.binding_task)
        target = d.repair_target
        u_b = d.backlash_uncertainty_um
        what = ("corrective maintenance: the machining error is out of tolerance" if kind == "corrective" else
                f"condition-based maintenance: the prognosis dates the backlash limit on {due:%Y-%m-%d %H:%M} UTC, "
                f"within the {self.settings.horizon_days:g}-day horizon")
        rec = (f"{what}. Axis {st.axis.machine_name}/{st.axis.name}: task {d.binding_task!r} (tolerance "
               f"{binding.task.tolerance_um:g} µm), b̄ {d.backlash_um:.1f} ± {u_b:.1f} µm, TBE "
               f"{binding.tbe_um:.2f} ± {binding.tbe_uncertainty_um:.2f} µm (k = 2, {d.rule} rule)."
               + (f" {target.sentence()[0].upper()}{target.sentence()[1:]}." if target is not None else ""))
        alert = next((a for a in alerts if a.active and a.kind == "tbe_exceeded"), None)
        req = OrderRequest(
            axis_id=axis_id, kind=kind, opened_at=cycle.finished_at or utcnow(), recommendation=rec,
            result_id=st.latest.id, alert_id=alert.id if alert is not None else None, binding_task=d.binding_task,
            tolerance_um=binding.task.tolerance_um, backlash_um=d.backlash_um, backlash_uncertainty_um=u_b,
            tbe_um=binding.tbe_um, tbe_uncertainty_um=binding.tbe_uncertainty_um,
            backlash_limit_um=d.backlash_limit_um if math.isfinite(d.backlash_limit_um) else None,
            restore_below_um=target.restore_below_um if target is not None else None, due_at=due,
        )
        with session_scope(self.service.factory) as s:
            order, created = maintenance_repo.open_order(s, req)
        if created:
            log.warning("axis %s: work order %s opened (%s)", axis_id, order.id, kind)
            self.publish(order)

    # -- after a stored circular test ----------------------------------------------------------
    def _order_kind(self, state: State, prognosis) -> tuple[str, datetime | None] | None:
        """The order a decision opens: ALARM a corrective one; WARNING a condition-based one,
        due on the prognosis' date, when that date falls within the horizon; else none."""
        if state is State.ALARM:
            return "corrective", None
        if state is not State.WARNING or prognosis is None or prognosis.limit_date_s is None:
            return None
        if prognosis.limit_date_s > prognosis.now_s + self.settings.horizon_days * 86400.0:
            return None
        return "condition_based", datetime.fromtimestamp(prognosis.limit_date_s, tz=timezone.utc)

    def after_circle(self, axis: AxisRecord, test: CircularTestRecord, decision, alerts: list[AlertRecord]) -> None:
        """A circular test judged ``axis`` (``decision``: core.circle.CircleDecision): a
        repaired order is verified by it; otherwise a WARNING or ALARM opens the order a
        round trip's decision would open, with the test as its evidence."""
        if not self.settings.enabled or decision is None:
            return
        try:
            if self._verify_by_circle(axis, test, decision):
                return
            self._open_from_circle(axis, test, decision, alerts)
        except (MebmError, StorageError) as exc:
            log.error("axis %s: maintenance step after circular test %s failed: %s", axis.id, test.id, exc)

    def _open_from_circle(self, axis: AxisRecord, test: CircularTestRecord, d, alerts: list[AlertRecord]) -> None:
        st = self.service.status.get(axis.id) if self.service.status is not None else None
        # condition-based on the prognosis' date, as after a round trip
        opened = self._order_kind(d.state, st.history.prognosis if st is not None and st.history is not None else None)
        if opened is None:
            return
        kind, due = opened
        with session_scope(self.service.factory) as s:
            if maintenance_repo.active_order(s, axis.id) is not None:
                return
        what = ("corrective maintenance: the machining error is out of tolerance" if kind == "corrective" else
                f"condition-based maintenance: the prognosis dates the backlash limit on {due:%Y-%m-%d %H:%M} UTC, "
                f"within the {self.settings.horizon_days:g}-day horizon")
        rec = (f"{what}. Axis {axis.machine_name}/{axis.name}: circular test {test.id} (R {test.radius_mm:g} mm, "
               f"F {test.feed_mm_min:g} mm/min) measures task {d.task!r} (tolerance {d.tolerance_um:g} µm) at TBE "
               f"{d.error_um:.2f} ± {d.uncertainty_um:.2f} µm (k = 2, {d.rule} rule, reversal {d.spike}); "
               f"circular deviation G {d.circular_deviation_um:.2f} ± {d.circular_deviation_uncertainty_um:.2f} µm.")
        alert = next((a for a in alerts if a.active and a.kind == "tbe_exceeded"), None)
        b = (test.agreement.get(axis.name) or {})
        req = OrderRequest(
            axis_id=axis.id, kind=kind, opened_at=test.measured_at, recommendation=rec, circular_test_id=test.id,
            alert_id=alert.id if alert is not None else None, binding_task=d.task, tolerance_um=d.tolerance_um,
            backlash_um=b.get("backlash_um"), backlash_uncertainty_um=b.get("backlash_uncertainty_um"),
            tbe_um=d.error_um, tbe_uncertainty_um=d.uncertainty_um, due_at=due,
        )
        with session_scope(self.service.factory) as s:
            order, created = maintenance_repo.open_order(s, req)
        if created:
            log.warning("axis %s: work order %s opened (%s) by circular test %s", axis.id, order.id, kind, test.id)
            self.publish(order)

    def _verify_by_circle(self, axis: AxisRecord, test: CircularTestRecord, d) -> bool:
        """A repaired order of the axis is concluded by a circular test that judged one of
        its circle tasks: the direct measurement of the error the order was opened for."""
        with session_scope(self.service.factory) as s:
            order = maintenance_repo.active_order(s, axis.id)
            if order is None or order.state != "repaired":
                return False
            repair = maintenance_repo.repair_of_order(s, order.id)
            if repair is not None and repair.performed_at > test.measured_at:
                return False  # measured before the repair: no evidence of it
            before_id = repair.before_measurement_id if repair is not None else None
            before = maintenance_repo.figures(s, before_id) if before_id is not None else None
        v = verify_repair_by_circle(before, d, circular_test_id=test.id, radius_mm=test.radius_mm,
                                    feed_mm_min=test.feed_mm_min)
        with session_scope(self.service.factory) as s:
            order = maintenance_repo.conclude_verification(s, order.id, passed=v["passed"], verification=v,
                                                           note=v["message"])
        (log.info if v["passed"] else log.warning)("axis %s: work order %s %s by circular test %s: %s", axis.id,
                                                   order.id, order.state, test.id, v["message"])
        self.publish(order)
        return True

    def _verify(self, axis_id: int, cycle: CycleRecord) -> bool:
        with session_scope(self.service.factory) as s:
            order = maintenance_repo.order_awaiting(s, cycle.id)
            if order is None:
                return False
            axis = config_repo.get_axis(s, axis_id)
            repair = maintenance_repo.repair_of_order(s, order.id)
            after = maintenance_repo.figures(s, cycle.id)
            before_id = repair.before_measurement_id if repair is not None else None
            before = maintenance_repo.figures(s, before_id) if before_id is not None else after
            comp = comp_u = None
            source = ""
            if repair is not None and repair.kind == "compensation_loaded" and repair.compensation_measurement_id:
                cf = maintenance_repo.figures(s, repair.compensation_measurement_id)
                comp, comp_u = cf.backlash_mean_um, cf.backlash_mean_uncertainty_um
                source = (f"table of measurement {repair.compensation_measurement_id}"
                          + (f", {repair.compensation_file}" if repair.compensation_file else ""))
        v = verify_repair(before, after, axis.tasks, rule=axis.settings.decision_rule,
                          warning_fraction=axis.settings.warning_fraction, compensated_backlash_um=comp,
                          compensated_uncertainty_um=comp_u or 0.0, compensation_source=source)
        with session_scope(self.service.factory) as s:
            order = maintenance_repo.conclude_verification(s, order.id, passed=v.passed, verification=v.to_dict(),
                                                           note=v.message)
        (log.info if v.passed else log.warning)("axis %s: work order %s %s: %s", axis_id, order.id, order.state,
                                                v.message)
        self.publish(order)
        return True

    # -- operations (REST, CLI) ------------------------------------------------------------------
    def transition(self, order_id: int, action: str, *, by: str, note: str = "") -> WorkOrderRecord:
        with session_scope(self.service.factory) as s:
            order = maintenance_repo.transition(s, order_id, action, by=by, note=note)
        self.publish(order)
        return order

    def record_repair(self, axis_id: int, kind: str, *, by: str, note: str = "", performed_at: datetime | None = None,
                      compensation_measurement_id: int | None = None,
                      compensation_file: str | None = None) -> tuple[RepairRecord, WorkOrderRecord | None]:
        with session_scope(self.service.factory) as s:
            axis = config_repo.get_axis(s, axis_id)
            repair, order = maintenance_repo.record_repair(
                s, axis_id, kind, by=by, note=note, performed_at=performed_at,
                compensation_measurement_id=compensation_measurement_id, compensation_file=compensation_file)
        self._simulate(axis, kind)
        if self.service.status is not None:
            self.service.status.invalidate(axis_id)  # the prognosis refits from the repair on
        if order is not None:
            self.publish(order)
            order = self.queue_verification(order.id, by) or order
        return repair, order

    def _simulate(self, axis: AxisRecord, kind: str) -> None:
        """On a simulated controller the repair is simulated too (the demo's technician)."""
        if axis.settings.controller_url != SIM_CONTROLLER or kind not in RESTORING_KINDS:
            return
        sim = self.service.simulators.get(axis.id)
        if sim is None:
            return
        try:
            sim.repair()
        except (OSError, ConnectionError) as exc:
            log.error("axis %s: the simulated controller was not repaired: %s", axis.id, exc)

    def queue_verification(self, order_id: int, by: str) -> WorkOrderRecord | None:
        """Queue the order's verification cycle now, or schedule it at ``verify_at``."""
        svc = self.service
        if svc.scheduler is None:
            return None
        at = next_verify_time(self.settings.verify_at, utcnow())
        if at is not None:
            svc.scheduler.clock.add_job(self.queue_verification, "date", run_date=at, args=(order_id, by),
                                        id=f"verify-{order_id}", replace_existing=True)
            log.info("work order %s: verification cycle at %s", order_id, at.isoformat())
            return None
        with session_scope(svc.factory) as s:
            order = maintenance_repo.get_order(s, order_id)
        if order.state != "repaired":
            return order
        cycle = svc.scheduler.request(order.axis_id, "verification", requested_by=by)
        if not isinstance(cycle, CycleRecord):
            log.warning("work order %s: verification cycle queued without the database; verify it again later",
                        order_id)
            return order
        with session_scope(svc.factory) as s:
            maintenance_repo.set_verification_cycle(s, order_id, cycle.id)
            return maintenance_repo.get_order(s, order_id)

    def resume(self) -> None:
        """At start-up: conclude each repaired order whose verification measurement was
        stored but not judged (a stop in between), and queue the verification of those
        whose measurement is not there (cancelled by a stop, or never queued)."""
        try:
            with session_scope(self.service.factory) as s:
                _, orders = maintenance_repo.list_orders(s, "repaired", limit=10_000)
                waiting = [o for o in orders if o.verification_measurement_id is None
                           or not maintenance_repo.cycle_pending_or_ok(s, o.verification_measurement_id)]
                measured = [(o, results_repo.get_measurement(s, o.verification_measurement_id, curves=False)[0])
                            for o in orders if o not in waiting
                            and maintenance_repo.result_id_of(s, o.verification_measurement_id) is not None]
        except StorageError as exc:
            log.warning("repaired orders not resumed: %s", exc)
            return
        for o, cycle in measured:
            try:
                self._verify(o.axis_id, cycle)
            except (MebmError, StorageError) as exc:
                log.error("work order %s: verification not concluded: %s", o.id, exc)
        for o in waiting:
            by = o.transitions[-1].by if o.transitions else maintenance_repo.SERVICE
            try:
                self.queue_verification(o.id, by)
            except (MebmError, StorageError) as exc:
                log.error("work order %s: verification not queued: %s", o.id, exc)

    def summary(self, since: datetime | None = None, until: datetime | None = None,
                fixed_interval_days: float | None = None) -> tuple[list, dict]:
        """Per-axis summaries (core.maintenance.AxisMaintenanceSummary) and the fleet's totals."""
        from core.maintenance import fleet_totals

        until = until or utcnow()
        fixed = fixed_interval_days or self.settings.fixed_interval_days
        out = []
        with session_scope(self.service.factory) as s:
            for axis in config_repo.list_axes(s):
                d = maintenance_repo.summary_inputs(s, axis.id, since, until)
                out.append((axis, summarise_axis(axis.id, d["start"].timestamp(), d["end"].timestamp(),
                                                 called_repairs_s=d["called_repairs_s"],
                                                 other_repairs=d["other_repairs"], orders=d["orders"],
                                                 fixed_interval_days=fixed)))
        return out, fleet_totals([x for _, x in out])
