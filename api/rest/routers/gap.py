"""/axes/{id}/gap: the sim-to-real gap diagnosis (core.gap) on an axis' stored runs.

The service writes every good cycle's raw round trip to the axis' dataset folder;
this endpoint diagnoses the newest ``runs`` of them *since the axis' last recorded
repair* (runs on both sides of a repair are never pooled; fewer than two since it: 422
saying so). The job's ``runs`` and ``period`` are fixed when it is created, and the
report's ``period`` says which runs it covers (first and last run, utility days, the
repair it starts after, the runs left out). With no ``split`` in stored runs the
diagnosis holds out whole runs by condition (temperature, feed) and says which.

A diagnosis takes from seconds to minutes (more on the first call of a process, which
compiles the model kernels), longer than an MES should hold a request open. So it is a
job of the service (api/service/gap_jobs.py: computed in a worker process, bounded,
abandoned jobs dropped, stopped after ``limits.gap_diagnosis_timeout_s``): the request
waits up to ``WAIT_S``; if the report is not ready it answers 202 with ``Retry-After``,
the job's progress (``job``: id, state, place in the queue, elapsed and expected
seconds) and ``Location``: ``/axes/{id}/gap/jobs/{job_id}``, which follows that job
whatever is stored meanwhile. The report (200) is cached per (folder, runs, version of
dataset.json), with ``computed_at``, ``age_s`` (seconds since it was computed),
``job_id`` and ``runs_stored_since`` (runs stored after the newest one it used). A
diagnosis that fails for its input is cached too and answered 422. More than the
service's pending bound: 429 with ``Retry-After`` (when the first pending diagnosis is
expected to end). A cached answer is served after one ``stat`` of ``dataset.json``,
without reading any run; the runs are read in the worker process. A folder that does
not record the axis as its owner and holds runs of other cycles (another database's
machine of the same ids) is never diagnosed: 409 saying whose it is.
"""

from __future__ import annotations

import asyncio
from concurrent.futures import CancelledError
from concurrent.futures import TimeoutError as FutureTimeout
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from api.rest.auth import ReadKey
from api.rest.deps import AxisId, ServiceDep
from api.rest.errors import TooManyRequestsError
from api.service.gap_jobs import (DiagnosisCrashed, DiagnosisTimedOut, GapJobs, Job, JobAbandoned, TooManyJobs,
                                  axis_job, public_body, repairs_of, runs_stored_since)
from storage.dataset import FolderOwnerError
from storage.db import ConflictError, NotFoundError, config_repo, session_scope

router = APIRouter(tags=["gap"])

WAIT_S = 5.0
RETRY_AFTER_S = 5

ACCEPTED = {202: {"description": "the diagnosis waits or runs: follow Location (or call again) after Retry-After "
                                 "seconds; `job` says its place in the queue and its expected time",
                  "content": {"application/json": {"schema": {"type": "object"}}}},
            429: {"description": "too many diagnoses waiting; call again after Retry-After seconds",
                  "content": {"application/json": {"schema": {"type": "object"}}}},
            503: {"description": "the diagnosis process died (killed, out of memory), the job was dropped, or "
                                 "it ran past the time limit; `detail` says which and what to do",
                  "content": {"application/json": {"schema": {"type": "object"}}}}}


def _folder(svc, axis_id: int) -> Path | None:
    """The axis' own folder, read in a session of its own: a request that then waits for
    its job holds no database connection either."""
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    try:  # only the axis' own runs: never a folder another machine (of another database) wrote
        return svc.executor.readable_folder(axis) if svc.executor is not None else None
    except FolderOwnerError as exc:
        raise ConflictError(str(exc)) from None


