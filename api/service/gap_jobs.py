"""Gap diagnoses as bounded background jobs, computed in a separate process.

A diagnosis (core.gap) takes a quarter to half a minute for a full-size benchmark dataset
on a quiet 2-core machine, about a minute for the demo axis' 16 newest runs
(docs/gap-diagnosis.md, "Time"), and several minutes on a
dataset whose visible gap no single candidate explains (the two-together search: up to
620 s seen in the independent plant's benchmark, two diagnoses at a time), longer than an MES should
hold a request open, and it is pure Python/numpy/numba that holds the interpreter lock
while it runs.
Run on a thread of the service, it slowed every other request (a status poll waited
for the lock: p99 47 ms in the soak). So the jobs are queued here, one at a time, and
each is computed by a worker *process* (a ``spawn``-started pool of one, kept for the
next job): the service's threads stay free for the API and the cycles.

Every job has an id: a caller (the dashboard's gap page, an MES following the 202's
``Location``) follows *its* job by id, whatever is stored meanwhile.

Which runs (:func:`plan_runs`, a :class:`RunPlan`): the newest ``runs`` stored runs of the
axis *since its last recorded repair* (of any kind, a loaded compensation table among them):
runs on both sides of a repair are two machines, and one model fitted across them reads
the repair as an effect. The plan is fixed when the job is created: the count the page
shows while the job waits is the count it uses, and the report begins with the period
it covers (first and last run, utility days, the repair it starts after, the runs left
out before it).

Bounds (a read key must not be able to keep the server busy for minutes):

- one pending job per run set (the caller's key: folder, runs); asking again while it
  waits or runs returns the same job, even when a new run was stored meanwhile (its
  answer names the runs it used, and ``runs_stored_since`` how many came after);
- a finished answer is kept per run set and data version (``version``: dataset.json's
  mtime and size, and the axis' last repair), at most ``cache_size`` of them (small
  dicts; no runs);
- at most ``max_pending`` jobs wait or run; more raise :class:`TooManyJobs`;
- a job nobody has asked for within ``abandon_s`` is dropped before it starts
  (:class:`JobAbandoned`);
- a diagnosis running longer than ``timeout_s`` is stopped (its process ended and
  replaced) and fails with :class:`DiagnosisTimedOut`;
- a worker process that dies (killed, out of memory) fails its job with
  :class:`DiagnosisCrashed` and is replaced for the next one.

A crash or an abandoned job is not an answer: starting the run set again computes it
anew. A diagnosis' own error (a GapError: data it cannot use) and a time-out are kept for
their data version (``fresh`` computes them again).

The REST router and the dashboard both use one :class:`GapJobs` of the service.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from api.service.worker_process import IDLE_END_S, end_pool, spawn_pool
from core.dataset import Dataset, Run
from core.errors import InputError, MebmError
from core.gap import diagnose
from storage.dataset import read_dataset, read_run_csv
from storage.db import NotFoundError

log = logging.getLogger("mebm.gap")


class JobAbandoned(MebmError):
    """Nobody asked for the diagnosis within ``abandon_s``: it was not computed."""


class TooManyJobs(MebmError):
    """``max_pending`` diagnoses wait or run already; ``retry_after_s``: when the first of
    them is expected to end."""

    def __init__(self, pending: int, retry_after_s: float):
        self.pending = pending
        self.retry_after_s = max(int(round(retry_after_s)), 1)
        super().__init__(f"{pending} gap diagnoses are being computed, the most the service runs at once; "
                         f"the first is expected to end in about {self.retry_after_s} s: start this one again then")


class DiagnosisTimedOut(MebmError):
    """The diagnosis ran longer than ``timeout_s``: its process was ended."""


class DiagnosisCrashed(MebmError):
    """The worker process died during the diagnosis (killed, or out of memory)."""


def dataset_of(folder: Path, files: Sequence[str]) -> Dataset:
    """The dataset of the stored runs ``files`` of a folder, in that order, each run with
    its ``utility_day`` and ``temperature_c`` as stored (the diagnosis lets the backlash
    grow with the utility day). DatasetError when one of them is no longer stored."""
    from core.errors import DatasetError

    meta = read_dataset(folder, load_runs=False)
    specs = {r.spec.file: r.spec for r in meta.runs}
    gone = [f for f in files if f not in specs]
    if gone:
        raise DatasetError(f"run(s) {gone} of the diagnosis are no longer stored in {folder.name} (retention "
                           f"removed them): start the diagnosis again")
    runs = tuple(Run(specs[f], read_run_csv(folder / f, specs[f])) for f in files)
    return Dataset(meta.machine, runs, meta.extra)


class TooFewRuns(InputError):
    """Fewer than two stored runs since the axis' last repair: nothing to diagnose yet."""


