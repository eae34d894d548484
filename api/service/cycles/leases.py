"""The fleet scheduler: several ``mebm serve`` workers on one PostgreSQL database.

Each worker runs one loop, every ``WorkerSettings.period_s`` (2 s by default):

1. **heartbeat**: its row's ``heartbeat_at`` and its leases' ``expires_at`` move to now
   (+ ``lease_s``), in database time; a lease found expired is lost (another worker may
   have taken the axis) and the axis leaves this worker's plan;
2. **claim**: the axes it may run (``[worker] axes`` patterns) whose lease is free or
   expired, up to its fair share of the live workers (``FOR UPDATE SKIP LOCKED``); an axis
   that stays free longer than two periods is taken beyond the share, so none is left
   unmeasured. Taking an axis from a worker whose lease expired marks the cycle it left
   ``interrupted`` (``storage.db.leases.take_over``). Above its share, a worker releases
   its idle axes so a worker that joins gets some;
3. **run**: the queued cycles of its axes (a manual trigger stored by any worker's API)
   go to the axis' thread, and every scheduled cycle that fell due is queued with its due
   time (the schedule goes on from the axis' last due time in the database, so an axis
   taken over catches up at once, once).

A cycle starts only if :func:`storage.db.leases.claim_cycle` moves it from queued to
running while the worker holds the axis' lease: one running cycle per axis, fleet-wide,
and a manual trigger runs exactly once. Without the database a worker starts no cycle.
The per-axis threads and the cycle executor are those of :mod:`api.service.cycles.scheduler`.
"""

from __future__ import annotations

import fnmatch
import logging
import math
import os
import queue
import socket
import threading
import time
import uuid as uuidlib
from datetime import datetime, timedelta, timezone

from api.service.config.settings import SIM_CONTROLLER, WorkerSettings
from api.service.cycles.executor import CycleExecutor, CycleRequest
from api.service.config.schedule import make_trigger
from api.service.cycles.scheduler import STOP, CycleScheduler
from storage.db import AxisRecord, CycleRecord, StorageError, config_repo, results_repo, session_scope, utcnow
from storage.db import leases

log = logging.getLogger("mebm.fleet")


def axis_key(axis: AxisRecord) -> str:
    return f"{axis.machine_name}/{axis.name}"


def matches(patterns: tuple[str, ...] | None, axis: AxisRecord) -> bool:
    """Whether a worker pinned to ``patterns`` (None: any) may run the axis."""
    return patterns is None or any(fnmatch.fnmatchcase(axis_key(axis), p) for p in patterns)


def fair_share(me: str, workers: list[tuple[str, tuple[str, ...] | None]], axes: list[AxisRecord]) -> int:
    """How many axes this worker should hold: each axis counts 1/n for each of the n live
    workers that may run it (so pinned workers get their own axes, and the rest is split)."""
    if not any(w == me for w, _ in workers):
        workers = [*workers, (me, None)]
    mine = dict(workers)[me]
    share = 0.0
    for a in axes:
        if not matches(mine, a):
            continue
        share += 1.0 / max(1, sum(1 for _, p in workers if matches(p, a)))
    return math.ceil(share - 1e-9)


def latest_due(axis: AxisRecord, last: datetime | None, now: datetime, catch_up: bool = True) -> datetime | None:
    """The due time of the axis' next scheduled cycle: after ``last`` (its last due time),
    and when several fell due since, the latest of them (missed ones run once, coalesced;
    with ``catch_up`` False, the next one after now). None: no active schedule. Never
    measured: now on the simulated controller (the demo shows a measurement at once), else
    one period from now, as a single worker does."""
    sch = axis.settings.schedule
    if not sch.active:
        return None
    if last is None:
        return now if axis.settings.controller_url == SIM_CONTROLLER else _after(axis, now)
    due = _latest(axis, last, now)
    if due is not None and due <= now and not catch_up and due != _after(axis, last):
        return _after(axis, now)
    return due


def _after(axis: AxisRecord, t: datetime) -> datetime | None:
    sch = axis.settings.schedule
    if sch.interval_s is not None:
        return t + timedelta(seconds=sch.interval_s)
    return make_trigger(sch).get_next_fire_time(None, t + timedelta(microseconds=1))


