"""Fleet coordination in the database: workers, per-axis leases, cycle claims.

Several ``mebm serve`` workers share one PostgreSQL database. Each axis has one row in
``axis_leases``: the worker that owns it and until when (``expires_at``, *database*
time, so the workers' clocks do not matter). The owner renews its leases with a
heartbeat; a worker that stops renewing (SIGKILL, network cut, host crash) loses them
when they expire, and another worker claims them with ``FOR UPDATE SKIP LOCKED`` (two
claimers never wait for, nor take, the same row). A cycle starts only through
:func:`claim_cycle`, which moves it from ``queued`` to ``running`` in one statement on
the condition that the worker still holds an unexpired lease on the axis: a manual
trigger queued through any worker's API runs exactly once, by the owner.

SQLite has one worker per file: :class:`SqliteWorkerLock` (an ``flock`` on a file next to
the database, released by the kernel when the process dies) refuses a second one.

Everything here except the SQLite lock is PostgreSQL SQL.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from sqlalchemy import text
from sqlalchemy.orm import Session

from storage.db import results_repo
from storage.db.errors import ConflictError, StorageError
from storage.db.records import CycleRecord, as_utc

SYNC_LOCK = 0x6D65626D0002  # advisory lock key: configuration sync at start-up


class WorkerConflictError(ConflictError):
    """A worker may not start: another one runs on the same SQLite file, or a live
    worker has the same name."""


@dataclass(frozen=True)
class Claimed:
    """An axis whose lease this worker just took; ``previous_owner`` (a worker id) when
    it was taken from a worker whose lease had expired."""

    axis_id: int
    previous_owner: str | None


@dataclass(frozen=True)
class WorkerInfo:
    id: str
    name: str
    host: str
    pid: int
    axes: tuple[str, ...] | None  # pinned patterns; None: any axis
    lease_s: float
    started_at: datetime
    heartbeat_at: datetime
    stopped_at: datetime | None
    takeovers: int
    live: bool
    held: tuple[int, ...]  # axis ids of its unexpired leases


@dataclass(frozen=True)
class QueuedCycle:
    uuid: str
    axis_id: int
    trigger: str
    requested_at: datetime
    requested_by: str | None
    due_at: datetime | None


def is_postgresql(s: Session) -> bool:
    return s.get_bind().dialect.name == "postgresql"


def serialize(s: Session, key: int = SYNC_LOCK) -> None:
    """Hold a transaction-scoped advisory lock (PostgreSQL; nothing on SQLite): workers
    starting together create the configured machines and keys one after another."""
    if is_postgresql(s):
        s.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": key})


def db_now(s: Session) -> datetime:
    return as_utc(s.execute(text("SELECT now()")).scalar_one())


# -- workers -----------------------------------------------------------------------------------
def register_worker(s: Session, worker_id: str, name: str, host: str, pid: int, axes: tuple[str, ...] | None,
                    lease_s: float) -> None:
    """Insert the worker's row; :class:`WorkerConflictError` when a live worker has the name."""
    s.execute(text("SELECT pg_advisory_xact_lock(:k, hashtext(:n))"), {"k": 0x6D65, "n": name})
    other = s.execute(text(
        "SELECT host, pid, extract(epoch FROM now() - heartbeat_at) FROM workers "
        "WHERE name = :n AND stopped_at IS NULL AND heartbeat_at > now() - make_interval(secs => lease_s)"
    ), {"n": name}).first()
    if other is not None:
        raise WorkerConflictError(
            f"a live worker is named {name!r} already (pid {other[1]} on {other[0]}, heartbeat {other[2]:.0f} s "
            "ago): give each worker its own [worker] name (or MEBM_WORKER_NAME), or stop the other one")
    s.execute(text(
        "INSERT INTO workers (id, name, host, pid, axes, lease_s, started_at, heartbeat_at, takeovers) "
        "VALUES (:id, :name, :host, :pid, :axes, :lease, now(), now(), 0)"
    ), {"id": worker_id, "name": name, "host": host, "pid": pid, "lease": lease_s,
        "axes": None if axes is None else json.dumps(list(axes))})


def local_workers(s: Session, host: str, me: str) -> list[tuple[str, int]]:
    """(id, pid) of the other workers on ``host`` that did not stop cleanly."""
    rows = s.execute(text("SELECT id, pid FROM workers WHERE host = :h AND id <> :me AND stopped_at IS NULL"),
                     {"h": host, "me": me})
    return [(r[0], r[1]) for r in rows]