MIN_RUNS = 2  # one to fit, one to test (core.gap refuses fewer)


@dataclass(frozen=True)
class StoredRun:
    """What the plan needs of one stored run: its file, when it was measured (None: not
    recorded), its utility day and whether its temperature was measured."""

    file: str
    measured_at: datetime | None
    utility_day: float | None
    temperature_measured: bool = True


@dataclass(frozen=True)
class Repair:
    """A recorded repair of the axis: its kind and when it was performed (UTC)."""

    kind: str
    performed_at: datetime
    id: int | None = None


@dataclass(frozen=True)
class RunPlan:
    """The runs a diagnosis uses, fixed before it starts, and the period they cover.

    ``files``: in measurement order. ``after_repair``: the last repair before them (None:
    none recorded); ``left_out``: stored runs measured before that repair (another state
    of the machine), ``untimed``: runs without a recorded measurement time, left out when
    a repair is recorded (they cannot be placed on either side of it);
    ``older``: runs of the period beyond the newest ``requested``. ``repairs_within``:
    repairs between the first and the last run used (none, by construction; kept in the
    answer so that a reader sees it said)."""

    files: tuple[str, ...]
    requested: int
    first_at: datetime | None = None
    last_at: datetime | None = None
    first_utility_day: float | None = None
    last_utility_day: float | None = None
    after_repair: Repair | None = None
    left_out: int = 0
    untimed: int = 0
    older: int = 0
    no_temperature: int = 0
    repairs_within: tuple[Repair, ...] = field(default=())

    @property
    def runs(self) -> int:
        return len(self.files)

    def to_dict(self) -> dict:
        """The period as the API's ``period`` (times ISO 8601 UTC, utility days in days)."""
        def at(t: datetime | None) -> str | None:
            return None if t is None else t.isoformat(timespec="seconds")

        def repair(r: Repair) -> dict:
            return {"kind": r.kind, "performed_at": at(r.performed_at)}

        return {"runs": self.runs, "requested": self.requested, "first_run_at": at(self.first_at),
                "last_run_at": at(self.last_at), "first_utility_day": self.first_utility_day,
                "last_utility_day": self.last_utility_day,
                "after_repair": repair(self.after_repair) if self.after_repair else None,
                "runs_before_repair_left_out": self.left_out, "runs_without_time_left_out": self.untimed,
                "older_runs_of_the_period": self.older, "runs_without_measured_temperature": self.no_temperature,
                "repairs_within": [repair(r) for r in self.repairs_within]}

    def payload(self) -> dict:
        """What the worker process gets (plain data: unpickling it imports nothing):
        ``files``, ``requested``, ``text`` and ``period``."""
        return {"files": list(self.files), "requested": self.requested, "text": self.text(), "period": self.to_dict()}

    def text(self) -> str:
        """The period in words: the report's first lines."""
        def at(t: datetime | None) -> str:
            return "an unrecorded time" if t is None else t.strftime("%Y-%m-%d %H:%M UTC")

        def day(d: float) -> str:
            return f"{d:.2f}"

        when = (f"measured {at(self.first_at)} to {at(self.last_at)}" if self.first_at and self.last_at
                else "measurement times not recorded")
        days = (f" (utility days {day(self.first_utility_day)} to {day(self.last_utility_day)})"
                if self.first_utility_day is not None and self.last_utility_day is not None else "")
        lines = [f"Runs used: {self.runs} stored run(s), {when}{days}."]
        if self.after_repair is not None:
            r = self.after_repair
            lines.append(f"All after the last recorded repair ({r.kind}, {at(r.performed_at)}): runs before a repair "
                         f"are another state of the axis and are not pooled with these; {self.left_out} run(s) before "
                         f"it left out" + (f", and {self.untimed} without a recorded time" if self.untimed else "")
                         + ".")
        else:
            lines.append("No repair is recorded for the axis: the runs are one period.")
        lines.append("Repairs within the period: none.")
        if self.older:
            lines.append(f"{self.older} older run(s) of the period not used (the newest {self.requested} are).")
        if self.no_temperature:
            lines.append(f"{self.no_temperature} run(s) without a measured temperature: taken at the measured runs' "
                         f"mean (not at the 20 °C stored in its place), so a thermal effect is judged on the others' "
                         f"temperatures.")
        return "\n".join(lines)


