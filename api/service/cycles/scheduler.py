"""Per-axis schedules and the per-axis cycle queue.

- Each axis has one worker thread: cycles of an axis never overlap; a manual trigger
  queues behind a running cycle. At most one manual request waits: asking again raises
  :class:`WaitingCycleError` (the database's partial unique index makes the rule atomic,
  also across processes).
- APScheduler (3.x, in-memory) is only the clock: an interval or cron job per axis,
  built from the schedule stored in the database, ``coalesce=True`` and
  ``max_instances=1`` so a missed run runs once. A scheduled request while the axis'
  previous scheduled cycle is still queued or running is skipped, not stacked.
- At start-up an axis whose last scheduled cycle is older than one period gets one
  catch-up cycle (not one per missed period).
"""

from __future__ import annotations

import logging
import queue
import threading
import uuid as uuidlib
from datetime import datetime, timedelta, timezone

from apscheduler.schedulers.background import BackgroundScheduler

from api.service.config.schedule import make_trigger
from api.service.cycles.executor import CycleExecutor, CycleRequest
from storage.db import (
    AxisRecord,
    CycleRecord,
    Schedule,
    StorageError,
    WaitingCycleError,
    results_repo,
    session_scope,
    utcnow,
)

log = logging.getLogger("mebm.scheduler")
STOP = object()  # put on an axis' queue, ends its worker thread (the fleet scheduler's too)


def missed_since(schedule: Schedule, last: datetime | None, now: datetime) -> bool:
    """Whether a scheduled run fell due after ``last`` and before ``now``."""
    if not schedule.active or last is None:
        return False
    if schedule.interval_s is not None:
        return now - last >= timedelta(seconds=schedule.interval_s)
    nxt = make_trigger(schedule).get_next_fire_time(None, last + timedelta(seconds=1))
    return nxt is not None and nxt <= now


class AxisWorker(threading.Thread):
    """One thread per axis running its queued cycles one after another."""

    def __init__(self, axis_id: int, executor: CycleExecutor):
        super().__init__(name=f"axis-{axis_id}", daemon=True)
        self.axis_id = axis_id
        self.executor = executor
        self.queue: queue.Queue = queue.Queue()
        self.lock = threading.Lock()
        self.waiting: dict[str, CycleRequest] = {}
        self.running: CycleRequest | None = None

    def run(self) -> None:
        while True:
            req = self.queue.get()
            if req is STOP:
                return
            with self.lock:
                self.waiting.pop(req.uuid, None)
                self.running = req
            try:
                self.executor.execute(req)
            except Exception:  # noqa: BLE001 - the schedule goes on
                log.exception("cycle %s on axis %s could not be stored", req.uuid, self.axis_id)
            finally:
                with self.lock:
                    self.running = None
                self.queue.task_done()

    def busy_with(self, triggers: tuple[str, ...]) -> CycleRequest | None:
        with self.lock:
            for r in [self.running, *self.waiting.values()]:
                if r is not None and r.trigger in triggers:
                    return r
        return None

    def waiting_manual(self) -> CycleRequest | None:
        with self.lock:
            return next((r for r in self.waiting.values() if r.trigger == "manual"), None)


