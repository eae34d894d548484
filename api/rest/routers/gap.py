"""/axes/{id}/gap: the sim-to-real gap diagnosis (core.gap) on an axis' stored runs.

The service writes every good cycle's raw round trip to the axis' dataset folder;
this endpoint diagnoses the newest ``runs`` of them. With no ``split`` in stored
runs the diagnosis holds out whole runs by condition (temperature, feed) and says
which.

A diagnosis takes seconds (more on the first call of a process, which compiles the
model kernels), longer than an MES should hold a request open. So it is a job of the
service (api/service/gap_jobs.py: computed in a worker process, bounded, abandoned
jobs dropped): the request waits up to ``WAIT_S``; if the report is not ready it
answers 202 with ``Retry-After``, and the next call gets the report (200), cached per
(folder, runs, version of dataset.json), with ``computed_at`` and ``age_s`` (seconds since
it was computed). A diagnosis that fails for its input is
cached too and answered 422. More than the service's pending bound: 429 with
``Retry-After``. A cached answer is served after one ``stat`` of ``dataset.json``,
without reading any run; the runs are read in the worker process. A folder that does
not record the axis as its owner and holds runs of other cycles (another database's
machine of the same ids) is never diagnosed: 409 saying whose it is.
"""

from __future__ import annotations

from concurrent.futures import TimeoutError as FutureTimeout
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse

from api.rest.auth import ReadKey
from api.rest.deps import AxisId, ServiceDep, SessionDep
from api.rest.errors import TooManyRequestsError
from api.service.gap_jobs import DiagnosisCrashed, JobAbandoned, TooManyJobs, axis_job, public_body
from storage.dataset import FolderOwnerError
from storage.db import ConflictError, config_repo

router = APIRouter(tags=["gap"])

WAIT_S = 5.0
RETRY_AFTER_S = 5

ACCEPTED = {202: {"description": "the diagnosis is being computed: call again after Retry-After seconds",
                  "content": {"application/json": {"schema": {"type": "object"}}}},
            429: {"description": "too many diagnoses waiting; call again after Retry-After seconds",
                  "content": {"application/json": {"schema": {"type": "object"}}}},
            503: {"description": "the diagnosis process died (killed, out of memory); call again to retry",
                  "content": {"application/json": {"schema": {"type": "object"}}}}}


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
    try:  # only the axis' own runs: never a folder another machine (of another database) wrote
        folder = svc.executor.readable_folder(axis) if svc.executor is not None else None
    except FolderOwnerError as exc:
        raise ConflictError(str(exc)) from None
    try:
        fut = axis_job(svc.gap_jobs, axis_id, folder, runs)
    except TooManyJobs as exc:
        raise TooManyRequestsError(str(exc), RETRY_AFTER_S) from None
    try:
        return public_body(fut.result(timeout=WAIT_S))  # re-raises the diagnosis' own error
    except FutureTimeout:
        return JSONResponse(
            {"status": "computing", "detail": f"the gap diagnosis of axis {axis_id} is running; "
                                              f"call again in {RETRY_AFTER_S} s"},
            status_code=202, headers={"Retry-After": str(RETRY_AFTER_S)},
        )
    except DiagnosisCrashed as exc:
        return JSONResponse({"detail": str(exc)}, status_code=503, headers={"Retry-After": str(RETRY_AFTER_S)})
    except JobAbandoned:
        return JSONResponse(  # asked again after it was dropped: computed anew
            {"status": "computing", "detail": f"the gap diagnosis of axis {axis_id} was restarted; "
                                              f"call again in {RETRY_AFTER_S} s"},
            status_code=202, headers={"Retry-After": str(RETRY_AFTER_S)},
        )