def _parse_time(v) -> datetime | None:
    if not isinstance(v, str):
        return None
    try:
        t = datetime.fromisoformat(v)
    except ValueError:
        return None
    return t if t.tzinfo is not None else t.replace(tzinfo=timezone.utc)


def plan_runs(stored: Sequence[StoredRun], requested: int, repairs: Sequence[Repair] = ()) -> RunPlan:
    """The newest ``requested`` of the ``stored`` runs (measurement order) measured after
    the last of ``repairs`` (each run's ``measured_at`` against the repair's
    ``performed_at``). TooFewRuns when fewer than two remain."""
    last = max(repairs, key=lambda r: r.performed_at, default=None)
    if last is None:
        period, left_out, untimed = list(stored), 0, 0
    else:
        period = [r for r in stored if r.measured_at is not None and r.measured_at > last.performed_at]
        untimed = sum(1 for r in stored if r.measured_at is None)
        left_out = len(stored) - len(period) - untimed
    used = period[-requested:]
    if len(used) < MIN_RUNS:
        since = (f" since the last recorded repair of the axis ({last.kind}, "
                 f"{last.performed_at:%Y-%m-%d %H:%M} UTC)" if last is not None else "")
        raise TooFewRuns(f"{len(used)} stored run(s){since}; a gap diagnosis needs at least {MIN_RUNS} (one to fit, "
                         f"one to test)" + (": runs before a repair are another state of the axis and are not pooled "
                                            "with the runs after it. Measure the axis again" if last is not None else
                                            ": measure the axis again"))
    times = [r.measured_at for r in used]
    return RunPlan(
        files=tuple(r.file for r in used), requested=requested, first_at=times[0], last_at=times[-1],
        first_utility_day=used[0].utility_day, last_utility_day=used[-1].utility_day, after_repair=last,
        left_out=left_out, untimed=untimed, older=len(period) - len(used),
        no_temperature=sum(1 for r in used if not r.temperature_measured),
        repairs_within=tuple(r for r in repairs if times[0] is not None and times[-1] is not None
                             and times[0] < r.performed_at < times[-1]))


def repairs_of(factory, axis_id: int) -> tuple[Repair, ...]:
    """The axis' recorded repairs, oldest first (read in a session of its own)."""
    from storage.db import maintenance_repo, session_scope

    with session_scope(factory) as s:
        return tuple(Repair(r.kind, r.performed_at, r.id) for r in maintenance_repo.list_repairs(s, axis_id))


RESIDUALS = "residuals"  # the test runs' residual curves, thinned: for the dashboard's plots, not the API's body


def public_body(result: dict) -> dict:
    """The API's body of a diagnosis (without the residual curves the dashboard plots),
    with ``age_s``: how long ago it was computed (a cached answer is served as it is)."""
    out = {k: v for k, v in result.items() if k != RESIDUALS}
    age = age_s(result)
    if age is not None:
        out["age_s"] = round(age, 1)
    return out


def age_s(result: dict) -> float | None:
    """Seconds since the diagnosis ``result`` was computed (None: not recorded)."""
    at = result.get("computed_at")
    if not isinstance(at, str):
        return None
    return max((datetime.now(timezone.utc) - datetime.fromisoformat(at)).total_seconds(), 0.0)


def diagnose_folder(folder: str, plan: dict) -> dict:
    """The job itself, in the worker process: read the planned runs there, diagnose, and
    return the JSON body (the spec's gap contract, the text report beginning with the
    period, the runs used, ``period``) and the test runs' residual curves (``RESIDUALS``,
    thinned to a screen's worth of points). A GapError (an InputError) for data it cannot
    use travels back as itself."""
    from api.service.figures.plots import thin_residuals

    dataset = dataset_of(Path(folder), plan["files"])
    report = diagnose(dataset)
    residuals = [thin_residuals(c) for c in [*report.curves.get("round_trip", []), *report.curves.get("contour", [])]]
    return {**report.to_dict(), "report": plan["text"] + "\n\n" + report.text(),
            "runs_used": [r.spec.file for r in dataset.runs], "period": plan["period"],
            "computed_at": datetime.now(timezone.utc).isoformat(timespec="seconds"), RESIDUALS: residuals}


