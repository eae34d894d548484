"""What the dashboard's pages show, assembled from the service's functions (the status
cache, ``api.service.status.verdict``, the storage repositories): plain dataclasses the
templates format. No query of its own."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from datetime import datetime, timedelta

from api.service.status import AxisStatus, state_and_message
from core.criteria import criterion_label
from storage.db import AlertRecord, config_repo, results_repo, utcnow

URGENCY = {"ALARM": 0, "WARNING": 1, "UNKNOWN": 2, "OK": 3}
RANGES = {"30d": 30, "90d": 90, "1y": 365, "all": None}  # history range selector: days back


@dataclass(frozen=True)
class BudgetView:
    """One uncertainty budget as the axis page lists it: each component's standard
    uncertainty (µm) and note, u_c and U (k = 2)."""

    key: str
    label: str
    components: tuple[tuple[str, float, str], ...]  # name, standard µm, note
    combined_um: float
    expanded_um: float
    coverage_factor: float


def _budget_label(key: str) -> str:
    if key == "backlash_mean":
        return "Mean backlash b̄"
    if key == "backlash_mean_20c":
        return "Mean backlash b̄ referred to 20 °C"
    stroke, _, criterion = key.partition(".")
    return f"{criterion_label(criterion)}, {stroke} stroke"


def budget_views(rt) -> tuple[BudgetView, ...]:
    """b̄'s budgets first, then the positive stroke's lead criteria (the ones the page shows)."""
    if rt is None or not rt.budgets:
        return ()
    keys = [k for k in ("backlash_mean", "backlash_mean_20c") if k in rt.budgets]
    keys += [k for k in rt.budgets if k.startswith("positive.")]
    return tuple(BudgetView(k, _budget_label(k), tuple((c.name, c.standard_um, c.note) for c in b.components),
                            b.combined_um, b.expanded_um, b.coverage_factor)
                 for k in keys for b in (rt.budgets[k],))


@dataclass(frozen=True)
class AxisRow:
    axis_id: int
    machine_name: str
    axis_name: str
    state: str
    message: str
    backlash_mean_um: float | None
    backlash_u_um: float | None  # expanded, k = 2
    binding_task: str | None
    tbe_um: float | None
    tbe_u_um: float | None
    tolerance_um: float | None
    warning_um: float | None
    backlash_limit_um: float | None
    temperature_c: float | None
    age_s: float | None
    next_run_at: datetime | None
    active_alert_id: int | None
    last_cycle_status: str | None
    last_failure_reason: str | None
    restore_below_um: float | None = None  # the repair target: the warning level in backlash
    restore_below_explanation: str | None = None
    budgets: tuple[BudgetView, ...] = ()  # the latest measurement's uncertainty budgets

    @property
    def utilisation(self) -> float:
        """TBE / tolerance of the binding task (0 when unknown)."""
        if self.tbe_um is None or not self.tolerance_um:
            return 0.0
        return self.tbe_um / self.tolerance_um

    @property
    def urgency(self) -> tuple:
        return (URGENCY.get(self.state, 2), -self.utilisation, self.machine_name, self.axis_name)


def axis_row(st: AxisStatus, next_run_at: datetime | None, now: datetime) -> AxisRow:
    state, message = state_and_message(st)
    latest, d = st.latest, st.decision
    rt = latest.round_trip if latest else None
    binding = next((a for a in d.assessments if a.task.name == d.binding_task), None) if d else None
    limit = d.backlash_limit_um if d is not None and math.isfinite(d.backlash_limit_um) else None
    target = d.repair_target if d is not None else None
    return AxisRow(
        axis_id=st.axis.id, machine_name=st.axis.machine_name, axis_name=st.axis.name, state=state, message=message,
        backlash_mean_um=rt.backlash.mean_um if rt else None,
        backlash_u_um=rt.backlash_mean_uncertainty_um if rt is not None and rt.budgets else None,
        binding_task=d.binding_task if d else None,
        tbe_um=binding.tbe_um if binding else None, tbe_u_um=binding.tbe_uncertainty_um if binding else None,
        tolerance_um=binding.task.tolerance_um if binding else None,
        warning_um=d.warning_fraction * binding.task.tolerance_um if binding else None,
        backlash_limit_um=limit, temperature_c=latest.temperature_c if latest else None,
        age_s=(now - latest.measured_at).total_seconds() if latest else None, next_run_at=next_run_at,
        active_alert_id=st.active_alert_id, last_cycle_status=st.last_cycle_status,
        last_failure_reason=st.last_failure_reason,
        restore_below_um=target.restore_below_um if target is not None else None,
        restore_below_explanation=target.explanation if target is not None else None,
        budgets=budget_views(rt),
    )


@dataclass(frozen=True)
class Fleet:
    rows: list[AxisRow]
    alerts: list[tuple[AlertRecord, str]]  # active alert, "machine axis"
    counts: dict[str, int]
    now: datetime


def fleet(svc, s) -> Fleet:
    now = utcnow()
    axes = config_repo.list_axes(s)
    rows = sorted((axis_row(svc.status.get(a.id), svc.scheduler.next_run(a.id), now) for a in axes),
                  key=lambda r: r.urgency)
    names = {a.id: f"{a.machine_name} {a.name}" for a in axes}
    _, alerts = results_repo.list_alerts(s, "active", limit=100)
    counts = {k: sum(1 for r in rows if r.state == k) for k in ("ALARM", "WARNING", "OK", "UNKNOWN")}
    return Fleet(rows, [(a, names.get(a.axis_id, f"axis {a.axis_id}")) for a in alerts], counts, now)


def since_of(range_: str, now: datetime | None = None) -> datetime | None:
    days = RANGES.get(range_, 90)
    return None if days is None else (now or utcnow()) - timedelta(days=days)


FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")  # a cell a spreadsheet would run as a formula


def spreadsheet_text(cell: str) -> str:
    """A text cell a spreadsheet shows as text: one that would start a formula gets a
    leading ``'`` (OWASP's CSV injection advice); numbers are written by us and left as they are."""
    return "'" + cell if cell.startswith(FORMULA_STARTS) else cell


def history_csv(s, axis_id: int, since: datetime | None) -> str:
    """Every good measurement of the range (not downsampled), one row each, units in the
    header; written by the csv module (a quote in a task name is doubled), every text
    cell neutralised for spreadsheets (:func:`spreadsheet_text`)."""
    tr = results_repo.trend(s, axis_id, since=since, max_points=None).series
    tbe: dict[datetime, list[str]] = {}
    for t, task, v, tol in results_repo.tbe_history(s, axis_id, since=since, max_points=None):
        tbe.setdefault(t, []).append(f"{task}={v:.3f}/{tol:g}")
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(["measurement_id", "measured_at_utc", "backlash_mean_um", "temperature_c", "utility_day",
                  "e_p_um_per_1000mm", "v_u_um", "v_300_um", "v_2pi_um", "tbe_um_per_task_over_tolerance_um"])

    def f(v, nd=3):
        return "" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{nd}f}"

    for i in range(len(tr.measured_at)):
        t = tr.measured_at[i]
        out.writerow([
            str(tr.measurement_id[i]), t.strftime("%Y-%m-%dT%H:%M:%SZ"), f(tr.backlash_mean_um[i]),
            f(tr.temperature_c[i], 2), f(tr.utility_day[i], 3), f(tr.e_p_um_per_1000mm[i]), f(tr.v_u_um[i]),
            f(tr.v_300_um[i]), f(tr.v_2pi_um[i]), spreadsheet_text(" ".join(tbe.get(t, []))),
        ])
    return buf.getvalue()
