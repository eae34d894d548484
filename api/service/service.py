"""The service: database, migrations, configured machines, keys, simulated controller,
scheduler and cycle executor, started and stopped as one.

``Service(settings).start()`` is what ``mebm serve`` does before the HTTP server
starts; the REST app (``api.rest.create_app``) reads through the same object.
"""

from __future__ import annotations

import gc
import json
import logging
import os
import shutil
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from urllib.parse import parse_qsl, urlencode, urlsplit

from sqlalchemy import text

from api.service.config.settings import SIM_CONTROLLER, Settings
from api.service.cycles.executor import CycleExecutor
from api.service.figures.cache import FigureCache
from api.service.figures.gate import RenderGate
from api.service.cycles.folders import axis_folders
from api.service.gap_jobs import GapJobs
from api.service.installation import installation_name
from api.service.figures.process import PlotProcess
from api.service.demo import DemoController
from api.service.health import HealthProbe
from api.service.cycles.leases import FleetScheduler
from api.service.cycles.runner import CycleProcesses, CycleRunner, DriverRunner
from api.service.cycles.scheduler import CycleScheduler
from api.service.secret_files import (
    ADMIN_KEY_FILE,
    DEMO_KEYS_FILE,
    database_identity,
    move_aside,
    secret_path,
    write_secret_file,
)
from api.service.events import Event, EventHub, events_of_saved_cycle
from api.service.maintenance.loop import MaintenanceLoop
from api.service.status import StatusCache
from core.errors import MebmError
from storage.retention import apply_retention
from storage.db import leases
from storage.db import (
    AxisRecord,
    DatabaseUnavailableError,
    StorageError,
    WaitingCycleError,
    config_repo,
    is_sqlite,
    make_engine,
    make_session_factory,
    ping,
    results_repo,
    session_scope,
    upgrade,
    utcnow,
)

log = logging.getLogger("mebm.service")
SQLITE_OPEN_ROOM_BYTES = 1_000_000  # enough for SQLite to open a WAL database and write a little


@dataclass(frozen=True)
class StartReport:
    """What start-up did, for the banner ``mebm serve`` prints."""

    database: str
    replayed: int
    interrupted: int
    created_axes: tuple[str, ...]
    demo_keys: dict
    simulators: dict  # axis id -> controller url
    bootstrap_admin: str | None
    worker: str | None = None  # fleet (PostgreSQL): this worker's name, axes and lease, for the banner
    folders_moved_aside: tuple[str, ...] = ()  # dataset folders of another machine or database, renamed (why, where)
    # the SQLite database could not be opened for lack of disk: why, and that the start
    # completes by itself once there is room (nothing else in this report happened yet)
    waiting_for_room: str | None = None
    # the finished cycles start-up could not store (still in the spool): one line each, with the reason
    not_stored: tuple[str, ...] = ()
    # the cycles lost on a full disk with every spool slot taken, recorded from the loss ledger
    lost: tuple[str, ...] = ()