def data_version(folder: Path) -> tuple[int, int]:
    """The version of a dataset folder's runs: dataset.json's mtime and size (every stored
    run rewrites it). NotFoundError when there are no stored runs."""
    try:
        st = (folder / "dataset.json").stat()
    except OSError:
        raise NotFoundError("stored runs in", folder.name) from None
    return st.st_mtime_ns, st.st_size


def run_set(folder: Path, runs: int) -> tuple[str, int]:
    """The key of a run set: keyed by the folder, not the axis id, since ids repeat across
    databases and data directories."""
    return str(folder.resolve()), runs


def axis_plan(folder: Path | None, axis_id: int, runs: int, repairs: Sequence[Repair] = ()) -> RunPlan:
    """The runs a diagnosis of the axis' newest ``runs`` would use now (:func:`plan_runs`).
    NotFoundError when there are no stored runs, TooFewRuns when fewer than two since the
    last repair."""
    stored = stored_runs(folder) if folder is not None else None
    if stored is None:
        raise NotFoundError("stored runs for axis", axis_id)
    return plan_runs(stored, runs, repairs)


def axis_job(jobs: "GapJobs", axis_id: int, folder: Path | None, runs: int, *, start: bool = True,
             fresh: bool = False, repairs: Sequence[Repair] = ()) -> "Job | None":
    """The job diagnosing the newest ``runs`` stored runs of the dataset ``folder`` of an
    axis since its last repair (``repairs``: the axis' recorded ones): the pending one,
    else the answer for the current data version, else a new job with its :class:`RunPlan`
    (``start=False``: the pending job, else the newest finished one of the run set, any
    version, else None). ``fresh``: a failure kept for this version (a time-out) is
    computed again. A cached answer costs a stat, not a read of every run.
    NotFoundError when there are no stored runs; TooFewRuns (an InputError) when fewer
    than two were stored since the last repair."""
    if folder is None or not (folder / "dataset.json").is_file():
        raise NotFoundError("stored runs for axis", axis_id)
    last = max(repairs, key=lambda r: r.performed_at, default=None)
    key = run_set(folder, runs)
    version = (*data_version(folder), None if last is None else (last.id, last.performed_at.isoformat()))
    if not start:
        return jobs.latest(key)
    # asking again keeps a pending job from being abandoned; the plan and the runs' size are made for a new job only
    return jobs.start(key, folder, runs, version, fresh=fresh, plan=lambda: axis_plan(folder, axis_id, runs, repairs))


_stored: OrderedDict[tuple, tuple[StoredRun, ...]] = OrderedDict()
_stored_lock = threading.Lock()


def stored_runs(folder: Path) -> tuple[StoredRun, ...] | None:
    """The runs of a dataset folder in measurement order, as the plan needs them (None:
    unreadable). Read once per data version."""
    try:
        key = (str(folder), data_version(folder))
    except NotFoundError:
        return None
    with _stored_lock:
        runs = _stored.get(key)
    if runs is None:
        try:
            runs = tuple(StoredRun(r.spec.file, _parse_time(r.spec.extra.get("measured_at")), r.spec.utility_day,
                                   r.spec.temperature_measured)
                         for r in read_dataset(folder, load_runs=False).runs)
        except (MebmError, OSError, ValueError):
            return None
        with _stored_lock:
            _stored[key] = runs
            while len(_stored) > 8:
                _stored.popitem(last=False)
    return runs


def stored_files(folder: Path) -> tuple[str, ...] | None:
    """The run files of a dataset folder in measurement order (None: unreadable)."""
    runs = stored_runs(folder)
    return None if runs is None else tuple(r.file for r in runs)


def runs_stored_since(folder: Path, result: dict) -> int | None:
    """How many runs were stored in ``folder`` after the newest run the diagnosis
    ``result`` used (None: not known)."""
    used = result.get("runs_used") or []
    files = stored_files(folder)
    if files is None or not used or used[-1] not in files:
        return None
    return len(files) - 1 - files.index(used[-1])


