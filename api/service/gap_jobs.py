"""Gap diagnoses as bounded background jobs, computed in a separate process.

A diagnosis (core.gap) takes 5-60 s on a 2-core machine, and several minutes on a
dataset whose visible gap no single candidate explains (the two-together search: up to
620 s seen in the independent plant's benchmark, two diagnoses at a time), longer than an MES should
hold a request open, and it is pure Python/numpy/numba that holds the interpreter lock
while it runs.
Run on a thread of the service, it slowed every other request (a status poll waited
for the lock: p99 47 ms in the soak). So the jobs are queued here, one at a time, and
each is computed by a worker *process* (a ``spawn``-started pool of one, kept for the
next job): the service's threads stay free for the API and the cycles.

Bounds (a read key must not be able to keep the server busy for minutes):

- one job per key (the caller's: folder, runs, data version); asking again for a
  pending job returns the same future;
- at most ``max_pending`` jobs wait or run; more raise :class:`TooManyJobs`;
- a job nobody has asked for within ``abandon_s`` is dropped before it starts
  (:class:`JobAbandoned`);
- at most ``cache_size`` finished answers are kept (small dicts; no runs);
- a worker process that dies (killed, out of memory) fails its job with
  :class:`DiagnosisCrashed` and is replaced for the next one.

The REST router and the dashboard both use one :class:`GapJobs` of the service.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

from api.service.worker_process import IDLE_END_S, end_pool, spawn_pool
from core.dataset import Dataset, Run
from core.errors import MebmError
from core.gap import diagnose
from storage.dataset import read_dataset, read_run_csv
from storage.db import NotFoundError

log = logging.getLogger("mebm.gap")


class JobAbandoned(MebmError):
    """Nobody asked for the diagnosis within ``abandon_s``: it was not computed."""


class TooManyJobs(MebmError):
    """``max_pending`` diagnoses wait or run already."""

    def __init__(self, pending: int):
        super().__init__(f"{pending} gap diagnoses are being computed; ask again later")
        self.pending = pending


class DiagnosisCrashed(MebmError):
    """The worker process died during the diagnosis (killed, or out of memory)."""


def newest_runs(folder: Path, n: int) -> Dataset:
    """The newest ``n`` runs of a dataset folder (runs are appended in measurement order)."""
    meta = read_dataset(folder, load_runs=False)
    specs = [r.spec for r in meta.runs][-n:]
    runs = tuple(Run(spec, read_run_csv(folder / spec.file, spec)) for spec in specs)
    return Dataset(meta.machine, runs, meta.extra)


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
    from datetime import datetime, timezone

    return max((datetime.now(timezone.utc) - datetime.fromisoformat(at)).total_seconds(), 0.0)


def diagnose_folder(folder: str, n: int) -> dict:
    """The job itself, in the worker process: read the runs there, diagnose, and return
    the JSON body (the spec's gap contract, the text report and the runs used) and the
    test runs' residual curves (``RESIDUALS``, thinned to a screen's worth of points). A
    GapError (an InputError) for data it cannot use travels back as itself."""
    from api.service.plots import thin_residuals

    dataset = newest_runs(Path(folder), n)
    report = diagnose(dataset)
    residuals = [thin_residuals(c) for c in [*report.curves.get("round_trip", []), *report.curves.get("contour", [])]]
    from datetime import datetime, timezone

    return {**report.to_dict(), "report": report.text(), "runs_used": [r.spec.file for r in dataset.runs],
            "computed_at": datetime.now(timezone.utc).isoformat(timespec="seconds"), RESIDUALS: residuals}


def axis_job(jobs: "GapJobs", axis_id: int, folder: Path | None, runs: int, *, start: bool = True) -> Future | None:
    """The job diagnosing the newest ``runs`` stored runs of the dataset ``folder`` of an
    axis: the pending or cached one, else a new one (``start=False``: None instead).

    Keyed by (folder, runs, version of dataset.json): a cached answer costs a stat, not a
    read of every run; keyed by the folder, not the axis id, since ids repeat across
    databases and data directories. NotFoundError when there are no stored runs."""
    if folder is None or not (folder / "dataset.json").is_file():
        raise NotFoundError("stored runs for axis", axis_id)
    st = (folder / "dataset.json").stat()
    key = (str(folder.resolve()), runs, st.st_mtime_ns, st.st_size)
    if not start:
        fut = jobs.future(key)
        if fut is None or fut.done():
            return fut
    return jobs.submit(key, folder, runs)  # asking again keeps a pending job from being abandoned


WORKER_NICE = 10  # the diagnosis yields the CPU to the service's cycles and requests


@dataclass
class _Job:
    future: Future
    last_asked: float = field(default_factory=time.monotonic)


class GapJobs:
    """The service's gap-diagnosis jobs: a queue of one thread feeding a process pool of one."""

    def __init__(self, *, max_pending: int = 2, abandon_s: float = 60.0, cache_size: int = 16,
                 compute: Callable[[str, int], dict] = diagnose_folder, use_process: bool = True):
        self.max_pending = max_pending
        self.abandon_s = abandon_s
        self.cache_size = cache_size
        self.compute = compute
        self.use_process = use_process
        self.crashes = 0
        self._jobs: OrderedDict[tuple, _Job] = OrderedDict()
        self._lock = threading.Lock()
        self._queue = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mebm-gap")
        self._pool: ProcessPoolExecutor | None = None
        self._closing = False

    # -- the queue ------------------------------------------------------------------------------
    def submit(self, key: tuple, folder: Path, runs: int) -> Future:
        """The future of the job for ``key``: the pending or cached one, or a new one."""
        with self._lock:
            job = self._jobs.get(key)
            if job is not None and job.future.done() and isinstance(job.future.exception(), DiagnosisCrashed):
                job = None  # a crash is not an answer: asking again computes it anew
            if job is None:
                pending = sum(1 for j in self._jobs.values() if not j.future.done())
                if pending >= self.max_pending:
                    raise TooManyJobs(pending)
                job = self._jobs[key] = _Job(self._queue.submit(self._run, key, str(folder), runs))
                done = [k for k, j in self._jobs.items() if j.future.done()]
                for k in done[: max(len(done) - self.cache_size, 0)]:
                    del self._jobs[k]
            else:
                job.last_asked = time.monotonic()
                self._jobs.move_to_end(key)
            return job.future

    def hold(self, fn: Callable[[], object]) -> Future:
        """Run ``fn`` on the queue's thread (tests hold the queue busy with it)."""
        return self._queue.submit(fn)

    def future(self, key: tuple) -> Future | None:
        """The future of the job for ``key``, without asking for it (no ``last_asked`` update)."""
        with self._lock:
            job = self._jobs.get(key)
            return None if job is None else job.future

    def pending_keys(self) -> list[tuple]:
        with self._lock:
            return list(self._jobs)

    def forget(self) -> None:
        """Drop every job (still queued ones find themselves dropped and end at once)."""
        with self._lock:
            self._jobs.clear()

    def _run(self, key: tuple, folder: str, runs: int) -> dict:
        with self._lock:
            job = self._jobs.get(key)
            abandoned = job is None or time.monotonic() - job.last_asked > self.abandon_s
            if abandoned and job is not None:
                del self._jobs[key]
        if abandoned:
            raise JobAbandoned(f"gap diagnosis of {Path(folder).name} (runs={runs}) dropped: nobody asked for "
                               f"it within {self.abandon_s:g} s")
        if not self.use_process:
            return self.compute(folder, runs)
        try:
            return self._process().submit(self.compute, folder, runs).result()
        except BrokenProcessPool as exc:
            if self._closing:  # the service stops: end_pool ended it
                raise DiagnosisCrashed(f"the service stopped while diagnosing runs={runs}; ask again") from None
            self.crashes += 1
            self._pool = None  # a fresh process for the next job
            log.error("the gap diagnosis process died during %s (runs=%d): %s", folder, runs, exc)
            raise DiagnosisCrashed(f"the gap diagnosis process died (killed, or out of memory) while "
                                   f"diagnosing runs={runs}; ask again to retry") from None

    def _process(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = spawn_pool(what="gap diagnosis", nice=WORKER_NICE)
        return self._pool

    def close(self) -> None:
        self._closing = True
        self.forget()
        self._queue.shutdown(wait=False, cancel_futures=True)
        if self._pool is not None:  # a diagnosis is asked again, not waited for
            end_pool(self._pool, grace_s=IDLE_END_S, what="gap diagnosis")
            self._pool = None