def expire_worker(s: Session, worker_id: str) -> int:
    """A worker known dead (its process is gone from this host): its leases expire now
    instead of at their expiry, and its row says it stopped. Returns the leases expired."""
    s.execute(text("UPDATE workers SET stopped_at = now() WHERE id = :w AND stopped_at IS NULL"), {"w": worker_id})
    return s.execute(text("UPDATE axis_leases SET expires_at = now() WHERE owner = :w AND expires_at > now()"),
                     {"w": worker_id}).rowcount


def heartbeat(s: Session, worker_id: str, lease_s: float) -> set[int]:
    """Renew the worker's unexpired leases; returns the axes it still holds. A lease that
    expired is not renewed (it may have been taken over): it is lost."""
    s.execute(text("UPDATE workers SET heartbeat_at = now() WHERE id = :me"), {"me": worker_id})
    rows = s.execute(text(
        "UPDATE axis_leases SET expires_at = now() + make_interval(secs => :lease) "
        "WHERE owner = :me AND expires_at > now() RETURNING axis_id"
    ), {"me": worker_id, "lease": lease_s})
    return {r[0] for r in rows}


def stop_worker(s: Session, worker_id: str) -> int:
    """A clean stop: the worker's leases are free at once, its row says it stopped, and the
    cycles it leaves are closed (running: ``interrupted``; queued by its schedule:
    ``cancelled``; a queued manual one or a repair's verification stays for the next owner). Returns the cycles closed."""
    release(s, worker_id)
    n = s.execute(text(
        "UPDATE cycles SET status = 'interrupted', finished_at = now(), "
        "failure_reason = 'the worker stopped during the cycle' WHERE worker = :me AND status = 'running'"),
        {"me": worker_id}).rowcount
    n += s.execute(text(
        "UPDATE cycles SET status = 'cancelled', finished_at = now(), "
        "failure_reason = 'the worker stopped before the cycle started' "
        "WHERE worker = :me AND status = 'queued' AND \"trigger\" NOT IN ('manual', 'verification')"), {"me": worker_id}).rowcount
    s.execute(text("UPDATE workers SET stopped_at = now() WHERE id = :me"), {"me": worker_id})
    return n


def live_workers(s: Session) -> list[tuple[str, tuple[str, ...] | None]]:
    """(id, pinned patterns) of the workers whose heartbeat is younger than their lease."""
    rows = s.execute(text(
        "SELECT id, axes FROM workers WHERE stopped_at IS NULL "
        "AND heartbeat_at > now() - make_interval(secs => lease_s)"))
    return [(r[0], None if r[1] is None else tuple(json.loads(r[1]))) for r in rows]


def list_workers(s: Session, *, include_stopped_s: float = 3600.0) -> list[WorkerInfo]:
    """Live workers, and those stopped or silent within the last ``include_stopped_s``."""
    held: dict[str, list[int]] = {}
    for owner, axis_id in s.execute(text(
            "SELECT owner, axis_id FROM axis_leases WHERE owner IS NOT NULL AND expires_at > now() "
            "ORDER BY axis_id")):
        held.setdefault(owner, []).append(axis_id)
    rows = s.execute(text(
        "SELECT id, name, host, pid, axes, lease_s, started_at, heartbeat_at, stopped_at, takeovers, "
        "stopped_at IS NULL AND heartbeat_at > now() - make_interval(secs => lease_s) AS live FROM workers "
        "WHERE coalesce(stopped_at, heartbeat_at) > now() - make_interval(secs => :keep) ORDER BY name, started_at"
    ), {"keep": include_stopped_s})
    return [WorkerInfo(id=r[0], name=r[1], host=r[2], pid=r[3], axes=None if r[4] is None else tuple(json.loads(r[4])),
                       lease_s=r[5], started_at=as_utc(r[6]), heartbeat_at=as_utc(r[7]),
                       stopped_at=as_utc(r[8]) if r[8] else None, takeovers=r[9], live=bool(r[10]),
                       held=tuple(held.get(r[0], ()))) for r in rows]


# -- leases ------------------------------------------------------------------------------------
def ensure_lease_rows(s: Session) -> None:
    """A (free) lease row for every axis that has none yet."""
    s.execute(text(
        "INSERT INTO axis_leases (axis_id, owner, expires_at) SELECT id, NULL, now() FROM axes "
        "ON CONFLICT (axis_id) DO NOTHING"))


