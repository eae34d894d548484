"""The maintenance loop's own logic: the work order's state machine, the
comparison that verifies a repair, and the managers' counts against a fixed interval.

Terms are those of EN 13306: an order opened on ALARM is *corrective* maintenance (the
required function is lost: a task's machining error is out of tolerance); one opened
on WARNING because the prognosis dates the limit within a horizon is *condition-based*
(predictive) maintenance. Pure Python and numpy: the storage and the service call it.

State machine::

    open --acknowledge--> acknowledged --repair--> repaired --verify(pass)--> verified
    open --repair--> repaired                       repaired --verify(fail)--> open
    repaired --repair--> repaired (a further repair before the verification: verified anew)
    open | acknowledged | repaired --cancel(reason)--> cancelled

``verified`` and ``cancelled`` are final. An order that is not final is *active*: an axis
has at most one active order at a time (the database enforces it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from core.errors import InputError
from core.tbe import MachiningTask, State, decide, repair_target

ORDER_STATES = ("open", "acknowledged", "repaired", "verified", "cancelled")
ACTIVE_STATES = ("open", "acknowledged", "repaired")
FINAL_STATES = ("verified", "cancelled")
ORDER_KINDS = ("corrective", "condition_based")  # EN 13306
REPAIR_KINDS = ("preload_adjusted", "nut_replaced", "screw_replaced", "compensation_loaded", "lubricated", "other")

# action -> {from state: to state}
TRANSITIONS: dict[str, dict[str, str]] = {
    "acknowledge": {"open": "acknowledged"},
    "repair": {"open": "repaired", "acknowledged": "repaired", "repaired": "repaired"},  # another repair: verify again
    "verify_pass": {"repaired": "verified"},
    "verify_fail": {"repaired": "open"},
    "cancel": {"open": "cancelled", "acknowledged": "cancelled", "repaired": "cancelled"},
}


class TransitionError(InputError):
    """An order cannot take this step from its state (``order_state``, ``action``)."""

    def __init__(self, order_id: int | None, order_state: str, action: str):
        self.order_id, self.order_state, self.action = order_id, order_state, action
        allowed = sorted(a for a, m in TRANSITIONS.items() if order_state in m)
        which = f"order {order_id}" if order_id is not None else "the order"
        super().__init__(f"{which} is {order_state!r}: it cannot be {_PAST.get(action, action)} "
                         f"(allowed from {order_state!r}: {', '.join(allowed) or 'nothing, it is final'})")


_PAST = {"acknowledge": "acknowledged", "repair": "repaired", "verify_pass": "verified",
         "verify_fail": "sent back to open", "cancel": "cancelled"}


def next_state(state: str, action: str, *, order_id: int | None = None) -> str:
    """The state after ``action``, or :class:`TransitionError` if the step is not allowed."""
    if state not in ORDER_STATES:
        raise InputError(f"order state (={state!r}) must be one of {ORDER_STATES}")
    if action not in TRANSITIONS:
        raise InputError(f"action (={action!r}) must be one of {tuple(TRANSITIONS)}")
    to = TRANSITIONS[action].get(state)
    if to is None:
        raise TransitionError(order_id, state, action)
    return to


def check_repair_kind(kind: str) -> str:
    if kind not in REPAIR_KINDS:
        raise InputError(f"repair kind (={kind!r}) must be one of {REPAIR_KINDS}")
    return kind


# -- verification -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Figures:
    """What one measurement says about the axis: b̄ and its expanded uncertainty (k = 2),
    the lead criteria of the positive stroke, and each task's TBE ± U and state."""

    measurement_id: int
    backlash_mean_um: float
    backlash_mean_uncertainty_um: float
    lead: dict[str, float] = field(default_factory=dict)  # e_p_um_per_1000mm, v_u_um, v_300_um, v_2pi_um
    tasks: tuple[dict, ...] = ()  # {"task", "tbe_um", "tbe_uncertainty_um", "tolerance_um", "state"}

    def to_dict(self) -> dict:
        return {"measurement_id": self.measurement_id, "backlash_mean_um": _r(self.backlash_mean_um),
                "backlash_mean_uncertainty_um": _r(self.backlash_mean_uncertainty_um),
                "lead": {k: _r(v) for k, v in self.lead.items()}, "tasks": [dict(t) for t in self.tasks]}


