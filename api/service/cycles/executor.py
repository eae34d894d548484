"""One measurement cycle from request to stored result, and the on-disk spool.

Order of writes, so that a measurement is never lost:
1. the raw round trip goes to the axis' dataset folder ``datasets/machine-<id>_axis-<id>``
   (``storage.dataset.append_runs``: CSV and dataset.json each written to a temporary
   file, fsynced and renamed, under the folder's lock), only if the folder records the
   axis as its owner (a folder of another database's axis of the same ids is moved
   aside first, see ``folders``);
2. a spool file (``<data_dir>/spool/<uuid>.json``) records the cycle's metadata (fsynced);
3. cycle, result, curves, TBE and alert change are saved in one transaction, durable
   when it returns (SQLite ``synchronous=FULL``; PostgreSQL ``synchronous_commit=on``);
4. the spool file is deleted.
If the database is down at step 3, the spool file stays and :meth:`CycleExecutor.replay_spool`
inserts it when the database is back (re-analysing the raw run from the dataset folder).
Saving is idempotent on the cycle's uuid, so a crash between 3 and 4 stores it once.
If the raw run cannot be written to the dataset folder, it is kept as
``<data_dir>/unfiled/<uuid>.npz`` instead; if that fails too, the cycle is stored with
``raw_run_lost`` (the reason), which the status, a ``raw_run_lost`` alert and the
``mebm_raw_runs_lost_total`` metric show.

A full disk: ``<data_dir>/spool/.reserve`` (``storage.spool_reserve_mb``) is allocated
while there is room. When a spool file meets ENOSPC the reserve is released and the
spool file written in its place; a cycle whose raw run found no room either carries its
trace in the spool file. Such a cycle is recorded with the reason code ``storage_full``
(its ``failure_reason`` starts with ``storage_full:``), shown so while it waits
(:meth:`CycleExecutor.held`) and stored when there is room again (re-analysed from its
trace). The reserve is allocated again once the spool is empty.

The second and later full disks in a row (the reserve already spent): spool slots,
``<data_dir>/spool/.slot-<i>`` (``storage.spool_slots`` files of ``storage.spool_slot_mb``),
written while there was room. A spool file that finds no room is written *into* a slot in
place (its blocks are the slot's already: no allocation), truncated to its length, fsynced
and renamed to ``<uuid>.json``: an ordinary spool file from then on, found by a restart,
also after a kill. A trace too large for a slot is left out (the cycle is then recorded
with ``raw_run_lost``, which says why). Slots are written again once there is room. Only
with every slot taken is a cycle kept in memory, retried with the spool and written to the
spool at stop; its record (uuid, axis, times, status, reason; no measurement) is then
written in place into the loss ledger ``<data_dir>/spool/.ledger`` (preallocated records of
512 bytes, written with the slots), so that a kill does not lose it without a trace: the
next start stores each ledger record the spool does not hold as a failed cycle with the
reason ``storage_full: lost: ...`` and a lost raw run, and lists it in its report.
Temporary files are renamed into place only after a successful fsync and removed on failure.
"""

from __future__ import annotations

import base64
import contextlib
import errno
import fcntl
import io
import json
import logging
import math
import os
import shutil
import tempfile
import threading
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path

import numpy as np

from api.service.cycles.folders import (
    axis_folders,
    axis_owner,
    claim_folder,
    dataset_folder_name,
    judge_folder,
    migrate_legacy_folders,
)
from api.service.cycles.runner import CycleOutcome, CycleRunner, analyse
from core.dataset import MachineSpec, Run, RunSpec
from core.criteria.roundtrip import with_history_uncertainty
from core.errors import MebmError
from core.history import TemperatureModel, history_uncertainty
from core.tbe import AxisDecision, MachiningTask, decide
from storage.dataset import (
    FolderOwnerError,
    append_runs,
    dataset_lock,
    fsync_dir,
    next_run_name,
    read_dataset,
    read_run_csv,
)
from storage.db import (
    AlertRecord,
    AxisRecord,
    CycleRecord,
    DatabaseUnavailableError,
    FinishedCycle,
    StorageError,
    as_utc,
    config_repo,
    maintenance_repo,
    results_repo,
    session_scope,
    utcnow,
)

log = logging.getLogger("mebm.cycles")

STORAGE_FULL = results_repo.STORAGE_FULL  # reason code: the cycle found no room under the data folder
LEDGER_RECORDS = 128  # the loss ledger: records of cycles that found no spool slot...
LEDGER_RECORD_BYTES = 512  # ...each this long (JSON, zero-padded; a zero first byte is a free record)
_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
_FULL_WORDS = ("no space left", "disk is full", "database or disk is full", "disk quota exceeded")
FREE_SPACE_HINT = ("free space under the data folder (old raw runs, other files on that disk) or raise its "
                   "quota; the kept cycle is then stored within scheduler.spool_retry_s, or at the next start")


def disk_full(exc: BaseException | None) -> bool:
    """Whether the error ``exc`` (or what caused it) says the disk or quota is full (a cycle's
    recorded reason says so by :func:`storage.db.results_repo.is_storage_full`)."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, OSError) and exc.errno in _FULL_ERRNOS:
            return True
        if any(w in str(exc).lower() for w in _FULL_WORDS):
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False


def storage_full_reason(detail: str) -> str:
    return f"{STORAGE_FULL}: {detail}; {FREE_SPACE_HINT}"


def _encode(a) -> str:
    return base64.b64encode(np.ascontiguousarray(np.asarray(a, dtype="<f8")).tobytes()).decode("ascii")


def _decode(s: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(s), dtype="<f8").copy()


def write_durably(path: Path, data: bytes) -> None:
    """``data`` as ``path``: written to a temporary name in the same folder, fsynced, renamed
    over ``path`` and the folder fsynced. The temporary file is removed on any failure, so
    a full disk leaves no empty or partial file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_dir(path.parent)


@dataclass(frozen=True)
class CycleRequest:
    uuid: str
    axis_id: int
    trigger: str
    requested_at: datetime
    requested_by: str | None = None


def utility_day(axis: AxisRecord, when: datetime) -> float:
    """Days in service (since the axis was put under monitoring), as in Table 2."""
    since = axis.settings.in_service_since or when
    return round(max((when - since).total_seconds(), 0.0) / 86400.0, 4)