def run_bytes(folder: Path, runs: int | Sequence[str]) -> int | None:
    """The size on disk of the newest ``runs`` run files, or of the files ``runs`` (None:
    not known): what a diagnosis' time grows with (runs, and samples per run)."""
    if isinstance(runs, int):
        files = stored_files(folder)
        if not files:
            return None
        runs = files[-runs:]
    total = 0
    for f in runs:
        try:
            total += (folder / f).stat().st_size
        except OSError:
            return None
    return total


WORKER_NICE = 10  # the diagnosis yields the CPU to the service's cycles and requests
# What a diagnosis is expected to take before one has been timed here: seconds per MB of
# run files (the demo axis' 1000 mm round trips are 0.86 MB each; its 16 newest took 57 s
# in the worker process on the quiet 2-core machine, benchmarks/bench_gap_history.py),
# plus the model kernels' compilation by a fresh worker process (docs/gap-diagnosis.md,
# "Time"); seconds per run when the size is not known. Beyond six train round trips an
# axis' fits are thinned (core.gap.data.thin_train), so a longer history takes less than
# its size says
DEFAULT_S_PER_MB = 5.0
DEFAULT_S_PER_RUN = 4.5
FIRST_DIAGNOSIS_EXTRA_S = 20.0
# not answers: starting the run set again computes it anew (a time-out is kept for its data
# version, so a poller does not start the same long diagnosis again and again; a start from
# the dashboard, ``fresh``, does)
RETRYABLE = (DiagnosisCrashed, JobAbandoned, CancelledError)


@dataclass
class Job:
    """One diagnosis of a run set: the caller follows it by ``id``. Times are on the
    jobs' clock (monotonic seconds)."""

    id: int
    key: tuple
    version: tuple | None
    folder: str
    plan: RunPlan
    future: Future
    queued_at: float
    last_asked: float
    expected_s: float
    size_bytes: int | None = None
    started_at: float | None = None
    finished_at: float | None = None
    waiting: int = 0  # REST requests waiting for it now (each on the event loop, holding no thread)

    @property
    def runs(self) -> int:
        """How many runs it uses (its plan's, fixed when it was created)."""
        return self.plan.runs

    @property
    def state(self) -> str:
        """``queued``, ``running``, ``done`` (an answer) or ``failed`` (``error()`` says why)."""
        if not self.future.done():
            return "running" if self.started_at is not None else "queued"
        return "failed" if self.error() is not None else "done"

    def error(self) -> BaseException | None:
        """The failure of a finished job (None: it has an answer, or has not finished)."""
        if not self.future.done():
            return None
        if self.future.cancelled():
            return CancelledError("the service stopped before the diagnosis started; start it again")
        return self.future.exception()

    def retryable(self) -> bool:
        return isinstance(self.error(), RETRYABLE)


