"""What the OPC UA address space shows for one axis, read through the service's status
functions (never through api.rest): :func:`axis_values` runs on the event hub's consumer
thread (it may touch the database); the server's event loop only writes the result."""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from datetime import datetime, timezone

from api.service.status import state_and_message
from storage.db import results_repo, session_scope

log = logging.getLogger("mebm.opcua")
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
    tasks: tuple[TaskValue, ...]  # tasks[].tbe_um per tasks[].name
    predicted_time: datetime | None  # prognosis (when present), else the active alert's raised_at
    prediction_source: str | None  # "prognosis" | "limit passed"


def _finite(x) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _as_time(v) -> datetime | None:
    if isinstance(v, datetime):
        return v if v.tzinfo else v.replace(tzinfo=timezone.utc)
    if isinstance(v, str):
        try:
            return _as_time(datetime.fromisoformat(v.replace("Z", "+00:00")))
        except ValueError:
            return None
    return None


# The prognosis is being added to the status body in parallel (issue 16): its shape is not
# fixed yet, so take the first date-time of these names, from a mapping or an object.
PROGNOSIS_TIME_KEYS = ("limit_reached_at", "predicted_time", "predicted_at", "limit_at", "date", "at")


def prognosis_time(p) -> datetime | None:
    """The predicted date the backlash limit is reached, from a prognosis (dict, object,
    date-time or ISO string); None when it gives none."""
    if p is None:
        return None
    direct = _as_time(p)
    if direct is not None:
        return direct
    get = p.get if isinstance(p, dict) else (lambda k: getattr(p, k, None))
    for key in PROGNOSIS_TIME_KEYS:
        t = _as_time(get(key))
        if t is not None:
            return t
    if isinstance(p, dict):  # any other *_at field
        for key, v in p.items():
            if key.endswith("_at") and _as_time(v) is not None:
                return _as_time(v)
    return None


def _prognosis(service, st) -> datetime | None:
    t = prognosis_time(getattr(st, "prognosis", None))
    if t is not None:
        return t
    try:
        doc = service.status_document(st.axis.id)  # the REST body, when a REST app is set up
    except Exception:  # noqa: BLE001 - the prognosis is optional; the alert date stands in
        log.debug("status document of axis %s unavailable", st.axis.id, exc_info=True)
        return None
    if doc is None:
        return None
    return prognosis_time(json.loads(doc).get("prognosis"))


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
    when, source = _prognosis(service, st), "prognosis"
    if when is None and st.active_alert_id is not None:
        when, source = _limit_passed_at(service, axis_id), "limit passed"
    return AxisValues(
        axis_id=axis_id, machine=st.axis.machine_name, axis=st.axis.name, state=state, message=message,
        measured_at=latest.measured_at if latest is not None else None,
        backlash_mean_um=_finite(rt.backlash.mean_um) if rt is not None else None,
        backlash_mean_uncertainty_um=_finite(rt.backlash_mean_uncertainty_um) if rt is not None and rt.budgets else None,
        backlash_limit_um=_finite(d.backlash_limit_um) if d is not None else None,
        tasks=tasks, predicted_time=when, prediction_source=source if when is not None else None,
    )  # fmt: skip