def claim(s: Session, worker_id: str, axis_ids: list[int], limit: int, lease_s: float,
          free_for_s: float = 0.0) -> list[Claimed]:
    """Take up to ``limit`` of ``axis_ids`` whose lease is free or expired (for at least
    ``free_for_s``; a free row's ``expires_at`` is when it was freed), skipping rows
    another worker is claiming right now."""
    if limit <= 0 or not axis_ids:
        return []
    rows = s.execute(text(
        "WITH cand AS (SELECT axis_id, owner FROM axis_leases "
        "  WHERE axis_id = ANY(:ids) AND expires_at <= now() - make_interval(secs => :free) "
        "  ORDER BY expires_at, axis_id LIMIT :n FOR UPDATE SKIP LOCKED) "
        "UPDATE axis_leases l SET owner = :me, previous_owner = cand.owner, acquired_at = now(), "
        "  expires_at = now() + make_interval(secs => :lease) "
        "FROM cand WHERE l.axis_id = cand.axis_id RETURNING l.axis_id, l.previous_owner"
    ), {"ids": list(axis_ids), "free": free_for_s, "n": limit, "me": worker_id, "lease": lease_s})
    return [Claimed(r[0], r[1]) for r in rows]


def release(s: Session, worker_id: str, axis_ids: list[int] | None = None) -> int:
    """Free the worker's leases (all, or those of ``axis_ids``); returns how many."""
    q = "UPDATE axis_leases SET owner = NULL, previous_owner = :me, expires_at = now() WHERE owner = :me"
    params: dict = {"me": worker_id}
    if axis_ids is not None:
        q += " AND axis_id = ANY(:ids)"
        params["ids"] = list(axis_ids)
    return s.execute(text(q), params).rowcount


def take_over(s: Session, worker_id: str, axis_id: int, previous_owner: str | None) -> int:
    """After claiming ``axis_id``: the cycle another worker left running is ``interrupted``,
    its queued scheduled ones ``cancelled`` (the schedule is recomputed from the history);
    a queued manual one or a repair's verification stays queued and is run by the new owner. Counts a takeover when
    the lease was taken from another worker. Returns the number of cycles closed."""
    name = None
    if previous_owner is not None and previous_owner != worker_id:
        name = s.execute(text("SELECT name FROM workers WHERE id = :w"), {"w": previous_owner}).scalar()
        s.execute(text("UPDATE workers SET takeovers = takeovers + 1 WHERE id = :me"), {"me": worker_id})
    who = f"worker {name!r}" if name else "its worker"
    n = s.execute(text(
        "UPDATE cycles SET status = 'interrupted', finished_at = now(), failure_reason = :why "
        "WHERE axis_id = :a AND status = 'running' AND (worker IS NULL OR worker <> :me)"
    ), {"a": axis_id, "me": worker_id,
        "why": f"{who} stopped renewing its lease on the axis during the cycle (dead, or cut from the database); "
               "the axis was taken over"}).rowcount
    n += s.execute(text(
        "UPDATE cycles SET status = 'cancelled', finished_at = now(), failure_reason = :why "
        "WHERE axis_id = :a AND status = 'queued' AND \"trigger\" NOT IN ('manual', 'verification') AND (worker IS NULL OR worker <> :me)"
    ), {"a": axis_id, "me": worker_id,
        "why": f"{who} lost its lease on the axis before the cycle started; the new owner schedules anew"}).rowcount
    return n


# -- cycles ------------------------------------------------------------------------------------
def queue_scheduled(s: Session, axis_id: int, uuid: str, trigger: str, due_at: datetime,
                    worker_id: str) -> CycleRecord:
    rec = results_repo.queue_cycle(s, axis_id, uuid, trigger)
    s.execute(text("UPDATE cycles SET due_at = :d, worker = :w WHERE uuid = :u"),
              {"d": due_at, "w": worker_id, "u": uuid})
    return rec


def claim_cycle(s: Session, uuid: str, worker_id: str, started_at: datetime, lease_s: float) -> bool:
    """``queued`` -> ``running`` for this worker, only if it holds an unexpired lease on
    the cycle's axis, which the same statement renews: the lease then outlives the start
    by a full ``lease_s``, so a cycle shorter than that ends before any other worker may
    take the axis, whatever happens to this worker's network. False: another worker
    started it, it was cancelled, or the lease is gone."""
    return s.execute(text(
        "WITH l AS (UPDATE axis_leases SET expires_at = now() + make_interval(secs => :lease) "
        "  WHERE axis_id = (SELECT axis_id FROM cycles WHERE uuid = :u AND status = 'queued') "
        "  AND owner = :me AND expires_at > now() RETURNING axis_id) "
        "UPDATE cycles SET status = 'running', started_at = :t, worker = :me "
        "WHERE uuid = :u AND status = 'queued' AND axis_id IN (SELECT axis_id FROM l)"
    ), {"u": uuid, "me": worker_id, "t": started_at, "lease": lease_s}).rowcount == 1


