"""/axes/{id}/gap: the sim-to-real gap diagnosis (core.gap) on an axis' stored runs.

The service writes every good cycle's raw round trip to the axis' dataset folder;
this endpoint diagnoses the newest ``runs`` of them. With no ``split`` in stored
runs the diagnosis holds out whole runs by condition (temperature, feed) and says
which.

A diagnosis takes seconds (more on the first call of a process, which compiles the
model kernels), longer than an MES should hold a request open. So it runs on a
background worker: the request waits up to ``WAIT_S``; if the report is not ready
it answers 202 with ``Retry-After``, and the next call gets the report (200), cached
per (folder, runs, version of dataset.json). A diagnosis that fails for its input is
cached too and answered 422.

Bounds (a read key must not be able to keep the server busy for minutes): at most
``MAX_PENDING`` diagnoses wait or run (more: 429 with ``Retry-After``); a job nobody
has asked for within ``ABANDON_S`` is dropped before it starts; a cached answer is
served after one ``stat`` of ``dataset.json``, without reading any run; the runs are
read on the worker, never on the request thread.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse

from api.rest.auth import ReadKey
from api.rest.deps import AxisId, ServiceDep, SessionDep
from api.rest.errors import TooManyRequestsError
from core.dataset import Dataset, Run
from core.errors import MebmError
from core.gap import diagnose
from storage.dataset import read_dataset, read_run_csv
from storage.db import NotFoundError, config_repo

router = APIRouter(tags=["gap"])

WAIT_S = 5.0
RETRY_AFTER_S = 5
_CACHE_SIZE = 16  # finished answers kept (each a small dict; no runs are kept)
MAX_PENDING = 2  # jobs waiting or running at once; more: 429 with Retry-After
ABANDON_S = 60.0  # a job nobody asked for in this long is dropped before it starts


@dataclass
class _Job:
    future: Future
    last_asked: float = field(default_factory=time.monotonic)


class JobAbandoned(MebmError):
    """Nobody asked for the diagnosis within ABANDON_S: it was not computed."""


_jobs: OrderedDict[tuple, _Job] = OrderedDict()
_lock = threading.Lock()
_worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mebm-gap")

ACCEPTED = {202: {"description": "the diagnosis is being computed: call again after Retry-After seconds",
                  "content": {"application/json": {"schema": {"type": "object"}}}},
            429: {"description": "too many diagnoses waiting; call again after Retry-After seconds",
                  "content": {"application/json": {"schema": {"type": "object"}}}}}


def _newest_runs(folder: Path, n: int) -> Dataset:
    meta = read_dataset(folder, load_runs=False)
    specs = [r.spec for r in meta.runs][-n:]  # runs are appended in measurement order
    runs = tuple(Run(spec, read_run_csv(folder / spec.file, spec)) for spec in specs)
    return Dataset(meta.machine, runs, meta.extra)


def _run(key: tuple, folder: Path, n: int) -> dict:
    """The job, on the worker: skipped if abandoned; the runs are read here, not on the
    request thread."""
    with _lock:
        job = _jobs.get(key)
        abandoned = job is None or time.monotonic() - job.last_asked > ABANDON_S
        if abandoned and job is not None:
            del _jobs[key]
    if abandoned:
        raise JobAbandoned(f"gap diagnosis of {folder.name} (runs={n}) dropped: nobody asked for it "
                           f"within {ABANDON_S:g} s")
    dataset = _newest_runs(folder, n)
    report = diagnose(dataset)  # GapError (an InputError) for data it cannot use: a 422 naming why
    return {**report.to_dict(), "report": report.text(), "runs_used": [r.spec.file for r in dataset.runs]}


def _job(key: tuple, folder: Path, n: int) -> Future:
    with _lock:
        job = _jobs.get(key)
        if job is None:
            pending = sum(1 for j in _jobs.values() if not j.future.done())
            if pending >= MAX_PENDING:
                raise TooManyRequestsError(f"{pending} gap diagnoses are being computed; ask again later",
                                           RETRY_AFTER_S)
            job = _jobs[key] = _Job(_worker.submit(_run, key, folder, n))
            done = [k for k, j in _jobs.items() if j.future.done()]
            for k in done[: max(len(done) - _CACHE_SIZE, 0)]:
                del _jobs[k]
        else:
            job.last_asked = time.monotonic()
            _jobs.move_to_end(key)
        return job.future


@router.get(
    "/axes/{axis_id}/gap",
    summary="Where the nominal model and the machine disagree, which effect causes it, how far the gap shrinks",
    response_model=dict[str, Any],
    responses=ACCEPTED,
)
def gap(
    axis_id: AxisId, s: SessionDep, svc: ServiceDep, _k: ReadKey,
    runs: Annotated[int, Query(ge=2, le=60, description="how many of the newest stored runs to use")] = 16,
):
    axis = config_repo.get_axis(s, axis_id)
    folder = svc.executor.dataset_folder(axis) if svc.executor is not None else None
    if folder is None or not (folder / "dataset.json").is_file():
        raise NotFoundError("stored runs for axis", axis_id)
    st = (folder / "dataset.json").stat()
    # one job per (folder, runs, data version): a cached answer costs a stat, not a read of every run;
    # keyed by the folder, not the axis id: ids repeat across databases and data directories
    fut = _job((str(folder.resolve()), runs, st.st_mtime_ns, st.st_size), folder, runs)
    try:
        return fut.result(timeout=WAIT_S)  # re-raises the diagnosis' own error
    except FutureTimeout:
        return JSONResponse(
            {"status": "computing", "detail": f"the gap diagnosis of axis {axis_id} is running; "
                                              f"call again in {RETRY_AFTER_S} s"},
            status_code=202, headers={"Retry-After": str(RETRY_AFTER_S)},
        )
    except JobAbandoned:
        return JSONResponse(  # asked again after it was dropped: computed anew
            {"status": "computing", "detail": f"the gap diagnosis of axis {axis_id} was restarted; "
                                              f"call again in {RETRY_AFTER_S} s"},
            status_code=202, headers={"Retry-After": str(RETRY_AFTER_S)},
        )