class CycleScheduler:
    """Owns the per-axis workers and the APScheduler clock."""

    def __init__(self, executor: CycleExecutor, factory):
        self.executor = executor
        self.factory = factory
        self.workers: dict[int, AxisWorker] = {}
        # A job that starts late (a busy host, a long pause of the process) still runs, once:
        # APScheduler's default misfire grace of 1 s would skip it with a "was missed"
        # warning, which for the one-shot verification of a repair (maintenance) means it
        # never runs, and for the spool retry that held readings wait another period.
        self.clock = BackgroundScheduler(
            timezone=timezone.utc, job_defaults={"coalesce": True, "max_instances": 1, "misfire_grace_time": None}
        )
        self._lock = threading.Lock()
        self._started = False

    def _worker(self, axis_id: int) -> AxisWorker:
        with self._lock:
            w = self.workers.get(axis_id)
            if w is None:
                w = self.workers[axis_id] = AxisWorker(axis_id, self.executor)
                w.start()
            return w

    def request(self, axis_id: int, trigger: str, requested_by: str | None = None) -> CycleRecord | CycleRequest | None:
        """Queue a cycle. Returns the queued cycle (stored, or only in memory during a
        database outage), or None when a scheduled request is skipped because the
        previous scheduled cycle of the axis has not finished."""
        w = self._worker(axis_id)
        if trigger in ("schedule", "catch_up") and w.busy_with(("schedule", "catch_up")) is not None:
            log.info("axis %s: scheduled cycle skipped, the previous one is still queued or running", axis_id)
            return None
        if trigger == "manual":
            waiting = w.waiting_manual()
            if waiting is not None:
                raise WaitingCycleError(axis_id, self._stored(waiting) or waiting)
        req = CycleRequest(uuid=str(uuidlib.uuid4()), axis_id=axis_id, trigger=trigger, requested_at=utcnow(),
                           requested_by=requested_by)
        record = None
        try:
            with session_scope(self.factory) as s:
                # a manual one is refused here, atomically, if another waits (WaitingCycleError)
                record = results_repo.queue_cycle(s, axis_id, req.uuid, trigger, requested_by=requested_by,
                                                  requested_at=req.requested_at)
        except StorageError as exc:
            if trigger == "manual":
                raise
            log.warning("axis %s: cycle queued without the database (%s)", axis_id, exc)
        with w.lock:
            w.waiting[req.uuid] = req
        w.queue.put(req)
        return record or req

    def _stored(self, req: CycleRequest) -> CycleRecord | None:
        try:
            with session_scope(self.factory) as s:
                total, rows = results_repo.list_measurements(s, req.axis_id, status="queued", limit=20)
            return next((r for r in rows if r.uuid == req.uuid), None)
        except StorageError:
            return None

    # -- schedules -----------------------------------------------------------------------------
    def schedule(self, axis: AxisRecord) -> None:
        """(Re)install the axis' schedule job."""
        job_id = f"axis-{axis.id}"
        self.executor.remember(axis)
        self._worker(axis.id)
        if self.clock.get_job(job_id) is not None:
            self.clock.remove_job(job_id)
        sch = axis.settings.schedule
        if not sch.active:
            return
        self.clock.add_job(self.request, make_trigger(sch), args=(axis.id, "schedule"), id=job_id,
                           coalesce=True, max_instances=1, misfire_grace_time=None, replace_existing=True)

    def catch_up(self, axis: AxisRecord, now: datetime | None = None) -> bool:
        """Queue one catch-up cycle when a scheduled run was missed while the service was down."""
        now = now or utcnow()
        with session_scope(self.factory) as s:
            last = results_repo.last_cycle_at(s, axis.id)
        if missed_since(axis.settings.schedule, last, now):
            self.request(axis.id, "catch_up")
            return True
        return False

    def next_run(self, axis_id: int) -> datetime | None:
        job = self.clock.get_job(f"axis-{axis_id}")
        return None if job is None else job.next_run_time

    def start(self) -> None:
        if not self._started:
            self.clock.start()
            self._started = True

    def stop(self, wait_s: float = 5.0) -> None:
        if self._started:
            self.clock.shutdown(wait=False)
            self._started = False
        for w in self.workers.values():
            w.queue.put(STOP)
        for w in self.workers.values():
            w.join(wait_s)

    def idle(self, timeout_s: float = 30.0) -> bool:
        """Wait until no cycle is queued or running (tests); bounded by ``timeout_s``."""
        import time

        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(w.queue.unfinished_tasks == 0 for w in list(self.workers.values())):
                return True
            time.sleep(0.02)
        return False
