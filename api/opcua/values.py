"""What the OPC UA address space shows for one axis, read through the service's status
functions (never through api.rest): :func:`axis_values` runs on the event hub's consumer
thread (it may touch the database); the server's event loop only writes the result."""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timezone

from api.service.circles import axis_summary
from api.service.status import state_and_message
from storage.db import results_repo, session_scope

TBE_ALERT_KIND = "tbe_exceeded"  # the alert raised when a TBE passes its permissible error


@dataclass(frozen=True)
class TaskValue:
    name: str
    tbe_um: float | None
    tolerance_um: float
    state: str | None


@dataclass(frozen=True)
class AxisValues:
    """One axis as the status body shows it (REST field names in the comments)."""

    axis_id: int
    machine: str  # machine_name
    axis: str  # axis_name
    state: str  # state: OK, WARNING, ALARM, UNKNOWN
    message: str  # message
    measured_at: datetime | None  # measured_at
    backlash_mean_um: float | None  # backlash_mean_um
    backlash_mean_uncertainty_um: float | None  # backlash_mean_uncertainty_um (k = 2)
    backlash_limit_um: float | None  # backlash_limit_um
    restore_below_um: float | None  # restore_below_um: the repair target
    restore_below_explanation: str | None  # restore_below_explanation
    tasks: tuple[TaskValue, ...]  # tasks[].tbe_um per tasks[].name
    predicted_time: datetime | None  # prognosis.limit_date when there is one, else the active alert's raised_at
    prediction_source: str | None  # "prognosis" | "limit passed"
    circle: dict | None = None  # circular_test: the newest circular test (api.service.circles.axis_summary)


def _finite(x) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def prognosis_time(st) -> datetime | None:
    """The date the prognosis expects b̄ at the worst-case temperature to reach the backlash
    limit (the status body's ``prognosis.limit_date``); None when it gives none."""
    history = st.history
    when_s = history.prognosis.limit_date_s if history is not None else None
    return datetime.fromtimestamp(when_s, timezone.utc) if when_s is not None else None


def _limit_passed_at(service, axis_id: int) -> datetime | None:
    with session_scope(service.factory) as s:
        _, alerts = results_repo.list_alerts(s, "active", axis_id=axis_id, limit=20)
    times = [a.raised_at for a in alerts if a.kind == TBE_ALERT_KIND]
    return min(times) if times else None


def axis_values(service, axis_id: int) -> AxisValues:
    st = service.status.get(axis_id)
    state, message = state_and_message(st)
    latest, d = st.latest, st.decision
    rt = latest.round_trip if latest is not None else None
    assessed = {x.task.name: x for x in d.assessments} if d is not None else {}
    tasks = tuple(
        TaskValue(t.name, _finite(assessed[t.name].tbe_um) if t.name in assessed else None, t.tolerance_um,
                  assessed[t.name].state.value if t.name in assessed else None)
        for t in st.axis.tasks
    )  # fmt: skip
    target = d.repair_target if d is not None else None
    when, source = prognosis_time(st), "prognosis"
    if when is None and st.active_alert_id is not None:
        when, source = _limit_passed_at(service, axis_id), "limit passed"
    return AxisValues(
        axis_id=axis_id, machine=st.axis.machine_name, axis=st.axis.name, state=state, message=message,
        measured_at=latest.measured_at if latest is not None else None,
        backlash_mean_um=_finite(rt.backlash.mean_um) if rt is not None else None,
        backlash_mean_uncertainty_um=_finite(rt.backlash_mean_uncertainty_um) if rt is not None and rt.budgets else None,
        backlash_limit_um=_finite(d.backlash_limit_um) if d is not None else None,
        restore_below_um=target.restore_below_um if target is not None else None,
        restore_below_explanation=target.explanation if target is not None else None,
        tasks=tasks, predicted_time=when, prediction_source=source if when is not None else None,
        circle=axis_summary(st.circle, st.axis.name),
    )  # fmt: skip
