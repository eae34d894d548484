"""The current condition of an axis, as the MES and the maintenance team see it.

Built from the newest good measurement and the axis' *current* machining tasks (so a
task changed through the API is reflected at once), plus the backlash normalised to
20 °C with the thermal model fitted on the axis' history (``core.history``).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from datetime import datetime


from api.service.prognosis import HistoryAnswers, HistoryMemo, history_answers
from core.errors import MebmError
from core.history import TemperatureModel
from core.tbe import AxisDecision, decide
from storage.db import (
    AxisRecord,
    CircularTestRecord,
    ResultRecord,
    WorkOrderRecord,
    circles_repo,
    config_repo,
    maintenance_repo,
    results_repo,
    session_scope,
)


@dataclass(frozen=True)
class AxisStatus:
    axis: AxisRecord
    latest: ResultRecord | None
    decision: AxisDecision | None
    backlash_mean_20c_um: float | None
    thermal_beta_um_per_k: float | None
    active_alert_id: int | None
    last_cycle_status: str | None
    last_cycle_at: datetime | None
    last_failure_reason: str | None
    decision_error: str | None = None
    last_raw_run_lost: str | None = None  # why the last finished cycle's raw run was lost
    history: HistoryAnswers | None = None  # prognosis and history clearance (api.service.prognosis)
    history_error: str | None = None
    work_order: WorkOrderRecord | None = None  # the axis' active maintenance order
    last_cycle_uuid: str | None = None
    circle: CircularTestRecord | None = None  # the newest circular test of a plane with the axis (no samples)


def with_held(st: AxisStatus, held: dict | None) -> AxisStatus:
    """``st`` with its last cycle as finished when it waits in the spool (a full disk, a
    database outage; ``held``: CycleExecutor.held): failed with its reason until the spool
    stores it (an ok one is then stored ok), never running."""
    if not held or st.last_cycle_status not in ("queued", "running") or st.last_cycle_uuid not in held:
        return st
    kept_status, kept_reason = held[st.last_cycle_uuid]
    return replace(st, last_cycle_status="failed" if kept_status == "ok" else kept_status,
                   last_failure_reason=kept_reason or "finished; waiting in the spool to be stored")


def compute_status(s, axis_id: int, history_memo: HistoryMemo | None = None) -> AxisStatus:
    axis = config_repo.get_axis(s, axis_id)
    latest = results_repo.latest_result(s, axis_id)
    decision = None
    decision_error = None
    b20 = beta = None
    if latest is not None:
        b = latest.round_trip.backlash.mean_um
        if axis.tasks:
            try:
                u = latest.round_trip.backlash_mean_uncertainty_um if latest.round_trip.budgets else 0.0
                decision = decide(max(b, 0.0), axis.tasks, warning_fraction=axis.settings.warning_fraction,
                                  backlash_uncertainty_um=u, rule=axis.settings.decision_rule)
            except MebmError as exc:
                decision_error = str(exc)
        sums = results_repo.backlash_history(s, axis_id)
        if sums.n >= 3 and sums.x_max - sums.x_min >= 1.0 and latest.temperature_c is not None:
            try:
                model = TemperatureModel().fit_sums(sums)
                b20 = float(model.normalise_um(b, latest.temperature_c))
                beta = model.beta_um_per_k_
            except MebmError:
                pass
    history = history_error = None
    try:
        history = history_answers(s, axis, latest, sums.n if latest is not None else 0, history_memo)
    except MebmError as exc:  # the status stands without its prognosis
        history_error = str(exc)
    _, alerts = results_repo.list_alerts(s, "active", axis_id=axis_id, limit=1)
    _, last = results_repo.list_measurements(s, axis_id, limit=1)
    last_final = next((c for c in last if c.status not in ("queued", "running")), None)
    return AxisStatus(
        axis=axis, latest=latest, decision=decision, backlash_mean_20c_um=b20, thermal_beta_um_per_k=beta,
        active_alert_id=alerts[0].id if alerts else None,
        last_cycle_status=last[0].status if last else None, last_cycle_uuid=last[0].uuid if last else None,
        last_cycle_at=(last[0].finished_at or last[0].requested_at) if last else None,
        last_failure_reason=last_final.failure_reason if last_final is not None else None,
        decision_error=decision_error,
        last_raw_run_lost=last_final.raw_run_lost if last_final is not None else None,
        history=history, history_error=history_error, work_order=maintenance_repo.active_order(s, axis_id),
        circle=circles_repo.latest_circular_test(s, axis_id),
    )


def state_and_message(s: AxisStatus) -> tuple[str, str]:
    """The axis' state (OK, WARNING, ALARM, UNKNOWN) and the sentence that explains it, as
    every interface shows them (REST status body, OPC UA)."""
    d, latest = s.decision, s.latest
    b = latest.round_trip.backlash.mean_um if latest is not None else None
    if latest is None:
        message = "no good measurement yet"
        if s.last_failure_reason:
            message += f"; last cycle failed: {s.last_failure_reason}"
        return "UNKNOWN", message
    if d is None and s.decision_error:
        return "UNKNOWN", f"mean backlash {b:.1f} µm; the TBE model cannot evaluate it: {s.decision_error}"
    if d is None:
        return "UNKNOWN", f"mean backlash {b:.1f} µm; no machining task configured (PUT /axes/{s.axis.id}/tasks)"
    return d.state.value, d.message()


class StatusCache:
    """Status per axis, recomputed when a cycle is saved or the axis changes (this
    process invalidates it), and at most ``ttl_s`` old otherwise (changes made by
    another process, e.g. a second API process on the same database, show up then).
    The age of the measurement is computed per request, not cached."""

    def __init__(self, factory, ttl_s: float = 30.0):
        self.factory = factory
        self.ttl_s = ttl_s
        self._cache: dict[int, tuple[float, AxisStatus]] = {}
        self._locks: dict[int, threading.Lock] = {}
        self._lock = threading.Lock()
        self._history_memo = HistoryMemo()  # the prognosis fit, redone only when its inputs change
        # per axis, bumped by every invalidation and publication: a recomputation that
        # started before one is returned to its caller but not cached
        self._gen: dict[int, int] = {}
        self._epoch = 0  # bumped by invalidating every axis
        self.held = None  # () -> uuid -> (status, reason) of finished cycles not stored yet (CycleExecutor.held)

    def fresh(self, axis_id: int) -> AxisStatus | None:
        """The cached status if it is recent enough (no database access)."""
        hit = self._cache.get(axis_id)
        if hit is not None and time.monotonic() - hit[0] < self.ttl_s:
            return hit[1]
        return None

    def stale(self, axis_id: int) -> AxisStatus | None:
        """The cached status however old (None after an invalidation)."""
        hit = self._cache.get(axis_id)
        return None if hit is None else hit[1]

    def refresh_in_background(self, axis_id: int) -> None:
        """Recompute in a thread unless a recomputation is already under way."""
        lock = self._axis_lock(axis_id)
        if lock.locked():
            return

        def work():
            try:
                self.get(axis_id)
            except Exception:  # noqa: BLE001 - the next request recomputes and reports it
                pass

        threading.Thread(target=work, name=f"status-{axis_id}", daemon=True).start()

    def get(self, axis_id: int) -> AxisStatus:
        hit = self.fresh(axis_id)
        if hit is not None:
            return hit
        with self._axis_lock(axis_id):  # one recomputation per axis, not one per waiting request
            hit = self.fresh(axis_id)
            if hit is not None:
                return hit
            now = time.monotonic()
            gen = self._stamp(axis_id)
            with session_scope(self.factory) as s:
                st = with_held(compute_status(s, axis_id, self._history_memo), self._held())
            with self._lock:
                if self._stamp(axis_id) == gen:  # not if a newer status was published meanwhile
                    self._cache[axis_id] = (now, st)
            return st

    def prepare(self, s, axis_id: int):
        """The status of ``axis_id`` computed in the transaction ``s`` that stores a cycle, so
        that no poller has to recompute it after the commit (otherwise the first poll after
        each cycle would pay for the recomputation). Computed before the commit, it already
        contains the new measurement. Returns the function the caller calls once the
        commit is done, which publishes it. Until then pollers get the cached status: the
        window in which a client may see the new measurement elsewhere but not yet in the
        status is the few statements between the commit and the publication, not a
        recomputation. If the transaction rolls back, the function is not called and
        nothing of it stays (the history memo's new entry included); if the axis' status
        is invalidated in between (e.g. its tasks changed), the publication is dropped and
        the next use recomputes. Errors propagate (the caller keeps the cycle and
        invalidates instead)."""
        memo = self._history_memo.staged()
        with self._lock:
            gen = self._stamp(axis_id)
        now = time.monotonic()
        st = with_held(compute_status(s, axis_id, memo), self._held())

        def publish() -> None:
            with self._lock:
                if self._stamp(axis_id) != gen:  # invalidated since (the entry was dropped then): recomputed on use
                    return
                memo.apply()
                self._gen[axis_id] = gen[1] + 1  # a computation started before the commit is not kept
                self._cache[axis_id] = (now, st)

        return publish

    def _held(self) -> dict | None:
        return None if self.held is None else self.held()

    def _stamp(self, axis_id: int) -> tuple[int, int]:
        return self._epoch, self._gen.get(axis_id, 0)

    def _axis_lock(self, axis_id: int) -> threading.Lock:
        with self._lock:
            return self._locks.setdefault(axis_id, threading.Lock())

    def invalidate(self, axis_id: int | None = None) -> None:
        with self._lock:
            if axis_id is None:
                self._cache.clear()
                self._epoch += 1
            else:
                self._cache.pop(axis_id, None)
                self._gen[axis_id] = self._gen.get(axis_id, 0) + 1


