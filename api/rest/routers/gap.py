"""/axes/{id}/gap: the sim-to-real gap diagnosis (core.gap) on an axis' stored runs.

The service writes every good cycle's raw round trip to the axis' dataset folder;
this endpoint diagnoses the newest ``runs`` of them. With no ``split`` in stored
runs the diagnosis holds out whole runs by condition (temperature, feed) and says
which.

A diagnosis takes seconds (more on the first call of a process, which compiles the
model kernels), longer than an MES should hold a request open. So it runs on a
background worker: the request waits up to ``WAIT_S``; if the report is not ready
it answers 202 with ``Retry-After``, and the next call gets the report (200), cached
per set of runs. A diagnosis that fails for its input is cached too and answered 422.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse

from api.rest.auth import ReadKey
from api.rest.deps import AxisId, ServiceDep, SessionDep
from core.dataset import Dataset, Run
from core.gap import diagnose
from storage.dataset import read_dataset, read_run_csv
from storage.db import NotFoundError, config_repo

router = APIRouter(tags=["gap"])

WAIT_S = 5.0
RETRY_AFTER_S = 5
_CACHE_SIZE = 16
_jobs: OrderedDict[tuple, Future] = OrderedDict()
_lock = threading.Lock()
_worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mebm-gap")

ACCEPTED = {202: {"description": "the diagnosis is being computed: call again after Retry-After seconds",
                  "content": {"application/json": {"schema": {"type": "object"}}}}}


def _newest_runs(folder: Path, n: int) -> Dataset:
    meta = read_dataset(folder, load_runs=False)
    specs = [r.spec for r in meta.runs][-n:]  # runs are appended in measurement order
    runs = tuple(Run(spec, read_run_csv(folder / spec.file, spec)) for spec in specs)
    return Dataset(meta.machine, runs, meta.extra)


def _diagnose(dataset: Dataset, files: list[str]) -> dict:
    report = diagnose(dataset)  # GapError (an InputError) for data it cannot use: a 422 naming why
    return {**report.to_dict(), "report": report.text(), "runs_used": files}


def _job(key: tuple, dataset: Dataset) -> Future:
    with _lock:
        fut = _jobs.get(key)
        if fut is None:
            fut = _worker.submit(_diagnose, dataset, list(key[1]))
            _jobs[key] = fut
            while len(_jobs) > _CACHE_SIZE:
                _jobs.popitem(last=False)
        else:
            _jobs.move_to_end(key)
        return fut


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
    dataset = _newest_runs(folder, runs)
    # keyed by the folder, not the axis id: ids repeat across databases and data directories
    fut = _job((str(folder.resolve()), tuple(r.spec.file for r in dataset.runs)), dataset)
    try:
        return fut.result(timeout=WAIT_S)  # re-raises the diagnosis' own error
    except FutureTimeout:
        return JSONResponse(
            {"status": "computing", "detail": f"the gap diagnosis of axis {axis_id} is running; "
                                              f"call again in {RETRY_AFTER_S} s"},
            status_code=202, headers={"Retry-After": str(RETRY_AFTER_S)},
        )