def _latest(axis: AxisRecord, last: datetime, now: datetime) -> datetime | None:
    sch = axis.settings.schedule
    if sch.interval_s is not None:
        step = timedelta(seconds=sch.interval_s)
        nxt = last + step
        if nxt <= now:
            nxt = last + step * int((now - last) / step)
        return nxt
    trig = make_trigger(sch)
    nxt = trig.get_next_fire_time(None, last + timedelta(microseconds=1))
    for _ in range(10000):  # coalesce: the latest fire time not after now
        after = trig.get_next_fire_time(nxt, nxt + timedelta(microseconds=1)) if nxt is not None else None
        if nxt is None or after is None or after > now:
            break
        nxt = after
    return nxt


_IN_THIS_PROCESS: set[str] = set()  # ids of the workers running in this process (tests run two)


def _alive(worker_id: str, pid: int) -> bool:
    """Whether the worker's process still runs on this host. Our own pid in the row of a
    worker not of this process is a predecessor's (a restarted container's pid 1)."""
    if pid == os.getpid():
        return worker_id in _IN_THIS_PROCESS
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # exists, another user's
    return True


class FleetScheduler(CycleScheduler):
    """A worker of a fleet. ``active=False`` (``serve --no-scheduler``): no loop, no
    leases; a manual trigger is only stored, for the axis' owner to run."""

    def __init__(self, executor: CycleExecutor, factory, worker: WorkerSettings, *, active: bool = True,
                 catch_up: bool = True):
        super().__init__(executor, factory)
        self.catch_up_missed = catch_up
        self.closed = 0  # cycles left by dead workers that this one closed (interrupted, cancelled)
        self.settings = worker
        self.active = active
        self.id = str(uuidlib.uuid4())
        self.host = socket.gethostname()
        self.name = worker.name or f"{self.host}-{os.getpid()}"
        self.lease_s = worker.lease_s
        self.period_s = worker.period_s
        self.held: set[int] = set()
        self.next_due: dict[int, datetime] = {}
        self.takeovers = 0
        self._axes: dict[int, AxisRecord] = {}
        self._pushed: set[str] = set()
        self._catch_up: set[int] = set()
        self._plan_lock = threading.RLock()
        self._halt = threading.Event()
        self._loop: threading.Thread | None = None
        self._last_renewed = time.monotonic()
        self._db_offset = timedelta(0)  # database clock minus this host's
        self._registered = False
        if active:
            executor.claim = self._claim

    # -- the life of a worker ------------------------------------------------------------------
    def register(self) -> None:
        """Insert this worker's row (refused if a live worker has its name)."""
        with session_scope(self.factory) as s:
            for other, pid in leases.local_workers(s, self.host, self.id):
                if not _alive(other, pid):  # a worker of this host killed earlier: no need to wait for its leases
                    n = leases.expire_worker(s, other)
                    if n:
                        log.warning("worker %s (pid %s on this host) is gone: its %d lease(s) end now", other, pid, n)
            leases.register_worker(s, self.id, self.name, self.host, os.getpid(), self.settings.axes, self.lease_s)
        self._registered = True
        _IN_THIS_PROCESS.add(self.id)
        log.info("worker %r (%s) joined the fleet: axes %s, lease %.0f s", self.name, self.id,
                 ", ".join(self.settings.axes) if self.settings.axes else "any", self.lease_s)

    def start(self) -> None:
        super().start()  # the clock: retention and spool jobs
        if self.active and self._loop is None:
            if not self._registered:
                self.register()
            self.tick()  # the first claims before the API answers
            self._loop = threading.Thread(target=self._run, name="fleet", daemon=True)
            self._loop.start()

    def stop(self, wait_s: float = 5.0) -> None:
        """Stop planning, drop what waits in the axes' queues (stored as queued: the manual
        ones stay for the next owner), give the running cycles ``wait_s`` in all, then
        free the leases and close what is left (``stop_worker``)."""
        self._halt.set()
        if self._loop is not None:
            self._loop.join(wait_s + self.period_s)
            self._loop = None
        if self._started:
            self.clock.shutdown(wait=False)
            self._started = False
        for w in self.workers.values():
            while True:
                try:
                    w.queue.get_nowait()
                except queue.Empty:
                    break
                w.queue.task_done()
            with w.lock:
                w.waiting.clear()
            w.queue.put(STOP)
        deadline = time.monotonic() + wait_s
        for w in self.workers.values():
            w.join(max(0.0, deadline - time.monotonic()))
        if self._registered:
            try:
                with session_scope(self.factory) as s:
                    leases.stop_worker(s, self.id)
            except StorageError as exc:
                log.warning("worker %r: leases not released (%s); they expire in %.0f s", self.name, exc,
                            self.lease_s)
            self._registered = False
            _IN_THIS_PROCESS.discard(self.id)

    def _run(self) -> None:
        """A tick every period; in between, woken at the next due time so a cycle starts
        on time, not up to a period late."""
        next_tick = time.monotonic() + self.period_s
        while True:
            wait = next_tick - time.monotonic()
            due_in = self._seconds_to_due()
            if due_in is not None:
                wait = min(wait, max(due_in, 0.02))
            if self._halt.wait(max(wait, 0.0)):
                return
            try:
                if time.monotonic() >= next_tick:
                    next_tick = time.monotonic() + self.period_s
                    self.tick()
                else:
                    self._queue_due()
            except Exception:  # noqa: BLE001 - the loop must go on; the next tick retries
                log.exception("worker %r: fleet tick failed", self.name)

    def _seconds_to_due(self) -> float | None:
        """Seconds (local clock, corrected by the database's) to the earliest due cycle of an
        axis that is not busy; None if none is planned."""
        with self._plan_lock:
            dues = [d for a, d in self.next_due.items()
                    if a not in self.workers or self.workers[a].busy_with(("schedule", "catch_up")) is None]
        if not dues:
            return None
        return (min(dues) - (utcnow() + self._db_offset)).total_seconds()

    # -- one tick ------------------------------------------------------------------------------
    def tick(self) -> None:
        """Heartbeat, claim/release, queue what is due (see the module docstring)."""
        try:
            with session_scope(self.factory) as s:
                still = leases.heartbeat(s, self.id, self.lease_s)
                # a lease found expired is dropped before the commit makes this worker live
                # again: no reader sees it live and holding an axis another worker took over
                expired = self.held - still
                if expired:
                    self._drop(expired)
                self._last_renewed = time.monotonic()
                leases.ensure_lease_rows(s)
                axes = {a.id: a for a in config_repo.list_axes(s)}
                workers = leases.live_workers(s)
        except StorageError as exc:
            if self.held and time.monotonic() - self._last_renewed > self.lease_s:
                log.error("worker %r: no database for %.0f s: its %d lease(s) have expired, other workers may "
                          "take the axes over (%s)", self.name, self.lease_s, len(self.held), exc)
                self._drop(set(self.held))
            else:
                log.warning("worker %r: heartbeat failed (%s)", self.name, exc)
            return
        self._axes = axes
        for a in axes.values():
            self.executor.remember(a)
        lost = expired | {a for a in self.held if a not in axes}
        if lost:
            log.warning("worker %r: lease lost on axis(es) %s (expired: another worker may run them)",
                        self.name, sorted(lost))
            self._drop(lost)
        mine = [a for a in axes.values() if matches(self.settings.axes, a)]
        target = fair_share(self.id, workers, list(axes.values()))
        self._claim_axes([a.id for a in mine if a.id not in self.held], target)
        if len(self.held) > target and len(workers) > 1:
            others = [p for w, p in workers if w != self.id]
            movable = {a for a in self.held if a in axes and any(matches(p, axes[a]) for p in others)}
            self._release_idle(len(self.held) - target, movable)
        self._queue_due()

    def _claim_axes(self, free: list[int], target: int) -> None:
        if not free:
            return
        need = target - len(self.held)
        try:
            with session_scope(self.factory) as s:
                got = leases.claim(s, self.id, free, need, self.lease_s) if need > 0 else []
                if not got:  # an axis nobody else took for two periods: taken beyond the share
                    got = leases.claim(s, self.id, free, 1, self.lease_s, free_for_s=2 * self.period_s)
                closed = {}
                for c in got:
                    closed[c.axis_id] = leases.take_over(s, self.id, c.axis_id, c.previous_owner)
                lasts = {c.axis_id: leases.last_due(s, c.axis_id) for c in got}
                now = leases.db_now(s)
        except StorageError as exc:
            log.warning("worker %r: claim failed (%s)", self.name, exc)
            return
        with self._plan_lock:
            for c in got:
                axis = self._axes[c.axis_id]
                self.held.add(c.axis_id)
                due = latest_due(axis, lasts[c.axis_id], now, self.catch_up_missed)
                self.closed += closed[c.axis_id]
                if due is not None:
                    self.next_due[c.axis_id] = due
                    if due < now:  # fell due while no worker held the axis: its cycle is a catch-up
                        self._catch_up.add(c.axis_id)
                taken = c.previous_owner is not None and c.previous_owner != self.id
                if taken:
                    self.takeovers += 1
                log.log(logging.WARNING if taken else logging.INFO,
                        "worker %r %s axis %s (%s)%s; next cycle due %s", self.name,
                        "took over" if taken else "claimed", c.axis_id, axis_key(axis),
                        f", {closed[c.axis_id]} cycle(s) it left closed" if closed[c.axis_id] else "",
                        due.isoformat(timespec="seconds") if due else "never (schedule off)")

    def _release_idle(self, n: int, movable: set[int]) -> None:
        """Hand back up to ``n`` idle axes that another live worker may run."""
        idle = [a for a in self.held & movable
                if a not in self.workers or self.workers[a].busy_with(("schedule", "catch_up", "manual")) is None]
        idle.sort(key=lambda a: self.next_due.get(a, datetime.max.replace(tzinfo=timezone.utc)), reverse=True)
        give = idle[:n]
        if not give:
            return
        with self._plan_lock:
            self._drop(set(give))
        try:
            with session_scope(self.factory) as s:
                leases.release(s, self.id, give)
            log.info("worker %r released axis(es) %s to balance the fleet", self.name, sorted(give))
        except StorageError as exc:
            log.warning("worker %r: release failed (%s); the leases expire in %.0f s", self.name, exc, self.lease_s)

    def _drop(self, axis_ids: set[int]) -> None:
        with self._plan_lock:
            for a in axis_ids:
                self.held.discard(a)
                self.next_due.pop(a, None)
                self._catch_up.discard(a)

    def _queue_due(self) -> None:
        held = sorted(self.held)
        if not held:
            return
        try:
            with session_scope(self.factory) as s:
                queued = leases.queued_cycles(s, held)
                now = leases.db_now(s)
            self._db_offset = now - utcnow()
        except StorageError as exc:
            log.warning("worker %r: queued cycles not read (%s)", self.name, exc)
            return
        for q in queued:  # manual triggers stored through any worker's API
            if q.uuid not in self._pushed and q.axis_id in self.held:
                self._push(CycleRequest(uuid=q.uuid, axis_id=q.axis_id, trigger=q.trigger,
                                        requested_at=q.requested_at, requested_by=q.requested_by))
        for axis_id in held:
            due = self.next_due.get(axis_id)
            if due is None or due > now:
                continue
            if self._worker(axis_id).busy_with(("schedule", "catch_up")) is not None:
                continue  # the previous scheduled cycle still runs: this one starts after it, late
            trigger = "catch_up" if axis_id in self._catch_up else "schedule"
            req = CycleRequest(uuid=str(uuidlib.uuid4()), axis_id=axis_id, trigger=trigger, requested_at=utcnow())
            try:
                with session_scope(self.factory) as s:
                    leases.queue_scheduled(s, axis_id, req.uuid, trigger, due, self.id)
            except StorageError as exc:
                log.warning("worker %r: scheduled cycle of axis %s not queued (%s)", self.name, axis_id, exc)
                continue
            self._push(req)
            self._catch_up.discard(axis_id)
            nxt = latest_due(self._axes[axis_id], due, now) if axis_id in self._axes else None
            with self._plan_lock:
                if axis_id in self.held and nxt is not None:
                    self.next_due[axis_id] = nxt
                else:
                    self.next_due.pop(axis_id, None)

    def _push(self, req: CycleRequest) -> None:
        w = self._worker(req.axis_id)
        self._pushed.add(req.uuid)
        with w.lock:
            w.waiting[req.uuid] = req
        w.queue.put(req)

    def _claim(self, req: CycleRequest, started: datetime) -> bool:
        """The executor's gate: run the cycle only if it moves to running under our lease."""
        self._pushed.discard(req.uuid)
        try:
            with session_scope(self.factory) as s:
                ok = leases.claim_cycle(s, req.uuid, self.id, started, self.lease_s)
        except StorageError as exc:
            log.warning("cycle %s not started: the database does not answer (%s)", req.uuid, exc)
            return False
        if not ok:
            log.info("cycle %s not started by %r: started elsewhere, cancelled, or the lease on axis %s is gone",
                     req.uuid, self.name, req.axis_id)
        return ok

    # -- the scheduler's interface (Service, REST) ----------------------------------------------
    def request(self, axis_id: int, trigger: str, requested_by: str | None = None) -> CycleRecord | CycleRequest | None:
        """Queue a cycle. On the axis' owner, as a single worker does (runs here). Elsewhere
        a manual trigger is only stored as queued (refused atomically if one waits already)
        and the owner runs it, and so is a repair's verification (the repair may be
        recorded through any worker's API); a scheduled one is not this worker's to queue (None)."""
        if self.active and axis_id in self.held:
            rec = super().request(axis_id, trigger, requested_by)
            if rec is not None:
                self._pushed.add(rec.uuid)
            return rec
        if trigger not in ("manual", "verification"):
            return None
        with session_scope(self.factory) as s:
            return results_repo.queue_cycle(s, axis_id, str(uuidlib.uuid4()), trigger, requested_by=requested_by)

    def schedule(self, axis: AxisRecord) -> None:
        """The axis changed (schedule, tasks): replan it if this worker holds it."""
        self.executor.remember(axis)
        self._axes[axis.id] = axis
        if not self.active or axis.id not in self.held:
            return
        try:
            with session_scope(self.factory) as s:
                last, now = leases.last_due(s, axis.id), leases.db_now(s)
        except StorageError:
            last, now = None, utcnow()
        due = latest_due(axis, last, now, self.catch_up_missed)
        with self._plan_lock:
            if due is None:
                self.next_due.pop(axis.id, None)
            elif axis.id in self.held:
                self.next_due[axis.id] = due

    def catch_up(self, axis: AxisRecord, now: datetime | None = None) -> bool:
        return False  # the plan starts from the axis' last due time: a missed run is caught up by itself

    def next_run(self, axis_id: int) -> datetime | None:
        return self.next_due.get(axis_id)


