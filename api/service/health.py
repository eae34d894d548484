"""Health that tells the truth: can the service store what it measures?

A database that answers ``SELECT 1`` may still refuse every write (a read-only file,
a read-only PostgreSQL transaction mode, a full disk); a data folder may refuse new
files; the disk may be nearly full. :class:`HealthProbe` tries each for real:

- database: an ``UPDATE alembic_version SET version_num = version_num`` that is rolled
  back (a genuine write on both backends, which changes nothing);
- data folders (``datasets``, ``spool``): create, fsync and delete a small file;
- free disk of the data folder against ``Settings.min_free_disk_mb`` (below it no cycle
  is started), finished cycles waiting in the spool for room (``storage_full``) and the
  spool reserve released.

The result is cached for ``ttl_s`` so a polling load balancer does not cost a write
per request. ``/healthz`` and ``/metrics`` both read it. Once a report is older than
``ttl_s`` (up to ``ttl_s + stale_s``) the checks run again on a thread of their own
while the last report is answered: the write and fsync behind a check take tens to
hundreds of milliseconds on a busy disk, a health check must not. Checks that have not
answered for ``stale_s`` hang (a database or disk that does not answer): the answer is
degraded and says so. A report older than ``ttl_s + stale_s`` (nobody asked for a while)
and the first after :meth:`HealthProbe.invalidate` (a change the report must show) are
computed before they are answered.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
import time
import uuid
from dataclasses import dataclass, replace
from pathlib import Path

from sqlalchemy import exc as sa_exc
from sqlalchemy import text

from storage.db import StorageError, results_repo
from storage.db.engine import translate


@dataclass(frozen=True)
class HealthReport:
    database: str  # ok | read-only | unavailable
    data_dir_writable: bool
    free_disk_bytes: int | None
    min_free_disk_bytes: int
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def status(self) -> str:
        return "ok" if self.ok else "degraded"


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


class HealthProbe:
    def __init__(self, service, ttl_s: float = 2.0, stale_s: float = 10.0, *, clock=time.monotonic):
        self.service = service
        self.clock = clock
        self.ttl_s = ttl_s
        self.stale_s = stale_s
        self._last: tuple[float, HealthReport] | None = None
        self._lock = threading.Lock()
        self._generation = 0  # bumped by invalidate(): a refresh begun before it is not kept
        self._refresh_lock = threading.Lock()
        self._refresh_started: float | None = None  # when the refresh in flight began (None: none)

    def invalidate(self) -> None:
        self._generation += 1
        self._last = None

    def report(self, *, block: bool = True) -> HealthReport | None:
        """The health report; with ``block=False`` None instead of running the checks on
        this thread (the caller is the event loop: it runs them on a thread instead)."""
        last = self._last
        now = self.clock()
        if last is not None and now - last[0] < self.ttl_s:
            return last[1]
        if last is not None:
            started = self._refresh_started
            if started is not None:  # the checks run again now
                if now - started < self.stale_s:
                    return last[1]
                return replace(last[1], problems=(*last[1].problems, f"the health checks have not answered for "
                                                  f"{now - started:.0f} s: the database or the data folder hangs"))
            if now - last[0] < self.ttl_s + self.stale_s:
                self._refresh_in_background()
                return last[1]
        if not block:
            return None
        with self._lock:
            last = self._last
            if last is not None and self.clock() - last[0] < self.ttl_s:
                return last[1]
            rep = self._check()
            self._last = (self.clock(), rep)
            return rep

    def _refresh_in_background(self) -> None:
        with self._refresh_lock:
            if self._refresh_started is not None:
                return
            self._refresh_started = self.clock()
        generation = self._generation

        def run() -> None:
            try:
                rep = self._check()
                if generation == self._generation:
                    self._last = (self.clock(), rep)
            except Exception:  # noqa: BLE001 - the next report tries again; a hang shows as its age
                pass
            finally:
                self._refresh_started = None

        threading.Thread(target=run, name="mebm-health-check", daemon=True).start()

    # -- the checks ----------------------------------------------------------------------------
    def _check(self) -> HealthReport:
        problems: list[str] = []
        database, why = self._database()
        if why:
            problems.append(why)
        writable = True
        ex = self.service.executor
        for folder in ((ex.datasets_dir, ex.spool_dir) if ex is not None else (Path(self.service.settings.data_dir),)):
            why = self._folder(Path(folder))
            if why:
                writable = False
                problems.append(why)
        waiting = getattr(self.service, "waiting_for_room", None)
        if waiting:
            n = self.service.spooled_count()
            problems.append(f"storage_full: {waiting}" + (f"; {n} finished cycle(s) wait in the spool" if n else ""))
        floor = int(self.service.settings.min_free_disk_mb * 1e6)
        free = self._free_bytes(Path(self.service.settings.data_dir))
        if free is not None and free < floor:
            problems.append(f"free disk under the data folder is {free / 1e6:.0f} MB, below the floor of "
                            f"{floor / 1e6:.0f} MB (storage.min_free_disk_mb): no new cycle is started; free space "
                            "under the data folder and the schedule resumes")
        if ex is not None:
            held = ex.held()
            full = any(results_repo.is_storage_full(reason) for _, reason in held.values())
            if full:  # (no count in the line: it is also a metric label; spooled_cycles counts them)
                problems.append("storage_full: finished cycles wait in the spool because the disk was full; free space "
                                "under the data folder and they are stored within scheduler.spool_retry_s (or at "
                                "the next start)")
            if not ex.reserve_ok() and (full or (free is not None and free < ex.reserve_bytes)):
                slots = len(ex.slot_paths)
                left = ex.free_slots()
                then = (f"{left} of {slots} spool slot(s) keep the next cycles on a full disk (storage.spool_slots)"
                        if left else "the next cycle on a full disk may be kept in memory only")
                problems.append(f"the spool reserve {ex.reserve_path} is released (the disk was full): {then}; free "
                                "space under the data folder")
        return HealthReport(database=database, data_dir_writable=writable, free_disk_bytes=free,
                            min_free_disk_bytes=floor, problems=tuple(problems))

    def _database(self) -> tuple[str, str | None]:
        factory = self.service.factory
        if factory is None:
            return "unavailable", "database: not connected"
        try:
            with factory() as s:
                try:
                    s.execute(text("SELECT 1"))
                except sa_exc.SQLAlchemyError as exc:
                    raise translate(exc) from exc
                try:
                    s.execute(text("UPDATE alembic_version SET version_num = version_num"))
                except sa_exc.SQLAlchemyError as exc:
                    return "read-only", f"database cannot be written: {_first_line(getattr(exc, 'orig', exc))}"
                finally:
                    with contextlib.suppress(Exception):
                        s.rollback()
        except StorageError as exc:
            return "unavailable", f"database unavailable: {_first_line(exc)}"
        return "ok", None

    @staticmethod
    def _folder(folder: Path) -> str | None:
        probe = folder / f".health-{uuid.uuid4().hex}"
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            try:
                os.write(fd, b"ok")
                os.fsync(fd)
            finally:
                os.close(fd)
            probe.unlink()
        except OSError as exc:
            with contextlib.suppress(OSError):
                probe.unlink()
            return f"data folder {folder} cannot be written: {exc.strerror or exc}"
        return None

    @staticmethod
    def _free_bytes(folder: Path) -> int | None:
        for p in (folder, *folder.resolve().parents):
            with contextlib.suppress(OSError):
                return shutil.disk_usage(p).free
        return None