def _answer(jobs: GapJobs, axis_id: int, folder: Path, job: Job, wait_s: float):
    """The job's report (200), its progress (202), or why it failed."""
    location = f"/api/v1/axes/{axis_id}/gap/jobs/{job.id}"
    try:
        result = job.future.result(timeout=wait_s)  # re-raises the diagnosis' own error (a GapError: 422)
    except FutureTimeout:
        p = jobs.progress(job)
        where = (f"{p['ahead']} diagnosis(es) ahead of it" if p.get("ahead") else
                 "it runs" if p["state"] == "running" else "it is next")
        return JSONResponse(
            {"status": "computing" if p["state"] == "running" else "queued",
             "detail": f"the gap diagnosis of axis {axis_id} ({job.runs} runs) is job {job.id}: {where}, expected "
                       f"to end in about {p.get('remaining_s', 0):.0f} s; call {location} again in {RETRY_AFTER_S} s",
             "job": p},
            status_code=202, headers={"Retry-After": str(RETRY_AFTER_S), "Location": location})
    except (DiagnosisCrashed, JobAbandoned, CancelledError, DiagnosisTimedOut) as exc:
        detail = str(exc) or "the service stopped before the diagnosis started; start it again"
        retry = {} if isinstance(exc, DiagnosisTimedOut) else {"Retry-After": str(RETRY_AFTER_S)}
        return JSONResponse({"detail": detail, "job": jobs.progress(job)}, status_code=503, headers=retry)
    body = public_body(result)
    body["job_id"] = job.id
    body["runs_stored_since"] = runs_stored_since(folder, result)
    return body


@router.get(
    "/axes/{axis_id}/gap",
    summary="Where the nominal model and the machine disagree, which effect causes it, how far the gap shrinks",
    response_model=dict[str, Any],
    responses=ACCEPTED,
)
async def gap(
    axis_id: AxisId, svc: ServiceDep, _k: ReadKey,
    runs: Annotated[int, Query(ge=2, le=60, description="how many of the newest stored runs since the axis' last repair to use")] = 16,
):
    folder = await run_in_threadpool(_folder, svc, axis_id)
    repairs = await run_in_threadpool(repairs_of, svc.factory, axis_id)
    try:
        job = await run_in_threadpool(lambda: axis_job(svc.gap_jobs, axis_id, folder, runs, repairs=repairs))
    except TooManyJobs as exc:
        raise TooManyRequestsError(str(exc), exc.retry_after_s) from None
    await _settle(job)
    return await run_in_threadpool(_answer, svc.gap_jobs, axis_id, folder, job, 0.0)


async def _settle(job: Job) -> None:
    """Up to ``WAIT_S`` for the job to end, on the event loop: a request that waits holds
    none of the worker threads the other requests (``/healthz`` among them) need."""
    wait_s = WAIT_S
    if not job.future.done():
        job.waiting += 1  # on the event loop only: no lock needed
        waited = asyncio.wrap_future(job.future)
        # a job that fails after this request has gone (202) is answered to whoever asks
        # next; the copy on this loop is read so that asyncio does not log it as lost
        waited.add_done_callback(lambda f: f.cancelled() or f.exception())
        try:
            await asyncio.wait({waited}, timeout=wait_s)  # never cancels the job
        finally:
            job.waiting -= 1


@router.get(
    "/axes/{axis_id}/gap/jobs/{job_id}",
    summary="One gap diagnosis job: its report when done, else its place in the queue and its expected time",
    response_model=dict[str, Any],
    responses=ACCEPTED,
)
async def gap_job(axis_id: AxisId, job_id: int, svc: ServiceDep, _k: ReadKey):
    folder = await run_in_threadpool(_folder, svc, axis_id)
    job = svc.gap_jobs.job(job_id)
    if job is None or folder is None or job.key[0] != str(folder.resolve()):
        raise NotFoundError(f"gap diagnosis job of axis {axis_id} (the service restarted, or the answer was "
                            f"dropped from its memory: GET /api/v1/axes/{axis_id}/gap starts a new one)", job_id)
    svc.gap_jobs.ask(job)
    await _settle(job)
    return await run_in_threadpool(_answer, svc.gap_jobs, axis_id, folder, job, 0.0)