def workers_overview(service) -> list[dict]:
    """The workers for ``GET /workers``: from the database on PostgreSQL; on SQLite the
    one process that runs the scheduler (this one, or none if it serves the API only)."""
    sched = service.scheduler
    if isinstance(sched, FleetScheduler):
        with session_scope(service.factory) as s:
            infos = leases.list_workers(s)
            axes = {a.id: a for a in config_repo.list_axes(s)}
        return [dict(id=w.id, name=w.name, host=w.host, pid=w.pid, live=w.live, pinned=None if w.axes is None
                     else list(w.axes), lease_s=w.lease_s, started_at=w.started_at, heartbeat_at=w.heartbeat_at,
                     stopped_at=w.stopped_at, takeovers=w.takeovers, this_process=w.id == sched.id,
                     axes=[dict(id=a, machine=axes[a].machine_name, name=axes[a].name) for a in w.held if a in axes])
                for w in infos]
    if not service.settings.scheduler_enabled:
        return []
    with session_scope(service.factory) as s:
        axes = config_repo.list_axes(s)
    now = utcnow()
    started = datetime.fromtimestamp(service.started_at, timezone.utc)
    return [dict(id="sqlite", name=f"{socket.gethostname()}-{os.getpid()}", host=socket.gethostname(),
                 pid=os.getpid(), live=True, pinned=None, lease_s=0.0, started_at=started, heartbeat_at=now,
                 stopped_at=None, takeovers=0, this_process=True,
                 axes=[dict(id=a.id, machine=a.machine_name, name=a.name) for a in axes])]