def make_decision(axis: AxisRecord, tasks, backlash_um: float,
                  backlash_uncertainty_um: float = 0.0) -> AxisDecision | None:
    """The maintenance decision by the axis' decision rule, or None without tasks or when
    the TBE model cannot be evaluated at this backlash for some task (the measurement
    is stored all the same). ``backlash_uncertainty_um``: expanded, k = 2."""
    if not tasks:
        return None
    try:
        return decide(max(backlash_um, 0.0), tasks, warning_fraction=axis.settings.warning_fraction,
                      backlash_uncertainty_um=backlash_uncertainty_um, rule=axis.settings.decision_rule)
    except MebmError as exc:
        log.warning("axis %s: no decision at b = %.1f µm: %s", axis.id, backlash_um, exc)
        return None


def _expanded(rt) -> float:
    """Expanded uncertainty of b̄ of a round trip (0 for one stored without a budget)."""
    return rt.backlash_mean_uncertainty_um if rt.budgets else 0.0


def _sampling_bound_um(rt) -> float:
    """The sampling bound (skew x speed) a round trip was analysed with, for its replay."""
    if rt is None or not rt.budgets:
        return 0.0
    c = next((c for c in rt.budgets["backlash_mean"].components if c.name == "sampling"), None)
    return 0.0 if c is None else c.standard_um * math.sqrt(3.0)


def _task_doc(t: MachiningTask) -> dict:
    return {"name": t.name, "profile": t.profile, "feed_mm_min": t.feed_mm_min, "gain_per_s": t.gain_per_s,
            "tolerance_um": t.tolerance_um, "radius_mm": t.radius_mm, "angle_deg": t.angle_deg}