class Service:
    def __init__(self, settings: Settings, *, runner: CycleRunner | None = None, db_wait_s: float = 30.0):
        self.settings = settings
        self.instance = installation_name(settings)  # this installation's name on MQTT, MTConnect, OPC UA
        # the production runner measures in worker processes (the acquisition and analysis off the API's interpreter)
        self.runner = runner or DriverRunner(processes=CycleProcesses(settings.cycle_processes),
                                             profiles_dir=settings.profiles_path)
        self.db_wait_s = db_wait_s
        self.engine = None
        self.factory = None
        self.executor: CycleExecutor | None = None
        self.scheduler: CycleScheduler | None = None
        self.status: StatusCache | None = None
        self.simulators: dict[int, DemoController] = {}
        self.started_at = time.time()
        self.report: StartReport | None = None
        self.health = HealthProbe(self)
        self.events = EventHub()  # "measurement stored", "cycle failed", "alert changed" -> every interface
        self.render_status = None  # axis_id -> the status body (bytes); set by the REST app
        self.gap_jobs = GapJobs(max_pending=settings.limits.gap_diagnoses_pending,  # gap diagnoses: bounded jobs,
                                timeout_s=settings.limits.gap_diagnosis_timeout_s,  # computed in a worker process
                                nice=settings.limits.gap_diagnosis_nice)
        self.plots = PlotProcess.shared()  # figure renders, in a worker process (not on the API's interpreter)
        # rendered figures, for the REST plot endpoints and the dashboard alike
        self.figures = FigureCache(resolution_s=settings.limits.plot_window_step_s)
        # figures drawn and waiting at once (the rest: 429), so that plots never hold every thread
        self.render_gate = RenderGate(settings.limits.plot_renders, settings.limits.plot_queue)
        self.maintenance = MaintenanceLoop(self, settings.maintenance)  # work orders, repairs, verification
        self.fleet = False  # PostgreSQL: this process is one worker (or API replica) of a fleet
        self._sqlite_lock: leases.SqliteWorkerLock | None = None
        self._sim_lock = threading.Lock()
        self.waiting_for_room: str | None = None  # the start waits for disk to open the database (see start)
        self._room_waiter: threading.Thread | None = None
        self._stopping = threading.Event()

    # -- wiring ----------------------------------------------------------------------------------
    def resolve_url(self, axis: AxisRecord) -> str:
        if axis.settings.controller_url == SIM_CONTROLLER:
            with self._sim_lock:  # a fleet worker starts them on first use, from the axes' threads
                sim = self.simulators.get(axis.id)
                if sim is None:
                    sim = self._start_simulator(axis)
            # sim://: the simulator's own scheme, so its round trips are active (mebm starts them)
            return sim.url.replace("modbus://", "sim://", 1)
        return axis.settings.controller_url

    def _start_simulator(self, axis: AxisRecord) -> DemoController:
        sim = DemoController(axis.spec, self.settings.simulator)
        sim.start()
        self.simulators[axis.id] = sim
        log.info("simulated controller for axis %s listens on %s", axis.id, sim.url)
        return sim

    def _on_saved(self, axis_id, cycle, alerts) -> None:
        # (the executor has published the axis' new status: computed with the cycle)
        axis = self.executor.known_axis(axis_id) if self.executor is not None else None
        machine, name = (axis.machine_name, axis.name) if axis is not None else ("?", "?")
        for ev in events_of_saved_cycle(axis_id, machine, name, cycle, alerts):
            self.events.publish(ev)
        self.maintenance.after_cycle(axis_id, cycle, alerts)  # opens or verifies a work order

    def status_document(self, axis_id: int) -> bytes | None:
        """The status body as REST serves it (``render_status``, set by the REST app), for
        the interfaces that publish it; None when no renderer is set."""
        render = self.render_status
        return None if render is None else render(axis_id)

    def _connect(self, wait_s: float | None = None) -> None:
        """Open the database (and migrate it), retried for ``wait_s`` (default
        ``db_wait_s``). A SQLite database on a disk too full to open it raises at once:
        waiting does not make room (:meth:`start` waits for it without blocking)."""
        st = self.settings
        idle_s = max(st.worker.lease_s / 2, 2.0) if st.scheduler_enabled and not is_sqlite(st.db_url) else None
        if self.engine is None:
            self.engine = make_engine(st.db_url, idle_in_transaction_timeout_s=idle_s)
        deadline = time.monotonic() + (self.db_wait_s if wait_s is None else wait_s)
        while True:
            try:
                ping(self.engine)
                upgrade(self.engine)
                break
            except DatabaseUnavailableError:
                if time.monotonic() > deadline or self._database_disk_full() is not None:
                    raise
                time.sleep(1.0)
        self.factory = make_session_factory(self.engine)

    def _database_disk_full(self) -> str | None:
        """Why the SQLite database cannot be opened for lack of disk (free space under its
        folder below the free-disk floor, and below the little SQLite needs to open a
        database: its shared-memory index and write-ahead log), or None."""
        if not is_sqlite(self.settings.db_url):
            return None
        folder = Path(self.engine.url.database or self.settings.data_dir).parent
        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            return None
        if free >= max(self.settings.min_free_disk_mb * 1e6, SQLITE_OPEN_ROOM_BYTES):
            return None
        return (f"the database {self.engine.url.database} cannot be opened: the disk under it is full "
                f"({free / 1e6:.1f} MB free); free space under the data folder and the service completes its "
                "start (spooled cycles are stored then)")

    # -- life cycle ------------------------------------------------------------------------------
    def start(self) -> StartReport:
        """Open the database and start everything. On a disk too full for SQLite to open its
        database, the start is not an error: the service answers (``/healthz`` says why it
        waits, every other request 503), keeps what the spool holds untouched, starts no
        cycle, and completes the start by itself once there is room."""
        st = self.settings
        Path(st.data_dir).mkdir(parents=True, exist_ok=True)
        _restrict(Path(st.data_dir), 0o700)  # raw runs, spool, keys: the service's own
        self._stopping.clear()
        self.engine = None
        try:
            self._connect()
        except DatabaseUnavailableError as exc:
            why = self._database_disk_full()
            if why is None:
                raise
            return self._wait_for_room(f"{why} ({exc})")
        return self._start_connected()

    def _wait_for_room(self, why: str) -> StartReport:
        self.waiting_for_room = why
        log.error("%s", why)
        self.report = StartReport(database=redact_secrets(self.settings.db_url), replayed=0, interrupted=0, created_axes=(),
                                  demo_keys={}, simulators={}, bootstrap_admin=None, waiting_for_room=why)
        self._room_waiter = threading.Thread(target=self._complete_start_when_room, name="mebm-wait-for-room",
                                             daemon=True)
        self._room_waiter.start()
        return self.report

    def _complete_start_when_room(self) -> None:
        # the free space is looked at every second (cheap), the database tried as soon as
        # there is room, and every spool_retry_s while the database refuses for another reason
        retry_s = max(self.settings.spool_retry_s, 0.1)
        next_try = 0.0  # (monotonic) while there is room but the database still refuses
        while not self._stopping.wait(min(1.0, retry_s)):
            why = self._database_disk_full()
            if why is not None:
                self.waiting_for_room = why  # with the free space of now
                next_try = 0.0  # tried as soon as there is room
                continue
            if time.monotonic() < next_try:
                continue
            try:
                self._connect(wait_s=0.0)
            except DatabaseUnavailableError as exc:
                next_try = time.monotonic() + retry_s
                self.waiting_for_room = f"the database is not open yet: {exc} (tried every {retry_s:g} s)"
                continue
            try:
                self._start_connected()
            except Exception:  # noqa: BLE001 - logged; /healthz says it
                log.exception("the start after the disk had room again failed")
                self.waiting_for_room = "the start after the disk had room again failed: see the log"
                return
            self.waiting_for_room = None
            log.info("the disk has room again: the service completed its start (%d spooled cycle(s) stored)",
                     self.report.replayed)
            return

    def _start_connected(self) -> StartReport:
        st = self.settings
        self.fleet = not is_sqlite(self.engine)
        if (not self.fleet and st.scheduler_enabled and self._sqlite_lock is None
                and self.engine.url.database not in (None, "", ":memory:")):
            self._sqlite_lock = leases.SqliteWorkerLock(Path(self.engine.url.database))
            self._sqlite_lock.acquire()  # a second worker on the file is refused (WorkerConflictError)
        if is_sqlite(self.engine):
            db_file = Path(self.engine.url.database or "")
            for p in (db_file, db_file.with_name(db_file.name + "-wal"), db_file.with_name(db_file.name + "-shm")):
                if p.is_file():
                    _restrict(p, 0o600)
        self.status = StatusCache(self.factory, ttl_s=st.status_max_age_s)
        self.executor = CycleExecutor(self.factory, Path(st.data_dir), self.runner, self.resolve_url,
                                      on_saved=self._on_saved, status=self.status,
                                      reserve_bytes=int(st.spool_reserve_mb * 1e6),
                                      min_free_bytes=int(st.min_free_disk_mb * 1e6), slots=st.spool_slots,
                                      slot_bytes=int(st.spool_slot_mb * 1e6))
        if isinstance(self.runner, DriverRunner) and self.runner.processes is not None and (
                st.scheduler_enabled or not self.fleet):  # (an API-only fleet replica runs no cycle)
            self.runner.processes.start()  # spawned in the background; cycles run in the service until they are up
        self.plots.warm_up()  # the plot process too, so the first plot asked for is not the slow one
        if isinstance(self.scheduler, FleetScheduler):  # started again (an ASGI lifespan run twice): one worker
            self.scheduler.stop()
        if self.fleet:  # leases in the database decide which worker runs which axis (docs/fleet.md)
            self.scheduler = FleetScheduler(self.executor, self.factory, st.worker, active=st.scheduler_enabled,
                                            catch_up=st.catch_up_missed)
            if st.scheduler_enabled:
                self.scheduler.register()  # a live worker of the same name: refused before anything moves
        else:
            self.scheduler = CycleScheduler(self.executor, self.factory)
        with session_scope(self.factory) as s:
            self.executor.migrate_folders(config_repo.list_axes(s))
        replayed = self.executor.replay_spool()
        interrupted = 0
        if not self.fleet:  # in a fleet, the cycles a dead worker left are closed by the worker taking its axes
            with session_scope(self.factory) as s:
                interrupted = results_repo.close_stale_cycles(s, held=self.executor.held())
        created = self._sync_config()
        admin = self._bootstrap_admin()
        demo_keys = self._demo_keys() if st.demo_keys and st.uses_simulator else {}
        with session_scope(self.factory) as s:
            axes = config_repo.list_axes(s)
        # after the spool's replay (its cycles count as the axes') and the creation of the
        # configured axes (a new database's axes meet the old folders of their ids here)
        aside = tuple(self.executor.claim_folders(axes))
        fresh_sim_axes = []
        for axis in axes:
            if self.fleet:  # the fleet scheduler plans the axes this worker claims (simulators start on use)
                self.executor.remember(axis)
                continue
            if axis.settings.controller_url == SIM_CONTROLLER:
                self._start_simulator(axis)
                with session_scope(self.factory) as s:
                    if results_repo.last_cycle_at(s, axis.id, ("schedule", "catch_up", "manual")) is None:
                        fresh_sim_axes.append(axis)
            self.executor.remember(axis)
            if st.scheduler_enabled:
                self.scheduler.schedule(axis)
        if st.scheduler_enabled:
            self.scheduler.clock.add_job(self.apply_retention, "interval", seconds=st.retention_interval_s,
                                         id="retention", coalesce=True, max_instances=1,
                                         next_run_time=datetime.now(timezone.utc) + timedelta(seconds=60))
            self.scheduler.clock.add_job(self._retry_spool, "interval", seconds=st.spool_retry_s, id="spool",
                                         coalesce=True, max_instances=1)
            self.scheduler.start()
            self.maintenance.resume()  # repaired orders whose verification the stop cancelled
            if self.fleet:  # the simulated controllers of the axes this worker claimed, listening before the banner
                for axis in axes:
                    if axis.id in self.scheduler.held and axis.settings.controller_url == SIM_CONTROLLER:
                        self.resolve_url(axis)
            for axis in axes:
                if axis in fresh_sim_axes:
                    self.scheduler.request(axis.id, "catch_up")  # the demo shows a measurement at once
                elif st.catch_up_missed:
                    self.scheduler.catch_up(axis)
        if isinstance(self.scheduler, FleetScheduler):
            interrupted += self.scheduler.closed  # those of a dead worker, closed when its axes were taken
        self.report = StartReport(
            database=redact_secrets(st.db_url), replayed=replayed, interrupted=interrupted, created_axes=tuple(created),
            demo_keys=demo_keys, simulators={a: s.url for a, s in self.simulators.items()}, bootstrap_admin=admin,
            worker=self._worker_line(), folders_moved_aside=aside,
            not_stored=tuple(f"cycle {u} ({status}) is kept in the spool, not stored yet: {reason or 'database down'}"
                             for u, (status, reason) in sorted(self.executor.held().items())),
            lost=tuple(self.executor.lost),
        )
        # Everything start-up made (modules, mappers, compiled statements, the app) lives as
        # long as the process: move it out of the collector's sight, so a full collection
        # during a request scans only what requests made. Without it the first request that
        # allocates a few thousand objects (a year's /trend) paid a full pass over ~130,000
        # start-up objects: 80-100 ms of its 180-260 ms (benchmarks/bench_history.py).
        # Once per process: a process that starts services in turn (the tests) would pay a
        # full collection of its whole heap at every start, and what the first one froze
        # stays frozen (its modules and mappers are the next one's too).
        if gc.get_freeze_count() == 0:
            gc.collect()
            gc.freeze()
        return self.report

    def _worker_line(self) -> str | None:
        sched = self.scheduler
        if not isinstance(sched, FleetScheduler):
            return None
        if not sched.active:
            return "fleet: API only (--no-scheduler); manual triggers are run by the worker that holds the axis"
        pinned = ", ".join(sched.settings.axes) if sched.settings.axes else "any axis"
        return (f"fleet worker {sched.name!r}: holds {len(sched.held)} axis lease(s) now, may run {pinned}, "
                f"lease {sched.lease_s:g} s (GET /api/v1/workers)")

    def stop(self) -> None:
        self._stopping.set()
        if self._room_waiter is not None:  # a start completing now finishes first, then stops here
            self._room_waiter.join()
            self._room_waiter = None
        if self.scheduler is not None:
            self.scheduler.stop()
        if self.executor is not None:
            self.executor.flush_unsaved()  # a cycle kept in memory goes to the spool (the reserve if need be)
        if self._sqlite_lock is not None:
            self._sqlite_lock.release()
            self._sqlite_lock = None
        self.events.close()
        if isinstance(self.runner, DriverRunner) and self.runner.processes is not None:
            self.runner.processes.close()
        self.gap_jobs.close()  # (self.plots is the interpreter's, shared: it ends with it)
        for sim in self.simulators.values():
            sim.stop()
        self.simulators.clear()
        if self.engine is not None:
            self.engine.dispose()

    def spooled_count(self) -> int:
        """Finished cycles not stored yet: in the spool or kept in memory (before the
        database is open, what the spool folder holds)."""
        if self.executor is not None:
            return len(self.executor.pending()) + len(self.executor.unsaved)
        spool = Path(self.settings.data_dir) / "spool"
        return len(list(spool.glob("*.json"))) if spool.is_dir() else 0

    def _retry_spool(self) -> None:
        if not self.executor.has_pending():
            self.executor.ensure_reserve()  # released on a full disk: back once there is room
        else:
            n = self.executor.replay_spool()
            if n:
                log.info("stored %d cycle(s) kept on disk during a database outage", n)

    def axis_folders(self, axis: AxisRecord) -> list[Path]:
        """The axis' dataset folders: its own, ``_rejected`` and ``@<time>`` ones (not those
        moved aside: retention never touches another machine's runs)."""
        return axis_folders(self.executor.datasets_dir, axis)

    def apply_retention(self) -> dict[int, int]:
        """Apply the retention policy to every axis' folders; returns bytes on disk per axis."""
        out = {}
        for axis_id, axis in list(self.executor._axes.items()):
            try:
                with session_scope(self.factory) as s:
                    events = results_repo.event_cycle_uuids(s, axis_id)
            except StorageError as exc:
                log.warning("retention of axis %s postponed: %s", axis_id, exc)
                continue
            total = 0
            reason = (f"deleted by the retention policy on {datetime.now(timezone.utc):%Y-%m-%d} (more than "
                      f"max_runs={self.settings.retention.max_runs} runs in the folder; the result is kept)")

            def mark(uuids: tuple[str, ...]) -> None:  # before the files go: a run is never gone unmarked
                with session_scope(self.factory) as s:
                    results_repo.mark_runs_deleted(s, uuids, reason)

            for folder in self.axis_folders(axis):
                try:
                    rep = apply_retention(folder, self.settings.retention, events, before_delete=mark)
                except StorageError as exc:
                    log.warning("retention of %s postponed: the cycles of the runs to delete could not be marked "
                                "(%s)", folder.name, exc)  # fmt: skip
                    continue
                except (MebmError, OSError) as exc:
                    log.error("retention of %s failed: %s", folder.name, exc)
                    continue
                if rep.compressed or rep.deleted:
                    log.info("retention of %s: %d run(s) compressed, %d deleted, %d kept",
                             folder.name, rep.compressed, rep.deleted, rep.runs)
                total += rep.bytes_on_disk
            out[axis_id] = total
        return out

    # -- configuration ---------------------------------------------------------------------------
    def _sync_config(self) -> list[str]:
        """Create the configured machines and axes that the database does not have yet.
        Existing ones are left as stored (changes made through the API persist)."""
        created = []
        with session_scope(self.factory) as s:
            leases.serialize(s)  # fleet workers starting together: one at a time
            for name, description in self.settings.machines:
                if config_repo.find_machine(s, name) is None:
                    config_repo.create_machine(s, name, description)
            for ac in self.settings.axes:
                m = config_repo.find_machine(s, ac.machine)
                if m is None:
                    m = config_repo.create_machine(s, ac.machine)
                if config_repo.find_axis(s, ac.machine, ac.settings.spec.name) is None:
                    config_repo.create_axis(s, m.id, ac.settings)
                    created.append(f"{ac.machine}/{ac.settings.spec.name}")
        return created

    def _bootstrap_admin(self) -> str | None:
        secret = self.settings.bootstrap_admin_key
        if not secret:
            return None
        with session_scope(self.factory) as s:
            leases.serialize(s)  # fleet workers starting together: one at a time
            known = config_repo.find_key_by_secret(s, secret)
            if known is not None and known.revoked_at is None:
                return known.name
            if known is not None:
                log.warning("MEBM_BOOTSTRAP_ADMIN_KEY is the key %r, revoked on %s: it stays revoked "
                            "(unset the variable)", known.name, known.revoked_at.isoformat())
                return None
            if any(k.role == "admin" and k.revoked_at is None for k in config_repo.list_keys(s)):
                log.warning("MEBM_BOOTSTRAP_ADMIN_KEY ignored: an admin key exists already")
                return None
            name = "bootstrap-admin"
            if config_repo.find_key(s, name) is not None:
                name = f"bootstrap-admin-{int(time.time())}"
            config_repo.create_key(s, name, "admin", secret=secret)
            return name

    def _demo_keys(self) -> dict:
        """Demo keys (read, operate, admin), created hashed at first start. Returns the keys
        created by this start only. The read and operate secrets are kept in
        ``<data_dir>/demo-keys.json`` for the demo's examples, the admin secret in
        ``<data_dir>/admin-key`` for the operator to take away (both mode 600,
        :mod:`api.service.secret_files`); none of them is printed unless ``mebm serve
        --show-keys`` asks. A key is created only if its file could be written: on a full
        disk none is, and the next start tries again. The files are this database's
        (:func:`api.service.secret_files.secret_path`); one found under this database's
        name that holds no key of it (another database's, from before the names carried the
        database) is moved aside, never overwritten."""
        data_dir = Path(self.settings.data_dir)
        database = database_identity(data_dir, self.settings.database_url)
        path = secret_path(data_dir, self.settings.database_url, DEMO_KEYS_FILE, claim=True)
        admin_path = secret_path(data_dir, self.settings.database_url, ADMIN_KEY_FILE)
        kept = {}
        if path.is_file():
            try:
                kept = json.loads(path.read_text(encoding="utf-8"))
            except ValueError:
                kept = {}
        if not isinstance(kept, dict):
            kept = {}
        created = {}
        try:
            with session_scope(self.factory) as s:
                leases.serialize(s)  # fleet workers starting together: one at a time
                live = [k for k in config_repo.list_keys(s) if k.revoked_at is None]
                valid = {r: kept[r] for r in ("read", "operate")
                         if isinstance(kept.get(r), str) and config_repo.authenticate(s, kept[r]) is not None}
                if path.is_file() and not valid and kept.get("database") != database and (
                        kept.get("read") or kept.get("operate")):
                    self._aside(path, kept.get("database"))  # another database's keys: kept, not overwritten
                    kept = {}
                for role in ("read", "operate", "admin"):
                    if role in valid or (role == "admin" and any(k.role == "admin" and k.name.startswith("demo-admin")
                                                                 for k in live)):
                        continue
                    name = f"demo-{role}"
                    if config_repo.find_key(s, name) is not None:
                        name = f"demo-{role}-{int(time.time())}"
                    _, created[role] = config_repo.create_key(s, name, role)
                # written before the keys are committed: a key nobody can read is never created
                keep = {"database": database, **valid, **{r: k for r, k in created.items() if r != "admin"}}
                if keep != kept:
                    write_secret_file(path, json.dumps(keep, indent=2))
                if "admin" in created:
                    if admin_path.is_file():  # an admin key this database does not have (its own demo admin is live)
                        self._aside(admin_path, None)
                    write_secret_file(admin_path, created["admin"] + "\n")
        except OSError as exc:
            log.warning("demo keys not created: cannot write them under %s (%s); the next start tries again",
                        data_dir, exc.strerror or exc)
            return {}
        return created

    @staticmethod
    def _aside(path: Path, database: str | None) -> None:
        moved = move_aside(path)
        log.warning("%s holds no key of this database%s: moved aside to %s (nothing deleted; its keys belong to "
                    "the database it was written for)", path, f" (it names {database})" if database else "",
                    moved.name)

    # -- operations for the API ------------------------------------------------------------------
    def trigger(self, axis_id: int, requested_by: str | None):
        """Queue a manual cycle. :class:`WaitingCycleError` (with ``retry_after_s``, the
        length of the axis' last cycle) if one waits already."""
        with session_scope(self.factory) as s:
            config_repo.get_axis(s, axis_id)  # 404 before anything moves
        try:
            return self.scheduler.request(axis_id, "manual", requested_by)
        except WaitingCycleError as exc:
            exc.retry_after_s = self._cycle_length_s(axis_id)
            raise

    def _cycle_length_s(self, axis_id: int) -> float:
        try:
            with session_scope(self.factory) as s:
                _, rows = results_repo.list_measurements(s, axis_id, status="ok", limit=1)
        except StorageError:
            rows = []
        c = rows[0] if rows else None
        if c is not None and c.started_at is not None and c.finished_at is not None:
            return max((c.finished_at - c.started_at).total_seconds(), 1.0)
        return 30.0

    def axis_changed(self, axis: AxisRecord) -> None:
        self.status.invalidate(axis.id)
        self.executor.remember(axis)
        if self.settings.scheduler_enabled:
            self.scheduler.schedule(axis)
        # an interface that describes the axes (MTConnect's device model) follows at once
        self.events.publish(Event("axis_changed", axis.id, axis.machine_name, axis.name, utcnow()))

    def db_ok(self) -> bool:
        try:
            with session_scope(self.factory) as s:
                s.execute(text("SELECT 1"))
            return True
        except StorageError:
            return False