def queued_cycles(s: Session, axis_ids: list[int]) -> list[QueuedCycle]:
    """The queued cycles of the axes (manual ones queued through any worker's API)."""
    if not axis_ids:
        return []
    rows = s.execute(text(
        "SELECT uuid, axis_id, \"trigger\", requested_at, requested_by, due_at FROM cycles "
        "WHERE status = 'queued' AND axis_id = ANY(:ids) ORDER BY requested_at"), {"ids": list(axis_ids)})
    return [QueuedCycle(r[0], r[1], r[2], as_utc(r[3]), r[4], as_utc(r[5]) if r[5] else None) for r in rows]


def last_due(s: Session, axis_id: int) -> datetime | None:
    """When the axis' last scheduled cycle that was not interrupted or cancelled was due
    (its request time for those stored without a due time): the schedule goes on from there."""
    v = s.execute(text(
        "SELECT max(coalesce(due_at, requested_at)) FROM cycles WHERE axis_id = :a "
        "AND \"trigger\" IN ('schedule', 'catch_up') AND status NOT IN ('interrupted', 'cancelled')"),
        {"a": axis_id}).scalar()
    return as_utc(v) if v is not None else None


def lateness(s: Session, since: datetime) -> list[tuple[int, float]]:
    """(axis id, start minus due time in s) of the scheduled cycles started since ``since``."""
    rows = s.execute(
        text("SELECT axis_id, extract(epoch FROM started_at - due_at) FROM cycles "
             "WHERE due_at IS NOT NULL AND started_at IS NOT NULL AND started_at >= :t ORDER BY started_at"),
        {"t": since})
    return [(r[0], float(r[1])) for r in rows]


def overlapping_cycles(s: Session) -> list[tuple[int, str, str]]:
    """(axis id, uuid, uuid) of every two cycles of one axis that ran at the same time."""
    rows = s.execute(text(
        "SELECT a.axis_id, a.uuid, b.uuid FROM cycles a JOIN cycles b ON a.axis_id = b.axis_id AND a.id < b.id "
        "WHERE a.started_at IS NOT NULL AND b.started_at IS NOT NULL "
        "AND a.started_at < coalesce(b.finished_at, now()) AND b.started_at < coalesce(a.finished_at, now())"))
    return [(r[0], r[1], r[2]) for r in rows]


# -- SQLite: one worker per file ---------------------------------------------------------------
class SqliteWorkerLock:
    """An exclusive ``flock`` on ``<database>.worker.lock`` for the worker's lifetime. The
    kernel releases it when the process ends, however it ends (kill -9 included)."""

    def __init__(self, db_file: Path):
        self.path = Path(str(db_file) + ".worker.lock")
        self._fd: int | None = None

    def acquire(self) -> None:
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = ""
            with contextlib.suppress(OSError, ValueError):
                holder = os.pread(fd, 200, 0).decode().strip()
            os.close(fd)
            raise WorkerConflictError(
                f"another mebm worker ({holder or 'pid unknown'}) runs the scheduler on the SQLite database "
                f"{db_file_of(self.path)}: SQLite takes one worker. Stop it, start this one with --no-scheduler "
                "(API only), or move to PostgreSQL to run several workers (docs/fleet.md)") from None
        except OSError as exc:
            os.close(fd)
            raise StorageError(f"cannot lock {self.path}: {exc}") from exc
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {os.uname().nodename}\n".encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self._fd, fcntl.LOCK_UN)
                os.close(self._fd)
            self._fd = None


def db_file_of(lock_path: Path) -> str:
    return str(lock_path)[: -len(".worker.lock")]


__all__ = ["Claimed", "QueuedCycle", "SqliteWorkerLock", "WorkerConflictError", "WorkerInfo", "claim",
           "claim_cycle", "db_now", "ensure_lease_rows", "expire_worker", "heartbeat", "is_postgresql", "last_due", "lateness",
           "list_workers", "live_workers", "local_workers", "overlapping_cycles", "queue_scheduled", "queued_cycles",
           "register_worker", "release", "serialize", "stop_worker", "take_over"]