def _fin(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


class CycleExecutor:
    """Runs cycles for the scheduler and stores them (see the module docstring)."""

    def __init__(self, factory, data_dir: Path, runner: CycleRunner, resolve_url, *, on_saved=None, status=None,
                 reserve_bytes: int = 0, min_free_bytes: int = 0, slots: int = 0, slot_bytes: int = 1 << 20):
        self.factory = factory
        self.data_dir = Path(data_dir)
        self.spool_dir = self.data_dir / "spool"
        self.datasets_dir = self.data_dir / "datasets"
        self.unfiled_dir = self.data_dir / "unfiled"
        self.reserve_path = self.spool_dir / ".reserve"
        self.reserve_bytes = max(int(reserve_bytes), 0)
        self.slot_paths = [self.spool_dir / f".slot-{i}" for i in range(max(int(slots), 0))]
        self.slot_bytes = max(int(slot_bytes), 1)
        self.ledger_path = self.spool_dir / ".ledger"
        self._slot_lock = threading.Lock()  # a slot is written, or written again, by one thread at a time
        self._ledger_lock = threading.Lock()
        self.lost: list[str] = []  # one line per ledger record stored as a lost cycle (for the start report)
        self._ledgered: dict[str, int] = {}  # uuid -> its loss-ledger record, written by this process
        self.min_free_bytes = max(int(min_free_bytes), 0)  # below it, no cycle is started
        self.runner = runner
        self.resolve_url = resolve_url
        self.on_saved = on_saved or (lambda axis_id, cycle, alerts: None)
        # the status cache (api.service.status.StatusCache): the new status is computed in
        # the transaction that stores a cycle and published after its commit
        self.status = status
        self._axes: dict[int, AxisRecord] = {}  # last known settings, for cycles during a DB outage
        self._spool_lock = threading.Lock()  # guards _in_flight and unsaved
        self._replay_lock = threading.Lock()
        self._in_flight: set[str] = set()  # uuids being finished by execute(): replay leaves them
        self.unsaved: list[FinishedCycle] = []  # neither spooled nor stored: retried with the spool
        self._unspooled: dict[str, dict] = {}  # uuid -> the spool document of an unsaved cycle, written at stop
        self._held: dict[str, tuple[str, str | None]] = {}  # uuid -> (status, reason): finished, not stored yet
        self._spool_refused_full: set[str] = set()  # uuids whose spool file met a full disk
        self._moved: dict[Path, Path] = {}  # legacy dataset folder -> its id-named successor
        self._verdicts: dict[str, tuple] = {}  # folder -> ((mtime, size, axis uuid), Verdict) for readers
        if status is not None:
            status.held = self.held
        # fleet (api.service.cycles.leases): (request, start time) -> whether this worker may run it; None: it may
        self.claim = None

    def migrate_folders(self, axes) -> None:
        """Rename or split the name-based dataset folders of older versions (see ``folders``)."""

        def owners(uuids: list[str]) -> dict[str, int]:
            with session_scope(self.factory) as s:
                return results_repo.axis_of_cycles(s, uuids)

        self._moved.update(migrate_legacy_folders(self.datasets_dir, axes, owners))

    def _cycles_of(self, axis: AxisRecord):
        def mine(uuids: list[str]) -> set[str]:
            with session_scope(self.factory) as s:
                return {u for u, a in results_repo.axis_of_cycles(s, uuids).items() if a == axis.id}

        return mine

    def claim_folders(self, axes) -> list[str]:
        """Adopt or move aside each axis' dataset folders that do not record it as owner
        (see ``folders``); returns one line per folder moved aside, for the start report.
        A folder that cannot be read is left as it is (logged): appends to it are refused."""
        lines = []
        for axis in axes:
            for folder in axis_folders(self.datasets_dir, axis):
                try:
                    moved = self.claim_folder(axis, folder)
                except (MebmError, OSError) as exc:
                    log.error("dataset folder %s could not be checked (%s): left as it is; axis %s appends no "
                              "run to it until its dataset.json can be read", folder, exc, axis.id)
                    continue
                if moved is not None:
                    lines.append(f"dataset folder {folder.name} moved aside to {moved[0].name}: {moved[1]}")
        return lines

    def claim_folder(self, axis: AxisRecord, folder: Path) -> tuple[Path, str] | None:
        moved = claim_folder(folder, axis, self._cycles_of(axis))
        if moved is not None:  # (not in _moved: a spooled cycle's run is in the axis' own folder at that name)
            self._verdicts.pop(str(folder), None)
        return moved

    def readable_folder(self, axis: AxisRecord) -> Path:
        """The axis' dataset folder for a reader of its runs (the gap diagnosis), checked to
        be the axis' own (see ``folders``; the verdict is kept until dataset.json changes).
        Raises FolderOwnerError for a folder another machine's or axis' runs are in."""
        folder = self.dataset_folder(axis)
        try:
            st = (folder / "dataset.json").stat()
        except OSError:
            return folder  # no runs: the reader says so
        stamp = (st.st_mtime_ns, st.st_size, axis.uuid)
        kept = self._verdicts.get(str(folder))
        if kept is None or kept[0] != stamp:
            kept = (stamp, judge_folder(folder, axis, self._cycles_of(axis)))
            self._verdicts[str(folder)] = kept
        verdict = kept[1]
        if verdict.kind == "foreign":
            raise FolderOwnerError(
                f"is not axis {axis.id}'s ({axis.machine_name}/{axis.name}): {verdict.reason}. Its runs are not "
                "used; restart the service to move it aside (or move it yourself), or run it on the database it "
                "belongs to", source=str(folder))
        return folder

    # -- the cycle ---------------------------------------------------------------------------
    def remember(self, axis: AxisRecord) -> None:
        self._axes[axis.id] = axis

    def known_axis(self, axis_id: int) -> AxisRecord | None:
        """The axis as last read (no database access), or None."""
        return self._axes.get(axis_id)

    def _axis(self, axis_id: int) -> AxisRecord:
        try:
            with session_scope(self.factory) as s:
                axis = config_repo.get_axis(s, axis_id)
            self._axes[axis_id] = axis
            return axis
        except DatabaseUnavailableError:
            if axis_id in self._axes:
                return self._axes[axis_id]
            raise

    def execute(self, req: CycleRequest) -> CycleRecord | None:
        """Run and store one cycle. Never raises for a failed measurement or a database
        outage (the cycle is then spooled); returns the stored cycle or None if spooled."""
        axis = self._axis(req.axis_id)
        started = utcnow()
        if self.claim is not None:
            if not self.claim(req, started):  # another worker runs it, or this one lost the axis
                return None
        refusal = self.storage_refusal()
        if refusal is not None:
            return self._refuse(axis, req, started, refusal)
        if self.claim is None:
            try:
                with session_scope(self.factory) as s:
                    results_repo.mark_running(s, req.uuid, started)
            except StorageError as exc:
                log.warning("cycle %s: could not mark running (%s); measuring anyway", req.uuid, exc)
        try:
            outcome = self.runner(axis, self.resolve_url(axis))
        except Exception as exc:  # noqa: BLE001 - a broken runner must not stop the schedule
            log.exception("cycle %s on axis %s: runner crashed", req.uuid, axis.id)
            outcome = CycleOutcome.failed(f"internal error in the cycle runner: {type(exc).__name__}: {exc}")
        finished = utcnow()
        with self._spool_lock:
            self._in_flight.add(req.uuid)
        try:
            return self._finish(axis, req, outcome, started, finished)
        except Exception as exc:  # noqa: BLE001 - never leave a cycle "running" because of a bug
            log.exception("cycle %s: could not be finished normally", req.uuid)
            reason = f"internal error while storing the cycle: {type(exc).__name__}: {exc}"
            lost = None
            if outcome.time_s is not None:
                kept = self._keep_trace(axis, req, outcome)
                reason += f"; the raw run is kept in {kept}" if kept else "; the raw run could not be kept"
                lost = None if kept else f"not kept after an internal error ({type(exc).__name__}: {exc})"
            fc = FinishedCycle(
                uuid=req.uuid, axis_id=axis.id, trigger=req.trigger, requested_by=req.requested_by, status="failed",
                requested_at=req.requested_at, started_at=started, finished_at=finished,
                failure_reason=reason, temperature_c=_fin(outcome.temperature_c), raw_run_lost=lost,
            )
            try:
                doc = self._spool_doc(fc, None, axis.tasks)
                return self._save(fc, self._write_spool(doc), doc=doc)
            except StorageError:
                log.exception("cycle %s: the failure could not be recorded", req.uuid)
                return None
        finally:
            with self._spool_lock:
                self._in_flight.discard(req.uuid)

    def free_bytes(self) -> int | None:
        for p in (self.data_dir, *self.data_dir.resolve().parents):
            with contextlib.suppress(OSError):
                return shutil.disk_usage(p).free
        return None

    def storage_refusal(self) -> str | None:
        """Why no cycle may start now (free disk under the floor), or None."""
        if self.min_free_bytes <= 0:
            return None
        free = self.free_bytes()
        if free is None or free >= self.min_free_bytes:
            return None
        return (f"{STORAGE_FULL}: no cycle started: free disk under the data folder is {free / 1e6:.1f} MB, below "
                f"the floor of {self.min_free_bytes / 1e6:.0f} MB (storage.min_free_disk_mb); free space under the "
                "data folder and the next scheduled or manual cycle runs")

    def _refuse(self, axis: AxisRecord, req: CycleRequest, started: datetime, reason: str) -> CycleRecord | None:
        """Record a cycle not started for lack of disk (cancelled, reason ``storage_full``;
        nothing was measured, so nothing is spooled)."""
        log.error("cycle %s on axis %s: %s", req.uuid, axis.id, reason)
        fc = FinishedCycle(uuid=req.uuid, axis_id=axis.id, trigger=req.trigger, requested_by=req.requested_by,
                           status="cancelled", requested_at=req.requested_at, started_at=None, finished_at=started,
                           failure_reason=reason)
        try:
            with session_scope(self.factory) as s:
                cycle, alerts = results_repo.save_finished_cycle(s, fc)
                publish = self._prepare_status(s, fc.axis_id)
        except StorageError as exc:
            log.error("cycle %s: the refusal could not be recorded (%s)", req.uuid, exc)
            return None
        self._notify(fc.axis_id, cycle, alerts, publish)
        return cycle

    def _finish(self, axis: AxisRecord, req: CycleRequest, outcome: CycleOutcome, started: datetime,
                finished: datetime) -> CycleRecord | None:
        run_file, folder, note, trace_file, lost, full = None, None, None, None, None, False
        if outcome.time_s is not None:
            try:
                try:
                    folder, run_file = self._write_run(axis, outcome, req, finished)
                except (MebmError, OSError) as exc:
                    if not (disk_full(exc) and self.release_reserve()):
                        raise
                    full = True  # the reserve makes room for the raw run (and the spool file) once
                    log.error("cycle %s: the disk is full (%s); the spool reserve (%s) was released to keep the "
                              "cycle; %s", req.uuid, exc, self.reserve_path, FREE_SPACE_HINT)
                    folder, run_file = self._write_run(axis, outcome, req, finished)
            except (MebmError, OSError) as exc:
                full = full or disk_full(exc)
                trace_file = self._keep_trace(axis, req, outcome)
                kept = f"kept in {trace_file}" if trace_file else "and it could not be kept anywhere else"
                note = f"raw run not written to the dataset folder ({exc}); {kept}"
                if trace_file is None:
                    lost = f"not written to the dataset folder ({exc}) nor to {self.unfiled_dir}"
                log.error("cycle %s: %s", req.uuid, note)
        decision = None
        if outcome.ok and outcome.round_trip is not None:
            rt = self._with_history(axis, outcome.round_trip, outcome.temperature_c, finished)
            if rt is not outcome.round_trip:
                outcome = replace(outcome, round_trip=rt, uncertainty_um=rt.budgets["backlash_mean"].combined_um)
            decision = make_decision(axis, axis.tasks, outcome.round_trip.backlash.mean_um,
                                     _expanded(outcome.round_trip))
        reason = outcome.reason if not outcome.ok else None
        if note and not outcome.ok:
            reason = f"{reason}; {note}"
        fc = FinishedCycle(
            uuid=req.uuid, axis_id=axis.id, trigger=req.trigger, requested_by=req.requested_by,
            status="ok" if outcome.ok else "failed", requested_at=req.requested_at, started_at=started,
            finished_at=finished, failure_reason=reason, temperature_c=_fin(outcome.temperature_c),
            utility_day=utility_day(axis, finished), uncertainty_um=_fin(outcome.uncertainty_um), run_file=run_file,
            round_trip=outcome.round_trip if outcome.ok else None, decision=decision, raw_run_lost=lost,
        )
        trace = None
        if outcome.time_s is not None and run_file is None and trace_file is None:  # only the spool can keep it
            trace = {"time_s": outcome.time_s, "motor_rev": outcome.motor_rev, "table_mm": outcome.table_mm}
        if full:
            fc = replace(fc, failure_reason=self._full_reason(fc, note or (
                "the disk under the data folder was full when the cycle finished; its raw run was written to the "
                f"room of the spool reserve ({self.reserve_path}), which is allocated again once there is space")))
        doc = self._spool_doc(fc, folder, axis.tasks, trace_file=trace_file, trace=trace)
        return self._save(fc, self._write_spool(doc), doc=doc)

    @staticmethod
    def _full_reason(fc: FinishedCycle, note: str | None) -> str:
        if results_repo.is_storage_full(fc.failure_reason):
            return fc.failure_reason
        what = note or "the disk under the data folder was full when the cycle finished"
        if fc.status != "ok" and fc.failure_reason:
            what = f"{fc.failure_reason}; {what}" if note is None or note not in fc.failure_reason else fc.failure_reason
        return storage_full_reason(what)

    def _with_history(self, axis: AxisRecord, rt, temperature_c: float | None, finished: datetime):
        """``rt`` with the history's budget components (repeatability at similar temperature,
        the 20 °C normalisation); unchanged without a temperature, a history, or a database."""
        if temperature_c is None or not math.isfinite(temperature_c) or not rt.budgets:
            return rt
        try:
            with session_scope(self.factory) as s:
                sums = results_repo.backlash_history(s, axis.id)
                t, b = results_repo.recent_at_temperature(  # the repeatability of the chain as it is since its last repair
                    s, axis.id, temperature_c, before=finished, since=maintenance_repo.last_repair_at(s, axis.id))
        except StorageError as exc:
            log.info("axis %s: no history for the budget (%s)", axis.id, exc)
            return rt
        beta = u_beta = None
        if sums.n >= 3 and sums.x_max - sums.x_min >= 1.0:
            try:
                model = TemperatureModel().fit_sums(sums)
                beta, u_beta = model.beta_um_per_k_, model.beta_uncertainty_um_per_k_
            except MebmError:
                pass
        # the axis' thermometer at this temperature (rectangular), as in the b̄ budget's temperature component
        u_t = axis.settings.instruments.inputs(temperature_c=temperature_c).thermometer_bound_c() / math.sqrt(3.0)
        comps = history_uncertainty(temperature_c, t, b, beta_um_per_k=beta, beta_uncertainty_um_per_k=u_beta or 0.0,
                                    thermometer_uncertainty_k=u_t)
        return with_history_uncertainty(rt, comps)

    def _save(self, fc: FinishedCycle, spool: Path | None, *, doc: dict | None = None) -> CycleRecord | None:
        try:
            with session_scope(self.factory) as s:
                cycle, alerts = results_repo.save_finished_cycle(s, fc)
                publish = self._prepare_status(s, fc.axis_id)
        except DatabaseUnavailableError as exc:
            spool_full = doc is not None and doc["uuid"] in self._spool_refused_full
            if doc is not None and (disk_full(exc) or spool_full) and not results_repo.is_storage_full(
                    fc.failure_reason):
                # the database found no room either (SQLite under the data folder): the true reason
                fc = replace(fc, failure_reason=self._full_reason(
                    fc, f"the database could not store the cycle ({exc})" if disk_full(exc) else None))
                doc = {**doc, "failure_reason": fc.failure_reason}
                spool = self._write_spool(doc) or spool
            self._held[fc.uuid] = (fc.status, fc.failure_reason)
            if self.status is not None:
                self.status.invalidate(fc.axis_id)  # shown finished, with its reason, not running
            if spool is None:
                log.error("cycle %s could not be spooled and the database is down (%s): kept in memory, "
                          "retried with the spool and written to the spool at stop; %s", fc.uuid, exc,
                          FREE_SPACE_HINT)
                with self._spool_lock:
                    if all(u.uuid != fc.uuid for u in self.unsaved):
                        self.unsaved.append(fc)
                    if doc is not None:
                        self._unspooled[fc.uuid] = doc
            elif results_repo.is_storage_full(fc.failure_reason):
                log.error("cycle %s kept in the spool (%s): the disk is full; %s", fc.uuid, exc, FREE_SPACE_HINT)
            else:
                log.warning("cycle %s kept on disk (%s): it is stored when the database is back", fc.uuid, exc)
            return None
        self._held.pop(fc.uuid, None)
        self._spool_refused_full.discard(fc.uuid)
        self._forget_loss(fc.uuid)
        if spool is not None:
            spool.unlink(missing_ok=True)
        self._notify(fc.axis_id, cycle, alerts, publish)
        return cycle

    def _prepare_status(self, s, axis_id: int):
        """The status cache's publication of the axis' new status, computed in ``s`` (a
        savepoint: a failing read leaves the cycle's transaction usable); None if there is
        no cache or it failed (the status is then recomputed on its next use)."""
        if self.status is None:
            return None
        try:
            with s.begin_nested():
                return self.status.prepare(s, axis_id)
        except Exception:  # noqa: BLE001 - the cycle is stored all the same
            log.exception("axis %s: the new status could not be computed with the cycle", axis_id)
            return None

    def _notify(self, axis_id: int, cycle: CycleRecord, alerts: list[AlertRecord], publish=None) -> None:
        if publish is not None:
            publish()
        elif self.status is not None:
            self.status.invalidate(axis_id)
        for a in alerts:
            if a.active:
                log.warning("ALERT raised on axis %s: %s", axis_id, a.message)
            else:
                log.warning("alert %s on axis %s cleared", a.id, axis_id)
        try:
            self.on_saved(axis_id, cycle, alerts)
        except Exception:  # noqa: BLE001 - a listener must not lose a cycle
            log.exception("on_saved listener failed")

    # -- raw runs ------------------------------------------------------------------------------
    def dataset_folder(self, axis: AxisRecord) -> Path:
        """The axis' folder, named by the database's ids (``machine-<id>_axis-<id>``): names
        can look alike once made file-system safe ("m a" and "m_a") or be renamed, ids do not."""
        return self.datasets_dir / dataset_folder_name(axis)

    def _write_run(self, axis: AxisRecord, out: CycleOutcome, req: CycleRequest, finished: datetime):
        """The raw round trip as a dataset run. Traces of failed cycles go to a sibling
        ``..._rejected`` folder: kept for diagnosis, never mistaken for measurements."""
        name = axis.name.lower()
        cols = {"time_s": np.asarray(out.time_s, float), f"{name}_motor_rev": np.asarray(out.motor_rev, float),
                f"{name}_table_mm": np.asarray(out.table_mm, float)}
        if out.command_mm is not None:
            cols[f"{name}_command_mm"] = np.asarray(out.command_mm, float)
        spec_axis = replace(axis.spec, name=name)
        machine = MachineSpec(id=axis.machine_name, axes={name: spec_axis})
        folder = self.dataset_folder(axis)
        if not out.ok:
            folder = folder.with_name(folder.name + "_rejected")
        claimed = stamped = False
        while True:
            try:
                with dataset_lock(folder):  # the name is picked and used by one writer at a time
                    return folder, self._append_run(folder, machine, axis, out, req, finished, name, cols)
            except FolderOwnerError:
                if claimed:
                    raise
                # not recorded as the axis': adopted if nothing in it is another's, else moved aside
                claimed = True
                self.claim_folder(axis, folder)
            except MebmError:
                if stamped:
                    raise
                # the axis' mechanics changed since the folder was started: begin a new one
                stamped = True
                folder = folder.with_name(f"{folder.name}@{finished:%Y%m%dT%H%M%S}")

    @staticmethod
    def _append_run(folder: Path, machine: MachineSpec, axis: AxisRecord, out: CycleOutcome, req: CycleRequest,
                    finished: datetime, name: str, cols: dict) -> str:
        """Append the run under a fresh name (the caller holds the folder's lock)."""
        file = next_run_name(folder, f"rt_{name}_{finished:%Y%m%dT%H%M%S}")
        temp = out.temperature_c if out.temperature_c is not None else float("nan")
        spec = RunSpec(
            file=file, kind="round_trip", axes=(name,),
            feed_mm_min=out.feed_mm_min or axis.settings.measure_feed_mm_min,
            temperature_c=temp if math.isfinite(temp) else 20.0,
            utility_day=utility_day(axis, finished),
            acceleration_mm_s2=out.acceleration_mm_s2 or axis.settings.measure_acceleration_mm_s2,
            extra={"cycle_uuid": req.uuid, "axis_id": axis.id, "measured_at": finished.isoformat(),
                   "temperature_measured": math.isfinite(temp), "cycle_status": "ok" if out.ok else "failed",
                   **({"trigger": out.trigger} if out.trigger else {}),
                   **({} if out.ok else {"failure_reason": out.reason or ""}),
                   **({"repeated_after": out.repeated_after} if out.repeated_after else {}),
                   # the bounds the run was analysed with, so a re-analysis of the file
                   # (mebm analyze, inputs_of_spec) states the same uncertainty
                   "instruments": axis.settings.instruments.to_dict(),
                   **({"skew_uncertainty_um": _sampling_bound_um(out.round_trip),
                       "clock_uncertainty_s": out.round_trip.clock_uncertainty_s} if out.round_trip is not None else {})},
        )
        append_runs(folder, machine, [Run(spec, cols)], owner=axis_owner(axis))
        return file

    def _keep_trace(self, axis: AxisRecord, req: CycleRequest, out: CycleOutcome) -> Path | None:
        """The raw trace as ``unfiled/<uuid>.npz`` when the dataset folder cannot take it."""
        try:
            self.unfiled_dir.mkdir(parents=True, exist_ok=True)
            path = self.unfiled_dir / f"{req.uuid}.npz"
            arrays = {"time_s": out.time_s, "motor_rev": out.motor_rev, "table_mm": out.table_mm}
            if out.command_mm is not None:
                arrays["command_mm"] = out.command_mm
            buf = io.BytesIO()
            np.savez(buf, axis=np.array(axis.name), **{k: np.asarray(v, float) for k, v in arrays.items()})
            write_durably(path, buf.getvalue())
            return path
        except (OSError, ValueError, TypeError) as exc:
            log.error("cycle %s: raw trace not kept either (%s)", req.uuid, exc)
            return None

    # -- spool -----------------------------------------------------------------------------------
    def _spool_doc(self, fc: FinishedCycle, folder: Path | None, tasks, *, trace_file: Path | None = None,
                   trace: dict | None = None) -> dict:
        doc = {
            "uuid": fc.uuid, "axis_id": fc.axis_id, "trigger": fc.trigger, "requested_by": fc.requested_by,
            "status": fc.status, "requested_at": fc.requested_at.isoformat(),
            "started_at": fc.started_at.isoformat() if fc.started_at else None,
            "finished_at": fc.finished_at.isoformat(), "failure_reason": fc.failure_reason,
            "temperature_c": fc.temperature_c, "utility_day": fc.utility_day, "uncertainty_um": fc.uncertainty_um,
            "sampling_bound_um": _sampling_bound_um(fc.round_trip),
            "clock_uncertainty_s": fc.round_trip.clock_uncertainty_s if fc.round_trip is not None else 0.0,
            "dataset_folder": str(folder) if folder else None, "run_file": fc.run_file,
            "trace_file": str(trace_file) if trace_file else None, "raw_run_lost": fc.raw_run_lost,
            "tasks": [_task_doc(t) for t in tasks],
        }
        if trace is not None:  # float64 little-endian, base64: the raw run had no room anywhere else
            doc["trace"] = {k: _encode(v) for k, v in trace.items()}
        return doc

    def _write_spool(self, doc: dict) -> Path | None:
        """The spool file of ``doc`` (fsynced), or None. On a full disk the reserve is
        released and the write tried once more."""
        data = json.dumps(doc).encode("utf-8")
        for attempt in (1, 2):
            try:
                self.spool_dir.mkdir(parents=True, exist_ok=True)
                path = self.spool_dir / f"{doc['uuid']}.json"
                write_durably(path, data)
                return path
            except OSError as exc:
                if attempt == 1 and disk_full(exc) and self.release_reserve():
                    log.error("cycle %s: the disk is full; the spool reserve (%s) was released to keep it",
                              doc["uuid"], self.reserve_path)
                    continue
                if disk_full(exc):
                    self._spool_refused_full.add(doc["uuid"])  # its reason is storage_full, kept in a slot or not
                    path = self._write_into_slot(doc)
                    if path is not None:
                        return path
                log.error("cycle %s: spool file not written (%s)", doc["uuid"], exc)
                return None
        return None

    def _write_into_slot(self, doc: dict) -> Path | None:
        """``doc`` written in place into a free spool slot and renamed to its spool file (see
        the module docstring); without its trace if that does not fit. None if no slot is free."""
        data = json.dumps(doc).encode("utf-8")
        if len(data) > self.slot_bytes and doc.get("trace"):
            why = (f"its raw trace ({len(data) / 1e6:.2f} MB with the record) did not fit a spool slot "
                   f"(storage.spool_slot_mb = {self.slot_bytes / 1e6:g}) on the full disk")
            doc = {**{k: v for k, v in doc.items() if k != "trace"},
                   "raw_run_lost": f"{doc.get('raw_run_lost') or 'not kept'}; {why}"}
            data = json.dumps(doc).encode("utf-8")
        if len(data) > self.slot_bytes:
            log.error("cycle %s: its spool file (%d bytes) is larger than a spool slot (%d bytes)", doc["uuid"],
                      len(data), self.slot_bytes)
            return None
        with self._slot_lock:
            return self._into_slot(doc, data)

    def _into_slot(self, doc: dict, data: bytes) -> Path | None:
        path = self.spool_dir / f"{doc['uuid']}.json"
        for slot in self.slot_paths:
            try:
                if slot.stat().st_size < self.slot_bytes:
                    continue  # not (fully) written: its blocks are not all there
                fd = os.open(slot, os.O_WRONLY)
            except OSError:
                continue
            try:
                # one writer per slot (cycles of other axes, another process on the folder): taken
                # while it is still the slot, held until it is renamed
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    if os.fstat(fd).st_ino != slot.stat().st_ino:
                        continue  # renamed by the writer before: no longer a slot
                except OSError:
                    continue
                os.pwrite(fd, data, 0)
                os.ftruncate(fd, len(data))
                os.fsync(fd)
                os.replace(slot, path)
                fsync_dir(self.spool_dir)
            except OSError as exc:
                log.error("cycle %s: spool slot %s could not be written (%s)", doc["uuid"], slot.name, exc)
                with contextlib.suppress(OSError):
                    slot.unlink()  # a half-written slot is no slot: written again once there is room
                continue
            finally:
                os.close(fd)
            log.error("cycle %s: the disk is full; its spool file was written into the spool slot %s (%d of %d "
                      "slots left); %s", doc["uuid"], slot.name, self.free_slots(), len(self.slot_paths),
                      FREE_SPACE_HINT)
            return path
        log.critical("cycle %s: the disk is full and all %d spool slots are taken (storage.spool_slots)%s",
                     doc["uuid"], len(self.slot_paths), "; its record is in the loss ledger " + str(self.ledger_path)
                     if self._record_loss(doc) else "")
        return None

    def _record_loss(self, doc: dict) -> bool:
        """The record of ``doc`` (no measurement) written in place into a free record of the
        loss ledger and fsynced; False if there is no ledger or no free record in it."""
        rec = {k: doc.get(k) for k in ("uuid", "axis_id", "trigger", "requested_by", "status", "requested_at",
                                       "started_at", "finished_at")}
        reason = doc.get("failure_reason") or ""
        data = json.dumps({**rec, "failure_reason": reason}).encode("utf-8")
        while len(data) >= LEDGER_RECORD_BYTES and reason:
            reason = reason[:max(len(reason) - (len(data) - LEDGER_RECORD_BYTES) - 8, 0)] + "..."
            data = json.dumps({**rec, "failure_reason": reason}).encode("utf-8")
        if len(data) >= LEDGER_RECORD_BYTES:
            return False
        with self._ledger_lock:
            try:
                with open(self.ledger_path, "r+b") as fh:
                    records = fh.read()
                    mine = self._ledgered.get(doc["uuid"])  # recorded already: its record is rewritten
                    for i in range(len(records) // LEDGER_RECORD_BYTES):
                        if i == mine or (mine is None and records[i * LEDGER_RECORD_BYTES] == 0):
                            os.pwrite(fh.fileno(), data.ljust(LEDGER_RECORD_BYTES, b"\0"), i * LEDGER_RECORD_BYTES)
                            os.fsync(fh.fileno())
                            self._ledgered[doc["uuid"]] = i
                            return True
            except OSError as exc:
                log.error("cycle %s: not recorded in the loss ledger either (%s)", doc["uuid"], exc)
        return False

    def _ledger_records(self) -> list[tuple[int, dict]]:
        """(index, record) of the loss ledger's records in use; unreadable ones are freed."""
        try:
            records = self.ledger_path.read_bytes()
        except OSError:
            return []
        out = []
        for i in range(len(records) // LEDGER_RECORD_BYTES):
            raw = records[i * LEDGER_RECORD_BYTES:(i + 1) * LEDGER_RECORD_BYTES]
            if raw[0] == 0:
                continue
            try:
                out.append((i, json.loads(raw.rstrip(b"\0").decode("utf-8"))))
            except ValueError:
                log.error("loss ledger record %d unreadable: freed", i)
                self._free_record(i)
        return out

    def _forget_loss(self, uuid: str) -> None:
        """The cycle of ``uuid`` was stored or spooled after all: its ledger record is freed."""
        i = self._ledgered.pop(uuid, None)
        if i is not None:
            self._free_record(i)

    def _free_record(self, i: int) -> None:
        with self._ledger_lock, contextlib.suppress(OSError), open(self.ledger_path, "r+b") as fh:
            os.pwrite(fh.fileno(), b"\0" * LEDGER_RECORD_BYTES, i * LEDGER_RECORD_BYTES)
            os.fsync(fh.fileno())

    def _replay_ledger(self) -> int:
        """Store each loss-ledger record whose cycle is neither in memory nor in the spool as
        a failed ``storage_full`` cycle that lost its measurement, then free the record."""
        stored = 0
        kept = {fc.uuid for fc in self.unsaved} | {p.stem for p in self.pending()}
        for i, d in self._ledger_records():
            if d.get("uuid") in kept:
                continue  # the cycle itself is still kept: stored from there
            try:
                ts = {k: as_utc(datetime.fromisoformat(d[k])) if d.get(k) else None
                      for k in ("requested_at", "started_at", "finished_at")}
                why = ("the disk under the data folder was full when the cycle finished and every spool slot was "
                       f"taken (storage.spool_slots); its measurement (status {d.get('status')}) was lost, this "
                       "record of it was kept")
                fc = FinishedCycle(
                    uuid=d["uuid"], axis_id=int(d["axis_id"]), trigger=d.get("trigger") or "schedule",
                    requested_by=d.get("requested_by"), status="failed", requested_at=ts["requested_at"],
                    started_at=ts["started_at"], finished_at=ts["finished_at"] or utcnow(),
                    failure_reason=storage_full_reason(f"lost: {why}" + (
                        f"; reason then: {d['failure_reason']}" if d.get("failure_reason") else "")),
                    raw_run_lost=why)
                with session_scope(self.factory) as s:
                    cycle, alerts = results_repo.save_finished_cycle(s, fc)
                    publish = self._prepare_status(s, fc.axis_id)
            except DatabaseUnavailableError:
                break  # kept for the next attempt
            except (StorageError, MebmError, KeyError, ValueError, TypeError) as exc:
                log.error("loss ledger record %d (%s) could not be stored: %s", i, d.get("uuid"), exc)
                continue
            self._free_record(i)
            self._ledgered.pop(fc.uuid, None)
            if cycle.failure_reason != fc.failure_reason:
                continue  # stored otherwise already (its spool file came first): nothing was lost
            self._held.pop(fc.uuid, None)
            self._notify(fc.axis_id, cycle, alerts, publish)
            line = (f"cycle {fc.uuid} (axis {fc.axis_id}, finished {d.get('finished_at')}) was lost on a full disk "
                    "with every spool slot taken: recorded failed, storage_full")
            log.error("%s", line)
            self.lost.append(line)
            stored += 1
        return stored

    def free_slots(self) -> int:
        """How many spool slots are written and free."""
        n = 0
        for slot in self.slot_paths:
            with contextlib.suppress(OSError):
                n += slot.stat().st_size >= self.slot_bytes
        return n

    # -- the reserve -----------------------------------------------------------------------------
    def ensure_reserve(self) -> bool:
        """Write the spool slots and the spool reserve that are missing (each written, fsynced
        and renamed into place; nothing is left on failure; each only while the disk has twice
        its size free). True if all are in place (or none is configured)."""
        ok = True
        ledger_bytes = LEDGER_RECORDS * LEDGER_RECORD_BYTES
        if self.slot_paths and not self._slot_ok(self.ledger_path, ledger_bytes):  # (one with records is kept)
            ok = self._allocate(self.ledger_path, ledger_bytes) and ok
        with self._slot_lock:
            for slot in self.slot_paths:
                if not self._slot_ok(slot):
                    ok = self._allocate(slot, self.slot_bytes) and ok
        if self.reserve_bytes > 0 and not self._slot_ok(self.reserve_path, self.reserve_bytes):
            ok = self._allocate(self.reserve_path, self.reserve_bytes) and ok
        return ok

    def _slot_ok(self, path: Path, size: int | None = None) -> bool:
        try:
            return path.stat().st_size >= (self.slot_bytes if size is None else size)
        except OSError:
            return False

    def _allocate(self, path: Path, nbytes: int) -> bool:
        free = self.free_bytes()
        if free is not None and free < 2 * nbytes:  # no room yet: taking it would fill the disk again
            log.debug("%s not allocated yet: %d bytes free", path.name, free)
            return False
        tmp = path.with_name(path.name + ".tmp")
        try:
            self.spool_dir.mkdir(parents=True, exist_ok=True)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                block = b"\0" * (1 << 20)
                left = nbytes
                while left > 0:  # written, not only fallocated: every block is the file's for sure
                    n = os.write(fd, block[:min(left, len(block))])
                    left -= n
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, path)
            fsync_dir(self.spool_dir)
            return True
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            log.warning("the spool reserve %s (%d bytes) could not be allocated (%s): a cycle that finishes on a "
                        "full disk may be kept in memory only until the stop; %s", path, nbytes, exc,
                        FREE_SPACE_HINT)
            return False

    def release_reserve(self) -> bool:
        """Delete the reserve (room for spool files); False if there was none."""
        try:
            self.reserve_path.unlink()
        except OSError:
            return False
        with contextlib.suppress(OSError):
            fsync_dir(self.spool_dir)
        return True

    def reserve_ok(self) -> bool:
        """Whether the reserve and every spool slot are in place."""
        return (self.reserve_bytes <= 0 or self._slot_ok(self.reserve_path, self.reserve_bytes)) and all(
            self._slot_ok(p) for p in self.slot_paths) and (not self.slot_paths or self._slot_ok(
                self.ledger_path, LEDGER_RECORDS * LEDGER_RECORD_BYTES))

    def held(self) -> dict[str, tuple[str, str | None]]:
        """uuid -> (status, reason) of the finished cycles not stored yet (spooled or in memory)."""
        return dict(self._held)

    def flush_unsaved(self) -> int:
        """At stop: write the memory-kept cycles to the spool (the reserve is released if the
        disk is full); returns how many are still only in memory (logged: lost at exit)."""
        with self._spool_lock:
            for fc in list(self.unsaved):
                doc = self._unspooled.get(fc.uuid)
                if doc is None:
                    doc = self._spool_doc(fc, None, ())
                if self._write_spool(doc) is not None:
                    self.unsaved.remove(fc)
                    self._unspooled.pop(fc.uuid, None)
                    self._forget_loss(fc.uuid)
            left = list(self.unsaved)
        for fc in left:
            log.critical("cycle %s could not be written to the spool at stop and is lost when the service exits: "
                         "%s", fc.uuid, FREE_SPACE_HINT)
        return len(left)

    def pending(self) -> list[Path]:
        return sorted(self.spool_dir.glob("*.json")) if self.spool_dir.is_dir() else []

    def has_pending(self) -> bool:
        return bool(self.unsaved) or bool(self.pending()) or bool(self._ledger_records())

    def replay_spool(self) -> int:
        """Store every spooled (or memory-kept) cycle the database does not have yet, then
        the loss ledger's records; returns how many were stored. Stops at the first database
        outage (retried later). The reserve is allocated again once nothing waits."""
        with self._replay_lock:  # start-up and the retry job never replay at once
            stored = self._replay()
            stored += self._replay_ledger()
        if not self.has_pending():
            self.ensure_reserve()
        return stored

    def _hold_rest(self, paths: list[Path]) -> None:
        """Note the spooled cycles the replay could not store, for :meth:`held`."""
        for path in paths:
            try:
                d = json.loads(path.read_text(encoding="utf-8"))
                self._held.setdefault(d["uuid"], (d["status"], d.get("failure_reason")))
            except (OSError, ValueError, KeyError, TypeError):
                continue

    def _replay(self) -> int:
        stored = 0
        with self._spool_lock:
            for fc in list(self.unsaved):
                try:
                    if self._save_unlocked(fc) is None:
                        return stored
                except StorageError as exc:
                    log.error("cycle %s kept in memory could not be stored: %s", fc.uuid, exc)
                    continue
                self.unsaved.remove(fc)
                self._unspooled.pop(fc.uuid, None)
                self._held.pop(fc.uuid, None)
                self._spool_refused_full.discard(fc.uuid)
                self._forget_loss(fc.uuid)
                stored += 1
        pending = self.pending()
        for i, path in enumerate(pending):
            if path.stem in self._in_flight:
                continue  # execute() is storing it right now (saving is idempotent all the same)
            try:
                fc = self._from_spool(path)
            except DatabaseUnavailableError:
                self._hold_rest(pending[i:])
                break  # the file stays for the next attempt
            except Exception as exc:  # noqa: BLE001 - one bad file must not block the others or the start
                log.error("spool file %s unreadable (%s): moved aside as .bad", path.name, exc)
                with contextlib.suppress(OSError):
                    path.rename(path.with_suffix(".bad"))
                continue
            try:
                if self._save(fc, path) is None:
                    self._hold_rest(pending[i + 1:])
                    break
            except StorageError as exc:
                log.error("spooled cycle %s could not be stored: %s", path.name, exc)
                continue
            stored += 1
        return stored

    def _save_unlocked(self, fc: FinishedCycle) -> CycleRecord | None:
        """Save a memory-kept cycle (the caller holds the spool lock)."""
        try:
            with session_scope(self.factory) as s:
                cycle, alerts = results_repo.save_finished_cycle(s, fc)
                publish = self._prepare_status(s, fc.axis_id)
        except DatabaseUnavailableError:
            return None
        self._notify(fc.axis_id, cycle, alerts, publish)
        return cycle

    def _from_spool(self, path: Path) -> FinishedCycle:
        d = json.loads(path.read_text(encoding="utf-8"))
        axis = self._axis(int(d["axis_id"]))
        rt = decision = None
        status, reason = d["status"], d["failure_reason"]
        kept = None
        if d.get("trace"):  # the raw run found no room when measured: kept now that there is
            kept = self._keep_embedded(axis, d)
            if kept is not None:
                d = {**d, "trace_file": str(kept), "raw_run_lost": None}
                if reason:
                    reason = f"{reason}; the raw run is kept in {kept}"
        if status == "ok":
            try:
                time_s, motor_rev, table_mm = self._spooled_trace(d)
                temp = d.get("temperature_c")
                rt = analyse(axis, time_s, motor_rev, table_mm, uncertainty=axis.settings.instruments.inputs(
                    sampling_bound_um=d.get("sampling_bound_um") or 0.0,
                    clock_uncertainty_s=d.get("clock_uncertainty_s") or 0.0,
                    temperature_c=temp if isinstance(temp, (int, float)) and math.isfinite(temp) else None))
                tasks = [MachiningTask(**t) for t in d["tasks"]]
                decision = make_decision(axis, tasks, rt.backlash.mean_um, _expanded(rt))
            except DatabaseUnavailableError:
                raise
            except Exception as exc:  # noqa: BLE001 - recorded as the cycle's failure, never dropped
                status, reason = "failed", f"stored run could not be re-read after a database outage: {exc}"
        ts = {k: as_utc(datetime.fromisoformat(d[k])) if d.get(k) else None
              for k in ("requested_at", "started_at", "finished_at")}
        return FinishedCycle(
            uuid=d["uuid"], axis_id=axis.id, trigger=d["trigger"], requested_by=d.get("requested_by"), status=status,
            requested_at=ts["requested_at"], started_at=ts["started_at"], finished_at=ts["finished_at"],
            failure_reason=reason, temperature_c=d.get("temperature_c"), utility_day=d.get("utility_day"),
            uncertainty_um=d.get("uncertainty_um"), run_file=d.get("run_file"), round_trip=rt, decision=decision,
            raw_run_lost=d.get("raw_run_lost"),
        )

    def _keep_embedded(self, axis: AxisRecord, d: dict) -> Path | None:
        """The trace a spool file carries, as ``unfiled/<uuid>.npz`` (None if it cannot be)."""
        try:
            t = {k: _decode(v) for k, v in d["trace"].items()}
        except (KeyError, ValueError, TypeError, AttributeError):
            return None
        out = CycleOutcome(ok=d["status"] == "ok", time_s=t["time_s"], motor_rev=t["motor_rev"],
                           table_mm=t["table_mm"])
        req = CycleRequest(uuid=d["uuid"], axis_id=axis.id, trigger=d["trigger"], requested_at=utcnow())
        return self._keep_trace(axis, req, out)

    def _spooled_trace(self, d: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The raw trace of a spooled ok cycle: its run in the dataset folder (only that run
        is read, so a damaged neighbour does not matter) or its ``unfiled`` copy."""
        if d.get("dataset_folder") and d.get("run_file"):
            root = Path(d["dataset_folder"])
            root = self._moved.get(root, root)  # spooled before its folder was migrated
            ds = read_dataset(root, load_runs=False)
            spec = next((r.spec for r in ds.runs if r.spec.file == d["run_file"]), None)
            if spec is None:
                raise MebmError(f"run {d['run_file']!r} is not listed in {root}/dataset.json")
            run = Run(spec, read_run_csv(root / spec.file, spec))
            name = spec.axes[0]
            return run.time_s, run.motor_rev(name), run.table_mm(name)
        if d.get("trace_file"):
            with np.load(d["trace_file"]) as z:
                return z["time_s"], z["motor_rev"], z["table_mm"]
        if d.get("trace"):
            t = d["trace"]
            return _decode(t["time_s"]), _decode(t["motor_rev"]), _decode(t["table_mm"])
        raise MebmError("the raw run was not kept (neither in the dataset folder nor unfiled)")