_SECRET_WORDS = ("password", "passwd", "pwd", "pass", "secret", "token", "key", "auth", "credential")


def _restrict(path: Path, mode: int) -> None:
    """chmod ``path`` to ``mode`` when it is more open (logged; a failure is only logged)."""
    try:
        current = path.stat().st_mode & 0o777
        if current & ~mode:
            os.chmod(path, mode)
            log.info("%s: mode %o -> %o", path, current, mode)
    except OSError as exc:
        log.warning("could not restrict %s to mode %o: %s", path, mode, exc)


def redact_secrets(url: str) -> str:
    """``url`` with every password-like part replaced by ``***``: the user info's password,
    query parameters and fragment parameters named like a secret (``?password=``,
    ``sslpassword``, ``api_key``...)."""
    try:
        parts = urlsplit(url)
    except ValueError:
        return "***"
    netloc = parts.netloc
    if "@" in netloc:
        creds, host = netloc.rsplit("@", 1)
        if ":" in creds:
            netloc = f"{creds.split(':', 1)[0]}:***@{host}"

    def clean(qs: str) -> str:
        if not qs:
            return qs
        pairs = parse_qsl(qs, keep_blank_values=True)
        return urlencode([(k, "***" if any(w in k.lower() for w in _SECRET_WORDS) else v) for k, v in pairs],
                         safe="*")

    # urlunsplit would drop the empty authority of sqlite:///path (sqlite://path names a host)
    out = f"{parts.scheme}:" + ("//" + netloc if netloc or url[len(parts.scheme) + 1:].startswith("//") else "")
    out += parts.path
    if parts.query:
        out += "?" + clean(parts.query)
    if parts.fragment:
        out += "#" + clean(parts.fragment)
    return out