def _r(x: float | None, nd: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


@dataclass(frozen=True)
class Verification:
    """The verification of a repair: before and after, each change with its expanded
    uncertainty (the two measurements are independent: U = sqrt(U1² + U2²)), the tasks
    judged after the repair by the axis' decision rule, and the verdict."""

    passed: bool
    before: Figures
    after: Figures
    changes: dict
    tasks_after: tuple[dict, ...]
    rule: str
    against: str  # "measured backlash" or "compensated error (...)"
    message: str

    def to_dict(self) -> dict:
        return {"passed": self.passed, "rule": self.rule, "against": self.against, "message": self.message,
                "before": self.before.to_dict(), "after": self.after.to_dict(), "changes": self.changes,
                "tasks_after": list(self.tasks_after)}


def _change(before: float, u_before: float, after: float, u_after: float) -> dict:
    d = after - before
    u = math.hypot(u_before or 0.0, u_after or 0.0)
    return {"before": _r(before), "after": _r(after), "change": _r(d), "uncertainty": _r(u),
            "significant": bool(abs(d) > u) if u > 0 else None}


def verify_repair(before: Figures, after: Figures, tasks: Sequence[MachiningTask], *, rule: str,
                  warning_fraction: float, compensated_backlash_um: float | None = None,
                  compensated_uncertainty_um: float = 0.0, compensation_source: str = "") -> Verification:
    """Judge a repair: it passes when every task is OK after it by ``rule`` (ISO 14253-1,
    core.tbe.decision): conformity with the warning threshold proven, so the axis is
    back below the level that opened the order. With ``compensated_backlash_um`` (a
    ``compensation_loaded`` repair), the tasks are judged on the compensated error: the
    residual backlash |b̄ - b_comp|, with U = sqrt(U(b̄)² + U(b_comp)²), since the
    mechanical play the encoders measure is unchanged by a controller's table."""
    if not tasks:
        raise InputError("the axis has no machining task: a repair cannot be verified against a tolerance")
    changes = {"backlash_mean_um": _change(before.backlash_mean_um, before.backlash_mean_uncertainty_um,
                                           after.backlash_mean_um, after.backlash_mean_uncertainty_um)}
    for k in sorted(set(before.lead) & set(after.lead)):
        changes[k] = _change(before.lead[k], 0.0, after.lead[k], 0.0)
    b_tasks = {t["task"]: t for t in before.tasks}
    for t in after.tasks:
        if t["task"] in b_tasks:
            bt = b_tasks[t["task"]]
            changes[f"tbe_um[{t['task']}]"] = _change(bt["tbe_um"], bt.get("tbe_uncertainty_um") or 0.0,
                                                      t["tbe_um"], t.get("tbe_uncertainty_um") or 0.0)
    b, u = after.backlash_mean_um, after.backlash_mean_uncertainty_um
    against = "measured backlash"
    if compensated_backlash_um is not None:
        b = abs(after.backlash_mean_um - compensated_backlash_um)
        u = math.hypot(after.backlash_mean_uncertainty_um, compensated_uncertainty_um)
        against = (f"compensated error: residual backlash |{after.backlash_mean_um:.1f} - "
                   f"{compensated_backlash_um:.1f}| = {b:.1f} ± {u:.1f} µm"
                   + (f" ({compensation_source})" if compensation_source else ""))
    d = decide(max(b, 0.0), tasks, warning_fraction=warning_fraction, backlash_uncertainty_um=u, rule=rule)
    judged = tuple({"task": a.task.name, "tbe_um": _r(a.tbe_um), "tbe_uncertainty_um": _r(a.tbe_uncertainty_um),
                    "tolerance_um": a.task.tolerance_um, "state": a.state.value, "passed": a.state is State.OK}
                   for a in d.assessments)
    passed = all(t["passed"] for t in judged)
    failing = [t["task"] for t in judged if not t["passed"]]
    cb = changes["backlash_mean_um"]
    head = (f"b̄ {before.backlash_mean_um:.1f} ± {before.backlash_mean_uncertainty_um:.1f} µm before, "
            f"{after.backlash_mean_um:.1f} ± {after.backlash_mean_uncertainty_um:.1f} µm after "
            f"(change {cb['change']:+.1f} ± {cb['uncertainty']:.1f} µm)")
    if passed:
        msg = f"verified against the {against}: every task OK by the {rule} rule; {head}"
    else:
        msg = (f"not verified against the {against}: task(s) {', '.join(failing)} not OK by the {rule} rule "
               f"({d.state.value}); {head}")
    return Verification(passed, before, after, changes, judged, rule, against, msg)


def verify_repair_by_circle(before: Figures | None, decision, *, circular_test_id: int, radius_mm: float,
                            feed_mm_min: float) -> dict:
    """Judge a repair on a circular test measured after it (``decision``: the
    core.circle.CircleDecision of the axis): the direct measurement of the task's
    machining error. It passes when the judged task is OK by the decision's rule (the
    worst of the tasks the test matched is the one judged). Returns the shape of
    :meth:`Verification.to_dict`, with ``after`` the test's figures and the change of the
    task's TBE from the round trip before the repair (its Eq. 8 estimate) to the test."""
    passed = decision.state is State.OK
    after = {"circular_test_id": circular_test_id, "radius_mm": radius_mm, "feed_mm_min": feed_mm_min,
             "tasks": [{"task": decision.task, "tbe_um": _r(decision.error_um),
                        "tbe_uncertainty_um": _r(decision.uncertainty_um), "tolerance_um": decision.tolerance_um,
                        "state": decision.state.value}],
             "circular_deviation_um": _r(decision.circular_deviation_um),
             "circular_deviation_uncertainty_um": _r(decision.circular_deviation_uncertainty_um)}
    changes = {}
    b_task = next((t for t in before.tasks if t["task"] == decision.task), None) if before is not None else None
    if b_task is not None:
        changes[f"tbe_um[{decision.task}]"] = _change(b_task["tbe_um"], b_task.get("tbe_uncertainty_um") or 0.0,
                                                      decision.error_um, decision.uncertainty_um)
    against = (f"circular test {circular_test_id} (R {radius_mm:g} mm, F {feed_mm_min:g} mm/min): the measured "
               f"machining error of task {decision.task!r}")
    head = (f"TBE {decision.error_um:.2f} ± {decision.uncertainty_um:.2f} µm (k = 2) against {decision.tolerance_um:g} "
            f"µm, reversal {getattr(decision, 'spike', '') or '?'}")
    if b_task is not None:
        head += f"; {b_task['tbe_um']:.2f} µm estimated from the round trip before the repair"
    msg = (f"verified against the {against}: OK by the {decision.rule} rule; {head}" if passed else
           f"not verified against the {against}: {decision.state.value} by the {decision.rule} rule; {head}")
    return {"passed": passed, "rule": decision.rule, "against": against, "message": msg,
            "before": before.to_dict() if before is not None else None, "after": after, "changes": changes,
            "tasks_after": [dict(after["tasks"][0], passed=passed)]}


def restore_target_um(backlash_limit_um: float | None, warning_fraction: float) -> float | None:
    """The backlash the chain must be restored below for the axis to be OK again
    (core.tbe.repair_target: the binding task's limit times the warning fraction)."""
    target = repair_target(backlash_limit_um, warning_fraction)
    return target.restore_below_um if target is not None else None


# -- the managers' counts -----------------------------------------------------------------------
@dataclass(frozen=True)
class AxisMaintenanceSummary:
    """One axis over ``[start_s, end_s]`` (epoch seconds)."""

    axis_id: int
    start_s: float
    end_s: float
    repairs_called: int  # repairs recorded on an order the error opened
    repairs_other: int  # repairs recorded without an order (preventive, or on the staff's own call)
    orders_opened: int
    orders_verified: int
    orders_corrective: int
    orders_condition_based: int
    intervals_days: tuple[float, ...]  # between consecutive called repairs (and from the start to the first)
    alarm_to_verified_days: tuple[float, ...]  # order opened -> verified, per verified order
    fixed_interval_days: float
    fixed_interval_repairs: int  # what a fixed plan would have done over the same span

    @property
    def days(self) -> float:
        return (self.end_s - self.start_s) / 86400.0

    @property
    def comparable(self) -> bool:
        """Whether the history spans one whole period of the fixed plan: shorter, the plan
        has made no repair yet, and any called repair would read as a repair lost."""
        return self.days >= self.fixed_interval_days - 1e-9

    @property
    def repairs_saved(self) -> int | None:
        """Repairs the error-driven plan saved against the fixed one; None until :attr:`comparable`."""
        return self.fixed_interval_repairs - self.repairs_called if self.comparable else None

    def repairs_saved_note(self) -> str | None:
        """Why :attr:`repairs_saved` is empty, in words; None when it is not."""
        if self.comparable:
            return None
        return (f"nothing to compare yet: {self.days:.1f} days of history, the comparison with the fixed plan "
                f"needs at least {self.fixed_interval_days:g} (one period of it)")

    def to_dict(self) -> dict:
        iv, av = np.asarray(self.intervals_days, float), np.asarray(self.alarm_to_verified_days, float)
        return {
            "axis_id": self.axis_id, "history_days": _r(self.days, 2),
            "repairs_called_by_error": self.repairs_called, "repairs_other": self.repairs_other,
            "orders_opened": self.orders_opened, "orders_verified": self.orders_verified,
            "orders_corrective": self.orders_corrective, "orders_condition_based": self.orders_condition_based,
            "intervals_days": [_r(x, 2) for x in self.intervals_days],
            "interval_mean_days": _r(float(iv.mean()), 2) if iv.size else None,
            "interval_min_days": _r(float(iv.min()), 2) if iv.size else None,
            "alarm_to_verified_days": [_r(x, 3) for x in self.alarm_to_verified_days],
            "alarm_to_verified_mean_days": _r(float(av.mean()), 3) if av.size else None,
            "alarm_to_verified_max_days": _r(float(av.max()), 3) if av.size else None,
            "fixed_interval_days": self.fixed_interval_days,
            "fixed_interval_repairs": self.fixed_interval_repairs,
            "repairs_saved": self.repairs_saved, "repairs_saved_note": self.repairs_saved_note(),
        }


def fixed_interval_count(days: float, interval_days: float) -> int:
    """Repairs a fixed plan with period ``interval_days`` makes in ``days`` (one at each
    whole period; none at the start)."""
    if not (math.isfinite(interval_days) and interval_days > 0):
        raise InputError(f"fixed_interval_days (={interval_days!r}) must be > 0")
    return int(math.floor(max(days, 0.0) / interval_days + 1e-9))


def summarise_axis(axis_id: int, start_s: float, end_s: float, *, called_repairs_s: Sequence[float],
                   other_repairs: int, orders: Sequence[tuple[str, float, float | None]],
                   fixed_interval_days: float) -> AxisMaintenanceSummary:
    """``orders``: (kind, opened_at_s, verified_at_s or None) of the orders opened in the span."""
    if not end_s >= start_s:
        raise InputError(f"summary: end (={end_s}) must not be before start (={start_s})")
    rs = sorted(float(t) for t in called_repairs_s if start_s <= t <= end_s)
    marks = [start_s, *rs]
    intervals = tuple((b - a) / 86400.0 for a, b in zip(marks[:-1], marks[1:]))
    a2v = tuple((v - o) / 86400.0 for _, o, v in orders if v is not None)
    return AxisMaintenanceSummary(
        axis_id=axis_id, start_s=start_s, end_s=end_s, repairs_called=len(rs), repairs_other=int(other_repairs),
        orders_opened=len(orders), orders_verified=sum(1 for *_, v in orders if v is not None),
        orders_corrective=sum(1 for k, *_ in orders if k == "corrective"),
        orders_condition_based=sum(1 for k, *_ in orders if k == "condition_based"),
        intervals_days=intervals, alarm_to_verified_days=a2v, fixed_interval_days=float(fixed_interval_days),
        fixed_interval_repairs=fixed_interval_count((end_s - start_s) / 86400.0, fixed_interval_days),
    )


def fleet_totals(axes: Sequence[AxisMaintenanceSummary]) -> dict:
    """The fleet's sums and pooled statistics over every axis' summary."""
    iv = np.asarray([x for a in axes for x in a.intervals_days], float)
    av = np.asarray([x for a in axes for x in a.alarm_to_verified_days], float)
    called = sum(a.repairs_called for a in axes)
    fixed = sum(a.fixed_interval_repairs for a in axes)
    compared = [a for a in axes if a.comparable]  # an axis with a short history has nothing to compare yet
    short = len(axes) - len(compared)
    if not compared:
        saved, note = None, ("nothing to compare yet: no axis has a history of one fixed-plan period "
                             f"({axes[0].fixed_interval_days:g} days)" if axes else "nothing to compare: no axis")
    else:
        saved = sum(a.repairs_saved for a in compared)
        note = (f"over {len(compared)} of {len(axes)} axes: the others have less than one fixed-plan period "
                f"({axes[0].fixed_interval_days:g} days) of history" if short else None)
    return {
        "axes": len(axes), "repairs_called_by_error": called, "repairs_other": sum(a.repairs_other for a in axes),
        "orders_opened": sum(a.orders_opened for a in axes), "orders_verified": sum(a.orders_verified for a in axes),
        "interval_mean_days": _r(float(iv.mean()), 2) if iv.size else None,
        "alarm_to_verified_mean_days": _r(float(av.mean()), 3) if av.size else None,
        "alarm_to_verified_max_days": _r(float(av.max()), 3) if av.size else None,
        "fixed_interval_repairs": fixed, "repairs_saved": saved, "repairs_saved_note": note,
    }