class GapJobs:
    """The service's gap-diagnosis jobs: a queue of one thread feeding a process pool of one."""

    def __init__(self, *, max_pending: int = 2, abandon_s: float = 60.0, cache_size: int = 16,
                 timeout_s: float = 900.0, compute: Callable[[str, dict], dict] = diagnose_folder,
                 use_process: bool = True, clock: Callable[[], float] = time.monotonic, nice: int = WORKER_NICE):
        self.max_pending = max_pending
        self.abandon_s = abandon_s
        self.cache_size = cache_size
        self.timeout_s = timeout_s
        self.compute = compute
        self.use_process = use_process
        self.nice = nice  # the worker process' niceness above the service's
        self.clock = clock
        self.crashes = 0
        self.timeouts = 0
        self.s_per_run: float | None = None  # measured by the last diagnosis that ended with an answer...
        self.s_per_mb: float | None = None  # ... per MB of its runs' files
        self._warm = False  # the worker process has diagnosed once (its kernels are compiled)
        self._ids = itertools.count(1)
        self._jobs: OrderedDict[int, Job] = OrderedDict()
        self._lock = threading.Lock()
        self._queue = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mebm-gap")
        self._pool: ProcessPoolExecutor | None = None
        self._closing = False

    # -- the queue ------------------------------------------------------------------------------
    def start(self, key: tuple, folder: Path | str, runs: int | RunPlan | Callable[[], RunPlan],
              version: tuple | None = None, *, fresh: bool = False,
              size_bytes: int | Callable[[], int | None] | None = None, plan=None) -> Job:
        """The job for the run set ``key``: the pending one, else the answer kept for
        ``version``, else a new one (TooManyJobs beyond ``max_pending``) with the runs
        ``plan`` (a RunPlan, or what makes it; else the newest ``runs`` of the folder).
        ``size_bytes``: of its run files (or what tells it; else measured), for the
        expected time."""
        now = self.clock()
        with self._lock:
            pending = [j for j in self._jobs.values() if not j.future.done()]
            for job in pending:
                if job.key == key:
                    job.last_asked = now
                    return job
            for job in reversed(self._jobs.values()):
                if job.key == key and job.version == version and not job.retryable():
                    if fresh and job.error() is not None:
                        break
                    self._jobs.move_to_end(job.id)
                    return job
            if len(pending) >= self.max_pending:
                raise TooManyJobs(len(pending), min(self._remaining_s(j, now) for j in pending))
            if callable(plan):
                plan = plan()
            if plan is None:
                stored = stored_files(Path(folder)) or ()
                plan = RunPlan(tuple(stored[-runs:]), runs)
            size = size_bytes() if callable(size_bytes) else size_bytes
            if size is None:
                size = run_bytes(Path(folder), plan.files)
            job = Job(next(self._ids), key, version, str(folder), plan, Future(), now, now,
                      self.expected_s(plan.runs, size), size)
            job.future = self._queue.submit(self._run, job)
            self._jobs[job.id] = job
            done = [i for i, j in self._jobs.items() if j.future.done()]
            for i in done[: max(len(done) - self.cache_size, 0)]:
                del self._jobs[i]
            return job

    def submit(self, key: tuple, folder: Path | str, runs: int, version: tuple | None = None) -> Future:
        """The future of :meth:`start`'s job."""
        return self.start(key, folder, runs, version).future

    def hold(self, fn: Callable[[], object]) -> Future:
        """Run ``fn`` on the queue's thread (tests hold the queue busy with it)."""
        return self._queue.submit(fn)

    def job(self, job_id: int) -> Job | None:
        """The job ``job_id`` (None: unknown here, e.g. the service restarted since, or its
        answer was dropped from the cache), without asking for it."""
        with self._lock:
            return self._jobs.get(job_id)

    def ask(self, job: Job) -> None:
        """Someone follows ``job``: a queued job is not abandoned."""
        with self._lock:
            job.last_asked = self.clock()

    def latest(self, key: tuple) -> Job | None:
        """The pending job of the run set ``key``, else its newest finished one (None: none)."""
        with self._lock:
            mine = [j for j in self._jobs.values() if j.key == key]
        pending = [j for j in mine if not j.future.done()]
        if pending:
            return pending[0]
        return max(mine, key=lambda j: j.finished_at or j.queued_at, default=None)

    def future(self, key: tuple) -> Future | None:
        """The future of :meth:`latest`'s job."""
        job = self.latest(key)
        return None if job is None else job.future

    def pending_jobs(self) -> list[Job]:
        """The jobs waiting or running, in their queue's order."""
        with self._lock:
            return [j for j in self._jobs.values() if not j.future.done()]

    def pending_keys(self) -> list[tuple]:
        """The run sets of the jobs waiting or running."""
        with self._lock:
            return [j.key for j in self._jobs.values() if not j.future.done()]

    def ahead(self, job: Job) -> int:
        """How many diagnoses run or wait before ``job`` (0: it runs, or is next)."""
        with self._lock:
            if job.started_at is not None or job.future.done():
                return 0
            return sum(1 for j in self._jobs.values() if j.id < job.id and not j.future.done())

    def expected_s(self, runs: int, size_bytes: int | None = None) -> float:
        """What a diagnosis of ``runs`` runs (``size_bytes`` of run files) is expected to
        take once started: as the last one timed here, per MB (else per run)."""
        extra = 0.0 if self._warm else FIRST_DIAGNOSIS_EXTRA_S
        if size_bytes is not None:
            per_mb = self.s_per_mb if self.s_per_mb is not None else DEFAULT_S_PER_MB
            return extra + per_mb * size_bytes / 1e6
        return extra + (self.s_per_run if self.s_per_run is not None else DEFAULT_S_PER_RUN) * runs

    def _remaining_s(self, job: Job, now: float) -> float:
        """Expected seconds until ``job`` ends, the jobs before it included (lock held)."""
        before = [j for j in self._jobs.values() if j.id <= job.id and not j.future.done()]
        return sum(max(j.expected_s - (now - j.started_at if j.started_at is not None else 0.0), 1.0)
                   for j in before)

    def progress(self, job: Job) -> dict:
        """The job's state for a caller: ``id``, ``state``, ``runs``, ``ahead`` (diagnoses
        before it), ``waited_s`` (in the queue), ``elapsed_s`` (since it started),
        ``expected_s`` (its expected duration once started), ``remaining_s`` (expected
        seconds until it ends, the ones before it included), ``timeout_s``; the error
        of a failed one as ``detail``."""
        now = self.clock()
        out = {"id": job.id, "state": job.state, "runs": job.runs, "period": job.plan.to_dict(),
               "expected_s": round(job.expected_s, 1), "timeout_s": self.timeout_s}
        started, finished = job.started_at, job.finished_at
        out["waited_s"] = round((started if started is not None else (finished or now)) - job.queued_at, 1)
        if started is not None:
            out["elapsed_s"] = round((finished if finished is not None else now) - started, 1)
        if not job.future.done():
            out["ahead"] = self.ahead(job)
            with self._lock:
                out["remaining_s"] = round(self._remaining_s(job, now), 1)
        elif job.error() is not None:
            out["detail"] = str(job.error())
        return out

    def forget(self) -> None:
        """Drop every job (still queued ones find themselves dropped and end at once)."""
        with self._lock:
            self._jobs.clear()

    def _run(self, job: Job) -> dict:
        now = self.clock()
        with self._lock:
            known = self._jobs.get(job.id) is job
            abandoned = not known or now - job.last_asked > self.abandon_s
            if abandoned:
                job.finished_at = now
            else:
                job.started_at = now
        folder, runs = job.folder, job.runs
        if abandoned:
            raise JobAbandoned(f"the gap diagnosis of {Path(folder).name} (runs={runs}) was dropped before it "
                               f"started: nobody asked for it within {self.abandon_s:g} s. Start it again")
        try:
            result = self._compute(folder, job.plan)
        finally:
            job.finished_at = self.clock()
        # the next jobs' expected time follows this one's
        work = max(job.finished_at - job.started_at - (0.0 if self._warm else FIRST_DIAGNOSIS_EXTRA_S), 0.1)
        self.s_per_run = work / max(runs, 1)
        if job.size_bytes:
            self.s_per_mb = work / (job.size_bytes / 1e6)
        self._warm = True
        return result

    def _compute(self, folder: str, plan: RunPlan) -> dict:
        runs = plan.runs
        if not self.use_process:
            return self.compute(folder, plan.payload())
        try:
            return self._process().submit(self.compute, folder, plan.payload()).result(timeout=self.timeout_s)
        except FutureTimeout:
            self.timeouts += 1
            pool, self._pool = self._pool, None  # a fresh process for the next job
            if pool is not None:
                end_pool(pool, grace_s=0.0, what="gap diagnosis")
            log.error("the gap diagnosis of %s (runs=%d) ran longer than %g s: stopped", folder, runs, self.timeout_s)
            raise DiagnosisTimedOut(
                f"the diagnosis of {runs} runs ran longer than {self.timeout_s:g} s and was stopped. Diagnose fewer "
                f"runs (?runs=8 in the API), or raise limits.gap_diagnosis_timeout_s in the configuration") from None
        except BrokenProcessPool as exc:
            if self._closing:  # the service stops: end_pool ended it
                raise DiagnosisCrashed(f"the service stopped while diagnosing runs={runs}; start it again") from None
            self.crashes += 1
            self._pool = None  # a fresh process for the next job
            self._warm = False
            log.error("the gap diagnosis process died during %s (runs=%d): %s", folder, runs, exc)
            raise DiagnosisCrashed(f"the gap diagnosis process died (killed, or out of memory) while "
                                   f"diagnosing runs={runs}; start it again to retry") from None

    def _process(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = spawn_pool(what="gap diagnosis", nice=self.nice)
            self._warm = False
        return self._pool

    def close(self) -> None:
        self._closing = True
        self.forget()
        self._queue.shutdown(wait=False, cancel_futures=True)
        if self._pool is not None:  # a diagnosis is asked again, not waited for
            end_pool(self._pool, grace_s=IDLE_END_S, what="gap diagnosis")
            self._pool = None
